"""Power cuts at every block write of a scenario, in every way a write can fail.

Legal end state (spec/sdcard.md, "Faults"): after remounting, every file
committed before the interrupted operation is listed and byte-identical
unless that operation was dropping it by design; nothing else is listed but
the old or new version of a file; last job and nonvolatile bytes are old or
new; and the card then takes a new file and reads everything back.
"""

import itertools
import random

import pytest

from robox.errors import PowerCut
from robox.firmware.error_flags import ErrorFlags
from robox.firmware.file_system import FileSystem
from robox.formats.sdcard import BLOCK_SIZE, SLOT_SIZE, SLOTS_OFFSET, Directory, printer_walk
from robox.hardware.faults import FaultPlan, Tear
from robox.hardware.sdcard import SdCard
from robox.hardware.storage import MemoryStorage
from tests.faults import campaign
from tests.faults.campaign import Case, Media, check, judge, observe


@pytest.fixture(scope="module")
def rec():
    return campaign.record()


def report(problems: list[str]) -> str:
    shown = "\n".join(problems[:10])
    return (f"{len(problems)} problem(s); replay one with tests.faults.campaign.replay(id)\n"
            f"{shown}")


def test_the_scenario_exercises_every_rule(rec):
    ops = campaign.SCENARIO
    names = [[f[0].rstrip(b"\0").decode() for f in s.files] for s in rec.states]
    after = {op[1] if len(op) > 1 else op[0]: names[i + 1] for i, op in enumerate(ops)}
    assert "m1" not in after["j2"]  # the macro made way for the next upload
    assert names[ops.index(("put", "s12", 600, True)) + 1][0] == "j2"  # ring of 15: j1 dropped
    assert "j2" not in after["big"] and "j3" in after["big"]  # dropped by make_space
    assert "j3" not in after["j5"]
    assert after["format"] == [] and after["j6"] == ["j6"]
    assert rec.states[ops.index(("open", "s3")) + 1].last_job.startswith(b"s3")
    # "big" wraps past the end of the card, so once "m2" follows it a printer's
    # walk rejects the card (the printer bug the project does not copy)
    media = Media(rec)
    media.advance_to(max(n for n, w in enumerate(rec.writes, 1)
                         if w[2] == ops.index(("put", "m2", 100, False))))
    d = Directory.decode(bytes(media.data[:512]))
    big = next(d.slots[i] for i in d.ring() if d.slots[i].id.startswith(b"big"))
    assert big.start_block + big.blocks > campaign.CAPACITY
    assert not printer_walk(d, campaign.CAPACITY).valid


@pytest.mark.parametrize("mode", ["cut", "prefix", "mix"])
def test_every_write_cut_or_torn_leaves_a_legal_card(rec, mode):
    media = Media(rec)
    problems = []
    count = 0
    for case in campaign.cases(rec, (mode,)):
        problems += check(rec, media, case)
        count += 1
    assert count >= len(rec.writes)
    assert not problems, report(problems)


def test_an_erased_block_0_recovers_from_the_copy_or_formats_cleanly(rec):
    media = Media(rec)
    problems, recovered = [], 0
    for case in campaign.cases(rec, ("erase",)):
        problems += check(rec, media, case)
        fs = FileSystem(media.surviving_card(case), ErrorFlags())
        fs.file_list()
        recovered += fs.last_mount.action == "recover"
    assert not problems, report(problems)
    assert recovered >= 20  # commits, deletions, last-job and nonvolatile updates


def _interpreted_differences(old: bytes, new: bytes) -> list[int]:
    """Offsets whose byte differs and that a mount interprets."""
    o, n = Directory.decode(old), Directory.decode(new)
    rings = set(o.ring()) | set(n.ring())
    offsets = []
    for i in range(BLOCK_SIZE):
        if old[i] == new[i] or 13 <= i < SLOTS_OFFSET:
            continue
        if i >= SLOTS_OFFSET:
            slot, within = divmod(i - SLOTS_OFFSET, SLOT_SIZE)
            if slot not in rings or 17 <= within < 20:
                continue
        offsets.append(i)
    return offsets


def test_every_byte_mix_of_every_directory_write_is_legal(rec):
    """Exhaustive over the bytes a mount reads: 2^k mixes for each block-0 write."""
    media = Media(rec)
    rng = random.Random(5)
    problems, checked = [], 0
    for n, (block, new, _) in enumerate(rec.writes, 1):
        if block != 0:
            continue
        media.advance_to(n - 1)
        old = bytes(media.data[:BLOCK_SIZE])
        offsets = _interpreted_differences(old, new)
        assert len(offsets) <= 12, f"write {n} changes {len(offsets)} interpreted bytes"
        for rest in ("old", "new", "mix"):
            base = bytearray(old if rest == "old" else new)
            if rest == "mix":
                base = bytearray(Tear(seed=rng.randrange(1 << 30)).apply(old, new))
            for choice in itertools.product((False, True), repeat=len(offsets)):
                block0 = bytearray(base)
                for offset, take_new in zip(offsets, choice, strict=True):
                    block0[offset] = (new if take_new else old)[offset]
                data = bytearray(media.data)
                data[:BLOCK_SIZE] = block0
                fs = FileSystem(SdCard(MemoryStorage(data)), ErrorFlags())
                state = observe(fs)
                found = judge(rec, Case("cut", n), state) or campaign.use_again(fs, state)
                problems += [f"[write {n}, mix {choice}, rest {rest}] {p}" for p in found]
                checked += 1
    assert checked > 100
    assert not problems, report(problems)


def test_the_recorded_survivor_is_what_a_real_cut_leaves(rec):
    """The campaign's shortcut is exact: replay sample cases through the FaultPlan."""
    media = Media(rec)
    all_cases = list(campaign.cases(rec))
    sample = all_cases[:: max(1, len(all_cases) // 40)] + [c for c in all_cases
                                                            if c.mode == "erase"][:5]
    for case in sample:
        real = campaign.replay(case.id)
        assert bytes(real.storage.data) == bytes(media.surviving_card(case).storage.data), case.id


def _cut_every_write_of(make_card, action) -> list[tuple[SdCard, str]]:
    """Survivors of a cut (whole, torn prefix, torn mix) at every write of `action`."""
    probe = make_card()
    action(probe)
    survivors = []
    for k in range(1, probe.writes + 1):
        for label, plan in (("cut", FaultPlan(cut_after_write=k)),
                            ("prefix", FaultPlan(tear_write=k, tear=Tear(prefix=37))),
                            ("mix", FaultPlan(tear_write=k, tear=Tear(seed=k)))):
            card = make_card()
            card.faults = plan
            with pytest.raises(PowerCut):
                action(card)
            card.faults = FaultPlan()
            survivors.append((card, f"{label}@{k}"))
    return survivors


def test_cuts_while_recovering_or_reusing_a_cut_card(rec):
    """A second cut: during the mount that repairs the first, or the upload after it."""
    media = Media(rec)
    problems = []
    first_cuts = [c for c in campaign.cases(rec, ("mix", "erase"))
                  if rec.writes[c.write - 1][0] == 0]
    for case in first_cuts:
        base = bytes(media.surviving_card(case).storage.data)

        def make_card(base=base):
            return SdCard(MemoryStorage(base))

        def recover_and_reuse(card):
            fs = FileSystem(card, ErrorFlags())
            campaign.use_again(fs, observe(fs))

        first = FileSystem(make_card(), ErrorFlags())
        before = observe(first)
        campaign.use_again(first, before)
        after = observe(first)
        for card, label in _cut_every_write_of(make_card, recover_and_reuse):
            state = observe(FileSystem(card, ErrorFlags()))
            problems += [f"[{case.id} then {label}] {p}"
                         for p in campaign.judge_states(before, after, state)]
    assert not problems, report(problems)


def test_the_digest_cache_answers_what_hashing_the_survivor_answers(rec):
    """The campaign's file digests come from a cache keyed by the writes that last touched
    a file's blocks; across cut points it gives what hashing the surviving card gives."""
    media = Media(rec)
    for case in list(campaign.cases(rec))[::7]:
        cached = observe(FileSystem(media.surviving_card(case), ErrorFlags()),
                         media.digest if case.write else None)
        plain = observe(FileSystem(media.surviving_card(case), ErrorFlags()))
        assert cached == plain, case.id

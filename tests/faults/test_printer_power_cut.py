"""Power cuts at every write of a print still being uploaded (tests/faults/printer_campaign).

Legal end state: the card mounts with every committed file intact and the job
absent or whole; each EEPROM loads VALID with one of the two images last
written to it (the reel's remaining filament is one of its last two values);
the hours page is old or new (or torn by a cut during its own write, as the
firmware leaves it); the image is intact; and the job sent again with resume
is stored byte-identical.
"""

import pytest
from click.testing import CliRunner

from robox.cli import cli
from robox.errors import PowerCut
from robox.formats.eeprom import EepromIndex
from robox.formats.firmware import HOURS_PAGE
from robox.formats.sdcard import make_id
from robox.hardware.faults import Landing, PowerPlan
from robox.sim.printer import VirtualPrinter
from tests.faults import printer_campaign as campaign


@pytest.fixture(scope="module")
def rec():
    return campaign.record()


def report(problems: list[str]) -> str:
    return (f"{len(problems)} problem(s); replay one with "
            "tests.faults.printer_campaign.replay(id)\n" + "\n".join(problems[:10]))


def test_the_scenario_writes_every_medium_while_the_job_prints_and_uploads(rec):
    media = [w.medium for w in rec.writes]
    last_chunk = max(n for n, w in enumerate(rec.writes) if w.medium == "card")
    during_upload = set(media[:last_chunk])
    assert {"head", "reel0"} <= during_upload  # head hours and filament booked meanwhile
    assert media.count("card") >= 30
    flash = [w for w in rec.writes if w.medium == "flash"]
    assert [w.address for w in flash] == [HOURS_PAGE]  # the job's hours, once it ended
    assert flash[0].time > rec.writes[last_chunk].time
    remaining = {w.intents[1][0xB8:0xC0] for w in rec.writes[:last_chunk]}
    assert len(remaining) >= 3  # the reel's remaining filament changed during the upload
    state = campaign.files_of(rec.final)
    assert (make_id(campaign.JOB_ID), campaign.job_digest()) in state.files


def test_every_write_cut_whole_or_torn_leaves_a_legal_printer(rec):
    judge = campaign.Judge(rec)
    problems, count = [], 0
    for case in campaign.cases(rec):
        problems += judge.check(case)
        count += 1
    assert count >= 2 * len(rec.writes)
    assert not problems, report(problems)


def test_survivors_that_share_an_upload_verdict_upload_alike(rec):
    """The premise of sharing the upload's verdict (campaign.Judge): survivors with the
    same card but different EEPROMs (cut during the chips' own writes, whole or
    garbled, with the bookkeeping's images years apart) upload the job again to the same
    card bytes."""
    builder = campaign.MediaBuilder(rec)
    groups = {}
    for case in campaign.cases(rec):
        if rec.writes[case.write - 1].medium in ("head", "reel0"):
            groups.setdefault(builder.card_key(case), []).append(case)
    groups = [g for g in groups.values() if len(g) > 4]
    assert len(groups) >= 4
    compared = 0
    for group in groups[:: max(1, len(groups) // 6)]:
        cards = set()
        chosen = (group[0], group[len(group) // 2], group[-1])
        assert len({builder.survivor(case).chips for case in chosen}) == 3
        for case in chosen:
            media = builder.survivor(case)
            virtual = VirtualPrinter(media=media)
            virtual.settle()
            printer = campaign.connect(virtual)
            printer.clear_errors()
            sent = printer.send_file(campaign.JOB, campaign.JOB_ID, resume=True)
            assert sent.restarted
            cards.add(virtual.hw.card.storage.read(0, campaign.CARD_BLOCKS * 512))
            compared += 1
        assert len(cards) == 1, group[0].id
    assert compared >= 12


def test_the_recorded_survivor_is_what_a_real_cut_leaves(rec):
    """The shortcut is exact: a cut after every card and flash write, torn ones and EEPROM
    ones across the run, replayed from the top through the PowerPlan, leave the bytes the
    campaign judged."""
    builder = campaign.MediaBuilder(rec)
    every = campaign.cases(rec)
    chosen = [c for c in every if rec.writes[c.write - 1].medium in ("card", "flash")
              and c.mode in ("whole", "partial")]
    chosen += [c for c in every if c.mode in ("mix", "prefix", "erase")][::4]
    chosen += [c for c in every if rec.writes[c.write - 1].medium in ("head", "reel0")][::40]
    for case in chosen:
        assert campaign.replay(case.id) == builder.survivor(case), case.id


def test_the_reel_judge_sees_a_value_that_was_never_written(rec):
    """The judge can fail: a reel image nobody wrote is refused."""
    builder = campaign.MediaBuilder(rec)
    case = campaign.Case("whole", len(rec.writes))
    media = builder.survivor(case)
    reel = bytearray(media.chips[EepromIndex.REEL0])
    virtual = VirtualPrinter(media=media)
    virtual.settle()
    virtual.firmware.eeproms.set_float(EepromIndex.REEL0, "remaining_filament", 1234.5)
    virtual.settle()
    reel = bytes(virtual.hw.eeprom_bus.sockets[EepromIndex.REEL0].data)
    forged = type(media)(media.card, (media.chips[0], reel, None), media.flash)
    problems = campaign.judge_printer(rec, case, forged)
    assert problems == ["reel0 EEPROM loaded an image that was not one of the last two written"]


def test_send_job_resume_after_a_power_cut_sends_the_job_again(tmp_path):
    """robox-cli, as a user runs it: the printer lost the upload with its power, so
    --resume sends the file again from the start and leaves the cut print unstarted."""
    state = tmp_path / "printer"
    job = tmp_path / "part.gcode"
    job.write_bytes(campaign.JOB)
    with VirtualPrinter(state) as virtual:
        virtual.settle()
        virtual.supply(PowerPlan(cut_at=12, landing=Landing("mix", 3)))
        with pytest.raises(PowerCut):
            campaign.scenario(virtual)
    args = ["--device", f"sim-once:{state}", "send-job", str(job), "--raw", "--id", "part",
            "--resume"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "sending it again from the start" in result.output
    assert "not printing" in result.output and "run-job part" in result.output
    with VirtualPrinter(state) as virtual:
        fs = virtual.firmware.file_system
        assert fs.read_committed(make_id("part")) == campaign.JOB
        assert virtual.firmware.job.job_id is None

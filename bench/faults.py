#!/usr/bin/env python3
"""Fault campaigns: cut points judged per second, for the card alone and the whole printer.

Usage: python bench/faults.py [--quick]
Prints figures; asserts nothing. The card campaign mounts each survivor with the
file system alone; the printer campaign powers a whole virtual printer up on each
survivor (card, EEPROMs, flash), lets it load, and sends the job again. The
two-programs campaign runs `robox-cli sdcard put` writers at once on one image,
refusing and then waiting for the lock, with one of them killed -9 in each round,
and judges every round (stored files whole, the card mountable, each refusal one
line).
"""

import random
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from robox.native import build  # noqa: E402
from tests.faults import campaign, printer_campaign  # noqa: E402


def measure(label: str, record, cases, check, limit: int | None):
    start = time.perf_counter()
    rec = record()
    recorded = time.perf_counter() - start
    chosen = list(cases(rec))[:limit]
    start = time.perf_counter()
    illegal = sum(bool(check(rec, case)) for case in chosen)
    elapsed = time.perf_counter() - start
    print(f"{label}: {len(rec.writes)} writes recorded in {recorded * 1000:.0f} ms")
    print(f"  {len(chosen)} cut points in {elapsed:.2f} s: {len(chosen) / elapsed:,.0f} "
          f"cut points/s, {illegal} illegal end states")
    return rec, chosen


def main() -> None:
    print(f"measuring {build()}")
    quick = "--quick" in sys.argv
    card_media = {}

    def card_check(rec, case):
        media = card_media.setdefault(id(rec), campaign.Media(rec))
        return campaign.check(rec, media, case)

    measure("card campaign (file system alone)", campaign.record, campaign.cases, card_check,
            2000 if quick else None)
    judges = {}

    def printer_check(rec, case):
        judge = judges.setdefault(id(rec), printer_campaign.Judge(rec))
        return judge.check(case)

    rec, chosen = measure("printer campaign (print while uploading, whole printer)",
                          printer_campaign.record, printer_campaign.cases, printer_check,
                          150 if quick else None)
    media = Counter(rec.writes[case.write - 1].medium for case in chosen)
    print("  cut points by medium: " + ", ".join(f"{k} {v}" for k, v in sorted(media.items())))
    two_programs(5 if quick else 20)


def writers_round(tmp: Path, rng: random.Random, writers: int, wait: bool) -> dict:
    """One round: `writers` puts at once on a fresh image (one killed -9 when `wait`)."""
    from robox.offline.sdcard import format_image, fsck_image, get_file, list_image

    card = tmp / "card.img"
    card.unlink(missing_ok=True)
    format_image(card, 65536)
    parts = []
    for n in range(writers):
        part = tmp / f"part{n}.gcode"
        # a job as it goes to the card (CR ends, no comments): put --job stores it as it is
        part.write_bytes(f"G1 X{n + 1}\r".encode() * rng.randint(100_000, 300_000))
        parts.append(part)
    options = ["--wait-lock", "120"] if wait else []
    runs = [subprocess.Popen([sys.executable, "-m", "robox.cli", *options, "sdcard", "put",
                              str(card), str(p), "--id", p.stem, "--job"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE) for p in parts]
    victim = rng.randrange(writers) if wait else None
    if victim is not None:
        time.sleep(rng.uniform(0.05, 1.0))
        runs[victim].send_signal(signal.SIGKILL)
    out = Counter()
    problems = []
    errs = [run.communicate()[1] for run in runs]  # all done before the card is read
    for n, (part, run, err) in enumerate(zip(parts, runs, errs, strict=True)):
        lines = err.decode().strip().splitlines()
        if run.returncode == 0:
            out["stored"] += 1
            if get_file(card, part.stem) != part.read_bytes():
                problems.append(f"{part.stem} reported stored, not on the card whole")
        elif n == victim:
            out["killed"] += 1
        elif len(lines) == 1 and " is in use by PID " in lines[0]:
            out["refused"] += 1
        else:
            problems.append(f"{part.stem}: exit {run.returncode}: {lines}")
    if fsck_image(card)["project"]["action"] == "format":
        problems.append("a printer would format the card")
    out["on card"] = len(list_image(card)["files"])
    out["problems"] = len(problems)
    return out


def two_programs(rounds: int) -> None:
    rng = random.Random(1)
    for wait in (False, True):
        totals = Counter()
        start = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            for _ in range(rounds):
                totals += writers_round(Path(tmp), rng, 4, wait)
        elapsed = time.perf_counter() - start
        how = "waiting for the lock, one killed -9 a round" if wait else "refused when held"
        print(f"two programs: {rounds} rounds of 4 sdcard put at once on one image, {how}: "
              f"{elapsed:.1f} s, {rounds / elapsed:.2f} rounds/s")
        print("  " + ", ".join(f"{k} {totals[k]}" for k in
                               ("stored", "refused", "killed", "on card", "problems")))


if __name__ == "__main__":
    main()

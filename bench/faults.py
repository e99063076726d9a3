#!/usr/bin/env python3
"""Fault campaigns: cut points judged per second, for the card alone and the whole printer.

Usage: python bench/faults.py [--quick]
Prints figures; asserts nothing. The card campaign mounts each survivor with the
file system alone; the printer campaign powers a whole virtual printer up on each
survivor (card, EEPROMs, flash), lets it load, and sends the job again.
"""

import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

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


if __name__ == "__main__":
    main()

"""Handler of ``milling-twin sweep`` (options in :mod:`milling_twin.cli`): the study run, then what it gave."""
from __future__ import annotations

import argparse
from collections.abc import Mapping

from milling_twin import api

MAX_LISTED = 10  # failed cases listed with their message


def phase_text(phases: Mapping[str, float]) -> str:
    """``executor start 0.81 s, cases 5.2 s, ...``: where a sweep's wall time went."""
    return ", ".join(f"{name} {seconds:.2g} s" for name, seconds in phases.items())


def command(args: argparse.Namespace) -> int:
    folder = args.out / "<study>"
    try:
        result = api.sweep(args.study, fmu_dir=args.fmu_dir, out=args.out, workers=args.workers,
                           scheduler=args.scheduler, resume=args.resume, progress=not args.no_progress)
    except KeyboardInterrupt as exc:
        exc.add_note(f"the finished cases are kept in {folder}/summary/; --resume runs the others")
        raise
    summary = result.summary
    where = ("serial, in this process" if result.workers == 0 else
             "the scheduler's workers" if args.scheduler else
             f"{result.workers} local workers" if result.workers else "the embedded local cluster")
    print(f"{result.name}: {len(summary)} of {result.ran + result.skipped} cases in the summary "
          f"({result.ran} run, {result.skipped} finished before), {result.failed} failed; "
          f"{result.wall_time:.3g} s on {where} ({phase_text(result.phases)})")
    failed = summary[summary["status"] != "ok"]
    for _, row in failed.head(MAX_LISTED).iterrows():
        print(f"failed {row['case_id']}: {row['error']}")
    if len(failed) > MAX_LISTED:
        print(f"... and {len(failed) - MAX_LISTED} more (summary column 'error')")
    print(f"summary: {result.summary_file} (and summary.csv, one file per case in summary/); "
          f"runs: {result.folder / 'cases'}/<case id>/")
    return 0

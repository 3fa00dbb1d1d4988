"""Handler of ``milling-twin optimize`` (options in :mod:`milling_twin.cli`): the optimization, then what it gave."""
from __future__ import annotations

import argparse

from milling_twin import api


def command(args: argparse.Namespace) -> int:
    result = api.optimize(args.part, fmu_dir=args.fmu_dir, out=args.out, objective=args.objective,
                          max_iterations=args.max_iterations,
                          sub_blocks=False if args.no_sub_blocks else None, workers=args.workers,
                          progress=not args.no_progress, echo=print)
    original, best = result.original, result.best
    p0, p1 = max(original.peak_force.values(), default=0.0), max(best.peak_force.values(), default=0.0)
    print(f"{result.name}: cycle time {original.cycle_time:.2f} s -> {best.cycle_time:.2f} s "
          f"({(best.cycle_time / original.cycle_time - 1) * 100:+.1f} %), largest force {p0:.4g} N -> {p1:.4g} N "
          f"({(p1 / p0 - 1) * 100 if p0 > 0 else 0.0:+.1f} %); iteration {best.number} of "
          f"{len(result.iterations) - 1} ({result.stopped}); {result.wall_time:.0f} s")
    for note in result.notes:
        print(f"note: {note}")
    print(f"optimized program: {result.program}")
    print(f"report: {result.report}")
    return 0

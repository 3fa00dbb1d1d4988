"""Benchmark of the feed optimizer (``milling-twin optimize``) on the committed whole parts: for each part and each
objective, the cycle time and largest force of the original and of the optimized program, both from the twin's
runs, with one feed per line and with lines split into sub-blocks where their engagement changes; the iterations,
the program's blocks, the sub-blocks of the best program, what the best re-simulation breaks (limits by more than the tolerance,
chatter the original did not have: 0 for a result) and the wall time of the whole optimization. A script, not a
timed test:

    .venv/bin/python tests/benchmarks/optimize_parts.py [--parts al_bracket al_plate] [--objectives time force] [--sub-blocks off on]

The parts' ``[optimize]`` sections hold their limits (scenarios/al_bracket.toml, scenarios/al_plate.toml); umich_part.toml
has none: the defaults (the original's largest force, at most twice the program's chip load).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

import milling_twin

REPO = Path(__file__).resolve().parents[2]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--parts", nargs="+", default=["al_bracket", "al_plate", "umich_part"])
    parser.add_argument("--objectives", nargs="+", choices=("time", "force"), default=["time", "force"])
    parser.add_argument("--sub-blocks", nargs="+", choices=("off", "on"), default=["off", "on"],
                        help="one feed per line (off), lines split where their engagement changes (on), or both")
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus")
    args = parser.parse_args()
    print(f"{'part':>11} {'objective':>9} {'split':>5} {'blocks':>6} {'cycle s: before':>15} {'after':>7} {'change':>7} "
          f"{'peak N: before':>14} {'after':>7} {'change':>7} {'best/iterations':>15} {'broken':>6} {'wall s':>6} {'sub-blocks':>9}")
    with tempfile.TemporaryDirectory() as out:
        for name in args.parts:
            for objective, split in ((o, b) for o in args.objectives for b in args.sub_blocks):
                start = time.perf_counter()
                result = milling_twin.optimize(REPO / "scenarios" / f"{name}.toml", fmu_dir=args.fmu_dir, out=out,
                                               objective=objective, sub_blocks=split == "on")
                wall = time.perf_counter() - start
                original, best = result.original, result.best
                blocks = len(pd.read_parquet(best.run_dir / "blocks.parquet"))
                p0, p1 = max(original.peak_force.values()), max(best.peak_force.values())
                parts = len(result.sub_blocks.parts) if result.sub_blocks and best.sub_blocks else 0
                print(f"{name:>11} {objective:>9} {split:>5} {blocks:>6} {original.cycle_time:>15.2f} {best.cycle_time:>7.2f} "
                      f"{(best.cycle_time / original.cycle_time - 1) * 100:>+6.1f}% {p0:>14.1f} {p1:>7.1f} "
                      f"{(p1 / p0 - 1) * 100:>+6.1f}% {best.number:>7}/{len(result.iterations) - 1:<7} "
                      f"{len(best.violations):>6} {wall:>6.0f} {parts:>9}", flush=True)
                for note in result.notes:
                    print(f"{'':>11} note: {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark of the feed optimizer's spindle speeds: a slot that chatters moved to a stable pocket, per programmed
speed. The tiny test part (tests/cases/part_case.py: a 10 mm 3-flute end mill slotting a 50 mm aluminium block)
on the flexible tool of scenarios/chatter.toml (922 Hz, 1.1 % damping, 1.34e6 N/m in x and y), cut DEPTH deep, is
optimized at each programmed speed with the speed taken from the tool's simulated stability map and from the
zero-order lobes. Per case: whether the original's slot chatters (the process report's indicator; "diverged": its
vibration grew beyond the FMUs' range and the run failed there), the speed
chosen, whether the simulated map has it stable at 1.25 x the depth, whether the re-simulated slot chatters, the
cycle times and the wall time. Then the same for the aluminium bracket (scenarios/al_bracket.toml) with a
long-reach tool: its tip modes replaced by 700 Hz, 3 % damping, 1.0e7 N/m in x and y (a 10 mm end mill on about
35 mm of stick-out; assumed), at which its 1.5 mm slots and pocket chatter at the programmed 11000 rpm, and its
deflection limit 75 um instead of 25 (the tool's forced response alone exceeds 25 um at any feed). A script, not a
timed test:

    .venv/bin/python tests/benchmarks/optimize_chatter.py [--speeds 4800 5850 6600 7200] [--depth 0.1] [--no-bracket]
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
sys.path.insert(0, str(REPO / "tests"))

from cases.part_case import MODES, PROGRAM, write_part  # noqa: E402

FLEXIBLE = "[ { frequency = 922.0, damping = 0.011, stiffness = 1.34e6 } ]"
LONG_REACH = "frequency = 700.0, damping = 0.03, stiffness = 1.0e7"


def long_reach_bracket(folder: Path) -> Path:
    """scenarios/al_bracket.toml with the long-reach tool's modes and a 75 um deflection limit, its paths made
    absolute, in ``folder``."""
    text = (REPO / "scenarios" / "al_bracket.toml").read_text()
    edits = [('program = "parts/', f'program = "{REPO}/scenarios/parts/'),
             ('tool_table = "parts/', f'tool_table = "{REPO}/scenarios/parts/'),
             ("frequency = 2800.0, damping = 0.03, stiffness = 2.0e7", LONG_REACH),
             ('deflection = { value = 25, unit = "um" }', 'deflection = { value = 75, unit = "um" }'),
             ('name = "al_bracket"', 'name = "al_bracket_long_reach"')]
    for old, new in edits:
        if old not in text:
            raise SystemExit(f"scenarios/al_bracket.toml has no {old!r} any more: update this benchmark")
        text = text.replace(old, new)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "al_bracket_long_reach.toml"
    path.write_text(text)
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speeds", nargs="+", type=float, default=[4800, 5400, 5850, 6600, 7200, 8000])
    parser.add_argument("--depth", type=float, default=0.1, help="axial depth of the slot, mm")
    parser.add_argument("--sources", nargs="+", choices=("simulated", "zero-order"),
                        default=["simulated", "zero-order"])
    parser.add_argument("--no-bracket", action="store_true", help="leave out the long-reach bracket")
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus")
    args = parser.parse_args()
    print(f"{'rpm':>6} {'source':>10} {'chatter before':>14} {'chosen rpm':>10} {'stable in map':>13} "
          f"{'chatter after':>13} {'cycle s':>14} {'wall s':>6}")
    with tempfile.TemporaryDirectory() as out:
        for speed in args.speeds:
            for source in args.sources:
                folder = Path(out) / f"{speed:.0f}_{source}"
                part = write_part(folder / "part", (MODES, f"[part.tool_modes]\nx = {FLEXIBLE}\ny = {FLEXIBLE}\n"),
                                  ("[part.spindle]", f'[optimize]\nmax_iterations = 2\nspeed_from = "{source}"\n'
                                                     f"[part.spindle]"),
                                  program=PROGRAM.replace("G1 Z-2 F300", f"G1 Z-{args.depth:g} F300")
                                  .replace("S6000", f"S{speed:.0f}"))
                start = time.perf_counter()
                try:
                    result = milling_twin.optimize(part, fmu_dir=args.fmu_dir, out=folder / "runs")
                except Exception as exc:  # the original run itself may fail: its vibration out of range
                    print(f"{speed:>6.0f} {source:>10} {'':>14} the optimization failed: {str(exc)[:110]}")
                    continue
                wall = time.perf_counter() - start
                table = pd.read_csv(result.folder / "blocks_before_after.csv")
                slot = table[table["line"] == 6]
                before = bool(slot["chatter before"].astype(bool).any())
                after = bool(slot["chatter after"].astype(bool).any())
                choice = result.speeds.get(1)
                chosen = f"{choice.chosen:.0f}" if choice else "kept"
                stable = "" if choice is None or choice.stable_chosen is None else str(choice.stable_chosen)
                failed = result.original.status != "completed"   # the vibration left the FMUs' range
                before_text = "diverged" if failed else str(before)
                cycle = f"{'failed' if failed else f'{result.original.cycle_time:.2f}'}->{result.best.cycle_time:.2f}"
                print(f"{speed:>6.0f} {source:>10} {before_text:>14} {chosen:>10} {stable:>13} {str(after):>13} "
                      f"{cycle:>14} {wall:>6.0f}", flush=True)
                for note in result.notes:
                    print(f"{'':>6} note: {note}")
        if args.no_bracket:
            return 0
        part = long_reach_bracket(Path(out) / "bracket")
        print(f"\nal_bracket with the long-reach tool ({LONG_REACH}), 11000 rpm programmed")
        print(f"{'source':>10} {'chatter blocks before':>21} {'chosen rpm':>10} {'stable in map':>13} "
              f"{'chatter blocks after':>20} {'cycle s':>14} {'peak N':>14} {'feasible':>8} {'wall s':>6}")
        for source in args.sources:
            text = part.read_text().replace('objective = "time"\n', f'objective = "time"\nspeed_from = "{source}"\n', 1)
            variant = part.with_name(f"al_bracket_long_reach_{source}.toml")
            variant.write_text(text.replace('name = "al_bracket_long_reach"',
                                            f'name = "al_bracket_long_reach_{source.replace("-", "_")}"'))
            start = time.perf_counter()
            result = milling_twin.optimize(variant, fmu_dir=args.fmu_dir, out=Path(out) / "bracket_runs")
            wall = time.perf_counter() - start
            original, best = result.original, result.best
            before = pd.read_parquet(original.run_dir / "blocks.parquet")["chatter"].astype(bool).sum()
            after = pd.read_parquet(best.run_dir / "blocks.parquet")["chatter"].astype(bool).sum()
            choice = result.speeds.get(1)
            chosen = f"{choice.chosen:.0f}" if choice else "kept"
            stable = "" if choice is None or choice.stable_chosen is None else str(choice.stable_chosen)
            p0, p1 = max(original.peak_force.values()), max(best.peak_force.values())
            print(f"{source:>10} {before:>21} {chosen:>10} {stable:>13} {after:>20} "
                  f"{original.cycle_time:>6.2f}->{best.cycle_time:<6.2f} {p0:>6.1f}->{p1:<6.1f} "
                  f"{str(best.feasible):>8} {wall:>6.0f}", flush=True)
            for note in result.notes:
                print(f"{'':>10} note: {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The Interpolator against the independent checker (tests/interp_checker.py), the long run: >= 500 seeded random
NURBS (seven families) and every corpus program (scenarios/programs/corpus/), through the C engine
build/tools/interp_run. Prints per family: curves, curves with a limit broken by more than 0.1 % (per quantity:
how many and the worst excess), unfinished runs, the time ratio to the acceleration-limited bound (mean, median,
max); per corpus program: the figures or the engine's refusal. A script, not a timed test:

    .venv/bin/python tests/benchmarks/interpolator_checks.py [--curves 504] [--no-corpus]
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests"))

import interp_checker as ic  # noqa: E402
from test_interpolator_checker import corpus_options, corpus_programs  # noqa: E402


def random_curves(n: int, work: Path) -> None:
    stats = defaultdict(lambda: {"n": 0, "bad": 0, "unfinished": 0, "ratios": [], "excess": defaultdict(list)})
    for seed in range(n):
        family, curve, rep = ic.check_random(seed, work)
        st = stats[family]
        st["n"] += 1
        st["bad"] += bool(rep.violations)
        ratio = rep.figures.get("time_ratio", math.inf)
        if math.isfinite(ratio):
            st["ratios"].append(ratio)
        for name, measured, bound, excess in rep.violations:
            if name == "not_finished":
                st["unfinished"] += 1
            else:
                st["excess"][name].append(excess)
    print(f"## {n} random NURBS (seeds 0..{n - 1})\n")
    print("| family | curves | with a violation > 0.1 % | not finished | time / bound mean | median | max | "
          "violations (curves, worst excess) |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    total = bad = 0
    for family in ic.FAMILIES:
        st = stats[family]
        total += st["n"]
        bad += st["bad"]
        r = np.array(st["ratios"]) if st["ratios"] else np.array([math.nan])
        worst = "; ".join(f"{name} {len(v)}, {'inf' if math.isinf(max(v)) else f'+{max(v) * 100:.2f} %'}"
                          for name, v in sorted(st["excess"].items()))
        print(f"| {family} | {st['n']} | {st['bad']} | {st['unfinished']} | {r.mean():.3f} | {np.median(r):.3f} | "
              f"{r.max():.3g} | {worst or '-'} |")
    print(f"\n{bad} of {total} curves break a limit by more than 0.1 %\n")


def corpus(work: Path) -> None:
    lim = ic.default_limits()
    print("## corpus\n")
    print("| program | result | time s | moving time / bound | violations |")
    print("|---|---|---:|---:|---|")
    for program in corpus_programs():
        name = f"{program.parent.name}/{program.name}"
        try:
            traj = ic.run_engine(program, {}, workdir=work, timeout=300.0, options=corpus_options(program))
        except (ic.EngineError, ic.EngineTimeout) as exc:
            print(f"| {name} | refused: {str(exc).replace('|', '/')} | | | |")
            continue
        rep = ic.check(traj, lim, line_feed=ic.line_feeds(program.read_text(), lim))
        f = rep.figures
        viol = "; ".join(f"{n} {m:.4g} > {b:.4g}" + (f" (+{x * 100:.2f} %)" if math.isfinite(x) else "")
                         for n, m, b, x in rep.violations)
        print(f"| {name} | runs | {f['time']:.3f} | {f['time_ratio']:.3f} | {viol or '-'} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--curves", type=int, default=504)
    parser.add_argument("--no-corpus", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        random_curves(args.curves, work)
        if not args.no_corpus:
            corpus(work)


if __name__ == "__main__":
    main()

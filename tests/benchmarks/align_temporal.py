"""Temporal alignment benchmark on known warps of real UMich paths (10 Hz recordings).

    .venv/bin/python tests/benchmarks/align_temporal.py [--experiments 01 04 06 08 09]
        [--data DIR] [--figure scenarios/figures/align_temporal.png]

For each experiment, the recorded positions become a smooth "simulated" path at 100 Hz
(:func:`cases.align_synthetic.path_from_umich`), played through a random warp of each
kind (``affine``: start offset -3..8 s and global scale 0.8..1.25; ``piecewise``: + 3..6 feed
override changes 0.6..1.5; ``pause``: + one pause of 5..30 s; ``all``: overrides, two pauses,
idle tail, 3 dropout gaps of 0.5..3 s and 2 % dropped samples) and recorded at 10 Hz with
0.01 mm noise and 3-significant-digit storage (1 mm steps above 100 mm, 0.1 mm below, as in
the data). Each method maps every recorded sample to simulated time; the error is the
difference to the true simulated time. Reported per kind and method: median and 95th
percentile of the error over all samples of all experiments (ms), the same over samples where
the simulation moves (> 0.5 mm/s at the true time), and the total wall time, with the time
ratio to the dtaidistance baseline run on the same cases.
"""
from __future__ import annotations

import sys
import argparse
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from milling_twin.orchestrator.align import align
from milling_twin.orchestrator.align.plots import plot_temporal
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the generated cases (tests/cases)

from cases.align_synthetic import make_recording, path_from_umich, random_warp, umich_data_dir

REPO = Path(__file__).resolve().parents[2]
KINDS = ("affine", "piecewise", "pause", "all")
METHODS = ("multiscale", "dtw", "patent")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--experiments", nargs="+", default=["01", "04", "06", "08", "09"])
    parser.add_argument("--data")
    parser.add_argument("--figure", type=Path, default=REPO / "scenarios" / "figures" /
                        "align_temporal.png")
    args = parser.parse_args()
    folder = umich_data_dir(args.data)
    errors = {(k, m): [] for k in KINDS for m in METHODS}
    moving = {(k, m): [] for k in KINDS for m in METHODS}
    wall = {(k, m): 0.0 for k in KINDS for m in METHODS}
    samples = {k: 0 for k in KINDS}
    figure_case = None
    cases = [(e, k) for e in args.experiments for k in KINDS]
    for exp, kind in tqdm(cases, desc="cases"):
        sim = path_from_umich(folder / f"experiment_{exp}.csv")
        rng = np.random.default_rng(1000 * int(exp) + KINDS.index(kind))
        warp = random_warp(kind, sim.time[-1], rng)
        extra = {"gaps": 3, "drop": 0.02} if kind == "all" else {}
        rec = make_recording(sim, warp, sample_period=0.1, noise=0.01, rng=rng, **extra)
        speed = np.linalg.norm(np.interp(rec.truth, sim.time, np.linalg.norm(
            sim.velocity(), axis=1))[:, None], axis=1)
        samples[kind] += len(rec.trajectory)
        for method in METHODS:
            start = time.perf_counter()
            tm = align(rec.trajectory, sim, method)
            wall[kind, method] += time.perf_counter() - start
            err = np.abs(tm.simulated_time - rec.truth) * 1000
            errors[kind, method].append(err)
            moving[kind, method].append(err[speed > 0.5])
            if exp == args.experiments[0] and kind == "all" and method == "multiscale":
                figure_case = (rec, sim, tm)
    print(f"\ndata: {folder}; experiments {' '.join(args.experiments)}; 10 Hz recordings, "
          f"simulated paths at 100 Hz\n")
    print("| warp | samples | method | median error (ms) | p95 error (ms) | median / p95, "
          "moving (ms) | wall time (s) | time / dtw |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    for kind in KINDS:
        for method in METHODS:
            e = np.concatenate(errors[kind, method])
            mv = np.concatenate(moving[kind, method])
            print(f"| {kind} | {samples[kind]} | {method} | {np.median(e):.1f} | "
                  f"{np.percentile(e, 95):.1f} | {np.median(mv):.1f} / "
                  f"{np.percentile(mv, 95):.1f} | {wall[kind, method]:.2f} | "
                  f"{wall[kind, method] / wall[kind, 'dtw']:.2f} |")
    if figure_case is not None and args.figure:
        rec, sim, tm = figure_case
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        plot_temporal(rec.trajectory, sim, tm, args.figure, truth=rec.truth,
                      title=f"experiment_{args.experiments[0]}: warp 'all' (overrides, 2 pauses, "
                            f"dropouts), 10 Hz, stored in 1 mm / 0.1 mm steps")
        print(f"\nfigure: {args.figure} ({args.figure.stat().st_size // 1024} kB)")


if __name__ == "__main__":
    main()

"""Scale benchmark: a 2-hour recording at 100 Hz (720,000 samples) aligned to its simulation.

    .venv/bin/python tests/benchmarks/align_scale.py [--repeat 3] [--data DIR]

The simulated path is the twelve UMich experiments one after another (smooth paths at 100 Hz,
joined by 2 s moves, 7600 s). The recording plays it with a start offset of 5 s, a global
scale of 0.97, 12 feed-override changes (0.7..1.4) and two pauses (40 s and 15 s), sampled at
100 Hz with 0.01 mm noise and 3-significant-digit storage, cut to 720,000 samples (the program
runs on past the end of the recording). Each alignment runs in a child process, which reports
its wall time and peak resident memory (ru_maxrss) before and after aligning; best and median
of ``--repeat`` runs. The baseline, dtaidistance full DTW, cannot run at this size (720,000 x
~760,000 cells, 4 TB); it is compared with the multiscale method on the first 1, 2 and 3
minutes of the same case (same process, same inputs) to give the ratio.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.align import Trajectory, align
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the generated cases (tests/cases)

from cases.align_synthetic import Warp, concatenate_paths, make_recording, path_from_umich, umich_data_dir

REPO = Path(__file__).resolve().parents[2]
N = 720_000


def make_case(folder: Path) -> tuple[Trajectory, Trajectory, np.ndarray]:
    paths = [path_from_umich(folder / f"experiment_{e:02d}.csv", rate=100) for e in range(1, 13)]
    sim = concatenate_paths(paths, 7600.0)
    rng = np.random.default_rng(7)
    starts, factors = np.sort(rng.uniform(0, 7000, 12)), rng.uniform(0.7, 1.4, 12)
    warp = Warp(start=5.0, scale=0.97, overrides=tuple(zip(starts.tolist(), factors.tolist())),
                pauses=((1234.5, 40.0), (4321.0, 15.0)))
    rec = make_recording(sim, warp, sample_period=0.01, noise=0.01, rng=rng)
    t, p = rec.trajectory.time[:N], rec.trajectory.position[:N]
    return Trajectory(t, p, "2 h at 100 Hz"), sim, rec.truth[:N]


def child(npz: Path) -> None:
    d = np.load(npz)
    rec, sim = Trajectory(d["rt"], d["rp"]), Trajectory(d["st"], d["sp"])
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    start = time.perf_counter()
    tm = align(rec, sim)
    wall = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    err = np.abs(tm.simulated_time - d["truth"]) * 1000
    print(json.dumps({"wall": wall, "rss_before_mb": before, "rss_peak_mb": peak,
                      "median_ms": float(np.median(err)), "p95_ms": float(np.percentile(err, 95)),
                      "within_10ms": float(np.mean(err < 10)), "levels": tm.info["levels"]}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--data")
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child)
        return
    rec, sim, truth = make_case(umich_data_dir(args.data))
    print(f"case: {len(rec)} recorded samples ({rec.duration / 3600:.2f} h at 100 Hz), "
          f"{len(sim)} simulated samples")
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "case.npz"
        np.savez(npz, rt=rec.time, rp=rec.position, st=sim.time, sp=sim.position, truth=truth)
        runs = []
        for _ in range(args.repeat):
            out = subprocess.run([sys.executable, __file__, "--child", str(npz)], check=True,
                                 capture_output=True, text=True, cwd=REPO)
            runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    walls = [r["wall"] for r in runs]
    r = runs[0]
    print(f"multiscale, {len(rec)} samples: wall best {min(walls):.2f} s, median "
          f"{float(np.median(walls)):.2f} s over {len(walls)} runs; peak RSS {r['rss_peak_mb']:.0f}"
          f" MB (process after loading the case: {r['rss_before_mb']:.0f} MB, so the alignment "
          f"adds {r['rss_peak_mb'] - r['rss_before_mb']:.0f} MB); error median "
          f"{r['median_ms']:.2f} ms, p95 {r['p95_ms']:.1f} ms, {100 * r['within_10ms']:.1f} % "
          f"within one sample period (10 ms); levels {[x['samples'] for x in r['levels']]}")
    print("\n| first minutes | samples | dtw (s) | multiscale (s) | dtw / multiscale | "
          "median error dtw / multiscale (ms) |")
    print("|---:|---:|---:|---:|---:|---:|")
    for minutes in (1, 2, 3):
        n = minutes * 6000
        sub = Trajectory(rec.time[:n], rec.position[:n])
        tail = truth[n - 1] + 10.0  # the part of the program the prefix can reach, with margin
        keep = sim.time <= tail
        sub_sim = Trajectory(sim.time[keep], sim.position[keep])
        res = {}
        for method in ("dtw", "multiscale"):
            start = time.perf_counter()
            tm = align(sub, sub_sim, method)
            res[method] = (time.perf_counter() - start,
                           float(np.median(np.abs(tm.simulated_time - truth[:n]) * 1000)))
        print(f"| {minutes} | {n} | {res['dtw'][0]:.2f} | {res['multiscale'][0]:.2f} | "
              f"{res['dtw'][0] / res['multiscale'][0]:.1f} | {res['dtw'][1]:.1f} / "
              f"{res['multiscale'][1]:.1f} |")


if __name__ == "__main__":
    main()

"""A study serially and on N local dask workers, in one process, alternately (docs/studies.md).

    .venv/bin/python tests/benchmarks/study_workers.py [STUDY] [--workers 2] [--repeats 2] [--stop-time S]
                                                       [--fmu-dir build/fmus]

Per repeat and executor: the sweep's wall time (cluster start and close included), the sum of the cases' own wall
times (on their workers), and the ratio serial / parallel. Then the engine's cost: the embedded cluster's start and
close, and the round trip of 200 trivial tasks through its executor (s per task). The load average is printed
before and after: on a shared machine other processes take cores too.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from concurrent.futures import wait
from dataclasses import replace
from pathlib import Path

from milling_twin.orchestrator.study.executor import open_executor
from milling_twin.orchestrator.study.run import sweep
from milling_twin.orchestrator.study.spec import load_study

REPO = Path(__file__).resolve().parents[2]


def nothing(i: int) -> int:
    return i


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path, nargs="?", default=REPO / "studies" / "spindle_depth.toml")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--stop-time", type=float, default=None, help="instead of the study's stop_time (s)")
    parser.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get("MILLING_TWIN_FMU_DIR", "build/fmus")))
    args = parser.parse_args()
    study = load_study(args.study, args.fmu_dir)
    if args.stop_time is not None:
        study = replace(study, stop_time=args.stop_time)
    print(f"{study.name}: {len(study.cases)} cases, stop time {study.scenario().stop_time:g} s; "
          f"load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="study-bench-") as folder:
        for repeat in range(args.repeats):
            walls = {}
            for workers in (0, args.workers):
                result = sweep(study, Path(folder) / str(workers), workers=workers, progress=False)
                walls[workers] = result.wall_time
                print(f"repeat {repeat + 1}, workers={workers}: {result.wall_time:.2f} s "
                      f"(cases' own {result.summary['wall_time'].sum():.2f} s; {result.failed} failed)")
            print(f"repeat {repeat + 1}: serial / {args.workers} workers = {walls[0] / walls[args.workers]:.2f}")
    t0 = time.perf_counter()
    with open_executor(workers=args.workers) as executor:
        t1 = time.perf_counter()
        wait([executor.submit(nothing, i) for i in range(args.workers)])  # the workers' first task
        t2 = time.perf_counter()
        wait([executor.submit(nothing, i) for i in range(200)])
        t3 = time.perf_counter()
    t4 = time.perf_counter()
    print(f"engine: cluster of {args.workers} started in {t1 - t0:.2f} s, closed in {t4 - t3:.2f} s; "
          f"200 trivial tasks in {t3 - t2:.3f} s = {1e3 * (t3 - t2) / 200:.1f} ms per task; "
          f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

"""A study serially and on N local dask workers, in one process, alternately (docs/studies.md).

    .venv/bin/python tests/benchmarks/study_workers.py [STUDY] [--workers 2] [--repeats 2] [--stop-time S]
                                                       [--fmu-dir build/fmus] [--baseline] [--ceiling]
                                                       [--command]

Per repeat and executor: the sweep's wall time (cluster start and close included), the sum of the cases' own wall
times (on their workers), and the ratio serial / parallel. ``--baseline`` adds, in each repeat, the same workers as
the cluster ran them before tasks held several cases: one case per task and dask's own worker settings (its
MALLOC_TRIM_THRESHOLD_ and profiler, see docs/studies.md). Then the engine's cost: the embedded cluster's start and
close, and the round trip of 200 trivial tasks through its executor (s per task). ``--ceiling`` adds what this
machine allows without any engine: the study's cases (run_case, as a worker runs them) in one spawned process, then
in N at once, each all of them, timed after a warm-up case and a barrier; N x (one's time) / (the slowest of N's)
is the throughput ratio that no executor can beat here (shared caches, memory bandwidth and the disk's fsyncs
bound it below N). ``--command`` adds, in each repeat, the whole ``milling-twin sweep STUDY --workers 0`` and
``--workers N`` commands as a user runs them, each a new process (interpreter start, imports, the cluster's start
from nothing: its fork server's imports included), timed from outside. The load average is printed before and
after: on a shared machine other processes take cores too.
"""
from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import wait
from dataclasses import replace
from pathlib import Path

from milling_twin.orchestrator.study import executor as study_executor
from milling_twin.orchestrator.study import run as study_run
from milling_twin.orchestrator.study.batching import BatchSizer
from milling_twin.orchestrator.study.cli import phase_text
from milling_twin.orchestrator.study.executor import open_executor
from milling_twin.orchestrator.study.run import CaseTask, run_case, sweep
from milling_twin.orchestrator.study.spec import load_study

REPO = Path(__file__).resolve().parents[2]


def nothing(i: int) -> int:
    return i


def timed_cases(warm_up: CaseTask, tasks: list[CaseTask], barrier, times) -> None:
    """In a spawned process: one case untimed (imports, FMU load), then all of `tasks` after the barrier."""
    run_case(warm_up)
    barrier.wait()
    t0 = time.perf_counter()
    for task in tasks:
        run_case(task)
    times.put(time.perf_counter() - t0)


def command_seconds(study_path: Path, workers: int, out: Path, fmu_dir: Path) -> float:
    """The wall time of ``milling-twin sweep`` in a new process (its output is kept beside ``out``)."""
    argv = [sys.executable, "-m", "milling_twin", "sweep", str(study_path), "--workers", str(workers),
            "--out", str(out), "--fmu-dir", str(fmu_dir), "--no-progress"]
    t0 = time.perf_counter()
    with open(out.with_suffix(".log"), "w") as log:
        subprocess.run(argv, check=True, stdout=log, stderr=subprocess.STDOUT)
    return time.perf_counter() - t0


def cases_in_processes(study, folder: Path, processes: int) -> float:
    """The wall time of the slowest of `processes` spawned processes each running every case of the study."""
    context = multiprocessing.get_context("spawn")
    barrier, times = context.Barrier(processes), context.Queue()
    base = study.scenario()

    def tasks(where: Path, cases) -> list[CaseTask]:
        return [CaseTask(case, base, where, study.reductions, study.variables) for case in cases]

    jobs = [context.Process(target=timed_cases,
                            args=(tasks(folder / f"warm-{k}", study.cases[:1])[0],
                                  tasks(folder / f"cases-{k}", study.cases), barrier, times))
            for k in range(processes)]
    for job in jobs:
        job.start()
    walls = [times.get() for _ in jobs]
    for job in jobs:
        job.join()
        if job.exitcode != 0:
            raise RuntimeError(f"a ceiling process exited with {job.exitcode}")
    return max(walls)


@contextlib.contextmanager
def one_case_per_task_and_dask_defaults():
    """The dispatch and the embedded cluster as they were: tasks of one case, dask's worker settings (its nanny
    also sets MALLOC_TRIM_THRESHOLD_ in this process's environment, which later workers would inherit: undone)."""
    sizer, config = study_run.BatchSizer, study_executor.LOCAL_WORKER_CONFIG
    trim = os.environ.get("MALLOC_TRIM_THRESHOLD_")
    study_run.BatchSizer = lambda slots: BatchSizer(slots, max_cases=1)  # type: ignore[assignment, misc]
    study_executor.LOCAL_WORKER_CONFIG = {}
    try:
        yield
    finally:
        study_run.BatchSizer, study_executor.LOCAL_WORKER_CONFIG = sizer, config
        if trim is None:
            os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
        else:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = trim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path, nargs="?", default=REPO / "studies" / "spindle_depth.toml")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--stop-time", type=float, default=None, help="instead of the study's stop_time (s)")
    parser.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get("MILLING_TWIN_FMU_DIR", "build/fmus")))
    parser.add_argument("--baseline", action="store_true", help="also one case per task with dask's worker settings")
    parser.add_argument("--ceiling", action="store_true",
                        help="also the engine-free ceiling: the cases in 1 and in N processes at once")
    parser.add_argument("--command", action="store_true",
                        help="also the whole `milling-twin sweep` command, serial and on N workers, new processes")
    args = parser.parse_args()
    if args.command and args.stop_time is not None:
        parser.error("--command runs the study file as it is: without --stop-time")
    study = load_study(args.study, args.fmu_dir)
    if args.stop_time is not None:
        study = replace(study, stop_time=args.stop_time)
    print(f"{study.name}: {len(study.cases)} cases, stop time {study.scenario().stop_time:g} s; "
          f"load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="study-bench-") as folder:
        for repeat in range(args.repeats):
            walls = {}
            runs = [("serial", 0, contextlib.nullcontext), (f"{args.workers} workers", args.workers,
                                                            contextlib.nullcontext)]
            if args.baseline:
                runs.insert(1, (f"{args.workers} workers, baseline", args.workers,
                                one_case_per_task_and_dask_defaults))
            for label, workers, setting in runs:
                with setting():
                    result = sweep(study, Path(folder) / label.replace(" ", "_"), workers=workers, progress=False)
                walls[label] = result.wall_time
                print(f"repeat {repeat + 1}, {label}: {result.wall_time:.2f} s "
                      f"(cases' own {result.summary['wall_time'].sum():.2f} s; {result.failed} failed; "
                      f"{phase_text(result.phases)})")
            print(f"repeat {repeat + 1}: " + ", ".join(f"serial / {label} = {walls['serial'] / wall:.2f}"
                                                       for label, wall in walls.items() if label != "serial"))
            if args.command:
                seconds = {n: command_seconds(args.study.resolve(), n, Path(folder) / f"command-{repeat}-{n}",
                                              args.fmu_dir.resolve()) for n in (0, args.workers)}
                print(f"repeat {repeat + 1}, the command: --workers 0 {seconds[0]:.2f} s, --workers {args.workers} "
                      f"{seconds[args.workers]:.2f} s: {seconds[0] / seconds[args.workers]:.2f}x")
            if args.ceiling:
                where = Path(folder) / f"ceiling-{repeat}"
                one = cases_in_processes(study, where / "one", 1)
                many = cases_in_processes(study, where / "many", args.workers)
                print(f"repeat {repeat + 1}, engine-free ceiling: {len(study.cases)} cases in one process "
                      f"{one:.2f} s, in each of {args.workers} at once {many:.2f} s: throughput "
                      f"{args.workers * one / many:.2f}x")
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

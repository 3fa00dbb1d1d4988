"""The study layer on dask: the embedded LocalCluster (worker processes) and an existing cluster (real `dask
scheduler` and `dask worker` processes over TCP, found by a scheduler file) give the serial results bit for bit."""
from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest

from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.study.run import StudyResult, sweep
from milling_twin.orchestrator.study.spec import Study, load_study

REPO = Path(__file__).resolve().parents[1]
STUDY = f"""\
[study]
name = "grid4"
base = "{(REPO / 'scenarios' / 'chatter.toml').as_posix()}"
stop_time = 0.01
[study.grid]
force.spindle_speed = {{ values = [5000, 7000], unit = "rpm" }}
force.axial_depth = {{ values = [0.05, 0.2], unit = "mm" }}
[[study.reduce]]
kind = "max"
variable = "vibration.tip_displacement_y"
[[study.reduce]]
kind = "mean"
variable = "force.Fy"
where = "force.Fx"
"""


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory, fmu_dir: Path) -> Study:
    path = tmp_path_factory.mktemp("study") / "grid4.toml"
    path.write_text(STUDY)
    return load_study(path, fmu_dir)


@pytest.fixture(scope="module")
def serial(study: Study, tmp_path_factory: pytest.TempPathFactory) -> StudyResult:
    return sweep(study, tmp_path_factory.mktemp("serial"), workers=0, progress=False)


def assert_same(result: StudyResult, reference: StudyResult) -> None:
    """The summary (but the wall times and folders) and every case's rows, bit for bit."""
    assert result.failed == 0, list(result.summary["error"])
    assert result.ran == len(reference.summary) == 4
    columns = [c for c in reference.summary.columns if c not in ("wall_time", "run_dir")]
    pd.testing.assert_frame_equal(result.summary[columns], reference.summary[columns], check_exact=True)
    for cid in reference.summary["case_id"]:
        pd.testing.assert_frame_equal(load_results(result.folder / "cases" / cid),
                                      load_results(reference.folder / "cases" / cid), check_exact=True)


def test_two_local_workers_give_the_serial_results_bit_for_bit(study: Study, serial: StudyResult,
                                                                tmp_path: Path) -> None:
    result = sweep(study, tmp_path, workers=2, progress=False)
    assert_same(result, serial)
    assert result.summary["max_vibration.tip_displacement_y"].gt(0).all()


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Path]:
    """A dask scheduler and one worker process on localhost, as `dask scheduler`/`dask worker` start them."""
    file = tmp_path / "scheduler.json"
    bin_dir = Path(sys.executable).parent
    procs = [subprocess.Popen([str(bin_dir / "dask"), "scheduler", "--scheduler-file", str(file), "--host",
                               "127.0.0.1", "--port", "0", "--no-dashboard"], cwd=tmp_path,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert file.is_file(), "the scheduler did not write its file within 60 s"
        procs.append(subprocess.Popen([str(bin_dir / "dask"), "worker", "--scheduler-file", str(file),
                                       "--nthreads", "1", "--no-nanny", "--no-dashboard"],
                                      cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        yield file
    finally:
        for proc in reversed(procs):  # the worker first, while its scheduler is there to hear it close
            proc.terminate()
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def test_an_existing_cluster_found_by_its_scheduler_file_gives_the_serial_results(
        study: Study, serial: StudyResult, tmp_path: Path, cluster: Path) -> None:
    result = sweep(study, tmp_path / "out", scheduler=str(cluster), progress=False)
    assert_same(result, serial)


def kill_study(tmp_path: Path, depths: str, always_depth: float) -> Path:
    markers = tmp_path / "markers"
    markers.mkdir()
    path = tmp_path / "kill.toml"
    path.write_text(STUDY.split("[study.grid]")[0] + f"""
[study.list]
force.axial_depth = {depths}
[[study.reduce]]
kind = "cases.study_kill:kill_worker"
markers = "{markers.as_posix()}"
always_depth = {always_depth}
[[study.reduce]]
kind = "max"
variable = "force.Fx"
""")
    return path


def _worker_settings() -> tuple[str | None, bool]:
    import os

    import dask

    return os.environ.get("MALLOC_TRIM_THRESHOLD_"), dask.config.get("distributed.worker.profile.enabled")


def _worker_start() -> tuple[str, int, int]:
    """How this worker started: its parent's command line, its OS threads and its Python threads."""
    import os
    import threading

    import psutil

    return " ".join(psutil.Process(os.getppid()).cmdline()), len(os.listdir("/proc/self/task")), \
        threading.active_count()


def test_the_embedded_cluster_s_workers_are_set_up_for_short_cases(monkeypatch: pytest.MonkeyPatch) -> None:
    import dask

    from milling_twin.orchestrator.study.executor import open_executor

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    with open_executor(workers=1) as executor:
        assert executor.submit(_worker_settings).result() == (None, False)  # glibc's own mmap threshold, no profiler
        if sys.platform == "linux":
            parent, os_threads, python_threads = executor.submit(_worker_start).result()
            assert "multiprocessing.forkserver" in parent  # forked from the fork server, which imported dask once
            assert os_threads == python_threads  # no BLAS thread pool: the server started with one BLAS thread
    import os

    assert "MALLOC_TRIM_THRESHOLD_" not in os.environ  # the nanny did not set it in this process either
    assert dask.config.get("distributed.worker.profile.enabled") is True  # this process's configuration is restored
    assert dask.config.get("distributed.nanny.pre-spawn-environ")["MALLOC_TRIM_THRESHOLD_"] == 65536


def _environ(name: str) -> str | None:
    import os

    return os.environ.get(name)


def test_workers_have_the_environment_of_the_moment_their_cluster_opens(monkeypatch: pytest.MonkeyPatch) -> None:
    from milling_twin.orchestrator.study.executor import open_executor, start_fork_server

    start_fork_server()  # running before the variable is set, as in a process that ran a study before
    monkeypatch.setenv("MILLING_TWIN_STUDY_TEST", "set after the fork server started")
    with open_executor(workers=1) as executor:
        assert executor.submit(_environ, "MILLING_TWIN_STUDY_TEST").result() == "set after the fork server started"


def test_a_killed_worker_loses_no_case_and_its_case_runs_again(tmp_path: Path, fmu_dir: Path) -> None:
    study = load_study(kill_study(tmp_path, "[1e-5, 2e-5, 4e-5]", -1.0), fmu_dir)
    result = sweep(study, tmp_path / "out", workers=2, progress=False)
    assert list(result.summary["status"]) == ["ok"] * 3, list(result.summary["error"])
    assert (result.summary["attempts"] >= 2).all()  # every case killed its worker once, then ran again
    assert (result.summary["max_force.Fx"] > 0).all()


def test_a_case_that_kills_every_worker_is_a_failed_row(tmp_path: Path, fmu_dir: Path) -> None:
    import dask

    # one case: another case on the worker it kills counts that death too (dask's suspicious tasks)
    study = load_study(kill_study(tmp_path, "[4e-5]", 4e-5), fmu_dir)
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        result = sweep(study, tmp_path / "out", workers=2, progress=False)
    row = result.summary.iloc[0]
    assert row["status"] == "failed" and row["error"].startswith("KilledWorker: "), row["error"]
    assert (tmp_path / "markers" / row["case_id"]).read_text() == "2"  # run twice, two workers killed

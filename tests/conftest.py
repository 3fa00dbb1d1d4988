"""Shared fixtures: the repository root, the built FMUs, and a small two-FMU scenario."""
from __future__ import annotations

import os
import signal
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import pytest

from cases.calibration_synthetic import TWO_FMU_CASE, edited

REPO_ROOT = Path(__file__).resolve().parents[1]
FMU_NAMES = ("SpindlePower", "MrrEstimator")

# Five samples, 0.1 s apart. Speed in rev/s, feed in mm/s, recorded power in kW.
CASE_CSV = """\
speed,vx,vy,process,power
0,0,0,Prep,0.1
10,3,4,Layer 1 Up,0.38
20,6,8,Layer 1 Up,0.47
20,6,8,Repositioning,0.36
0,0,0,End,0.1
"""

# The two-FMU case (SpindlePower + MrrEstimator): one text for these tests and the synthetic power
# calibration case, which edits it (tests/cases/calibration_synthetic.py).
CASE_TOML = TWO_FMU_CASE


def pytest_configure(config: pytest.Config) -> None:
    """The stop-signal tests send SIGINT, SIGTERM and SIGHUP and expect a run to stop. A test command started in the
    background of a non-interactive shell or under nohup inherits SIGINT or SIGHUP ignored, and a run leaves an
    ignored signal ignored on purpose (orchestrator/master.py, _StopFlag; tested with start_run(ignored=...)):
    the tests and the processes they start get the default dispositions back."""
    from milling_twin.orchestrator.master import _STOP_SIGNALS  # the signals a run stops on

    del config
    for signum in _STOP_SIGNALS:
        if signal.getsignal(signum) is signal.SIG_IGN:
            signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope="session")
def fmu_dir() -> Path:
    """The built FMUs; missing ones fail the test (the test command builds first)."""
    path = Path(os.environ.get("MILLING_TWIN_FMU_DIR", REPO_ROOT / "build" / "fmus"))
    missing = [f"{n}{suffix}.fmu" for n in FMU_NAMES for suffix in ("", "_fmi2")
               if not (path / f"{n}{suffix}.fmu").is_file()]
    if missing:
        pytest.fail(f"FMUs missing in {path}: {', '.join(missing)}; build them with "
                    f"cmake -S {REPO_ROOT} -B {REPO_ROOT / 'build'} && cmake --build {REPO_ROOT / 'build'}")
    return path


@pytest.fixture
def make_case(tmp_path: Path) -> Callable[..., Path]:
    """Write the two-FMU case into tmp_path; ``edits`` are (old, new) text replacements
    of the TOML (each must apply), ``csv`` replaces the data. Returns the TOML path."""

    def make(*edits: tuple[str, str], csv: str = CASE_CSV, name: str = "case.toml") -> Path:
        text = edited(CASE_TOML, *edits)
        (tmp_path / "data.csv").write_text(csv)
        path = tmp_path / name
        path.write_text(text)
        return path

    return make


LONG_TOML = """\
[scenario]
name = "long"
stop_time = 100000.0
output_interval = 0.01
[fmus.power]
fmu = "SpindlePower"
step_size = 0.001
[fmus.power.parameters]
P_standby = 100.0
P_idle = 200.0
[outputs]
record = ["power.P_total", "power.spindle_on"]
"""
# Inputs keep their start values (speed 0, mrr 0, spindle on): P_total = 100 + 200 W.
LONG_P_TOTAL = 300.0


def start_run(scenario: Path, fmu_dir: Path, tmp_path: Path, *options: str, ignored: tuple[int, ...] = ()):
    """Start the CLI on ``scenario`` in a subprocess writing to tmp_path/runs; returns the process.
    TMPDIR: a killed run cannot remove its extracted FMUs; keep them in pytest's tmp_path.
    ``ignored``: signals the process starts with ignored (SIG_IGN), as nohup or a background job leaves them."""
    import subprocess
    import sys

    def ignore() -> None:
        for signum in ignored:
            signal.signal(signum, signal.SIG_IGN)

    return subprocess.Popen(
        [sys.executable, "-m", "milling_twin", "run", str(scenario), "--fmu-dir", str(fmu_dir),
         "--out", str(tmp_path / "runs"), "--no-progress", *options],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "TMPDIR": str(tmp_path)}, preexec_fn=ignore if ignored else None)


def wait_for_first_chunk(proc, run_dir: Path, timeout: float = 60.0) -> None:
    import time

    deadline = time.monotonic() + timeout
    while not list((run_dir / "chunks").glob("chunk_*.parquet")):
        assert proc.poll() is None, f"run ended early: {proc.communicate()}"
        assert time.monotonic() < deadline, f"no chunk within {timeout} s"
        time.sleep(0.02)


@contextmanager
def running_long(tmp_path: Path, fmu_dir: Path, ignored: tuple[int, ...] = ()):
    """The CLI on a long run in a subprocess (``ignored``: see start_run); yields (process, run folder)
    once the first chunk is on disk. The process is killed at exit if still alive."""
    scenario = tmp_path / "long.toml"
    scenario.write_text(LONG_TOML)
    proc = start_run(scenario, fmu_dir, tmp_path, ignored=ignored)
    run_dir = tmp_path / "runs" / "long"
    try:
        wait_for_first_chunk(proc, run_dir)
        yield proc, run_dir
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


@pytest.fixture
def long_run(tmp_path: Path, fmu_dir: Path):
    """running_long as a fixture."""
    with running_long(tmp_path, fmu_dir) as started:
        yield started

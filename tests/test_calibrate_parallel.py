"""Parallel calibration (orchestrator/calibrate/parallel.py): the simulations of a fit through the FMUs (its
starts, solved at once, and its finite-difference Jacobians' columns) as tasks of an executor give the serial
fit bit for bit (estimates, objectives, statistics, the report's figures, the count of simulations), with local
dask worker processes as with the in-process executor; a failed evaluation on a worker is reported as the serial
loop reports it; the spec and the command line take the workers or a scheduler."""
from __future__ import annotations

import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import require_fmu
from milling_twin.orchestrator.calibrate import CalibrationSpecError, calibrate, load_spec
from milling_twin.orchestrator.calibrate.fit import fit
from milling_twin.orchestrator.calibrate.fmu_outputs import FmuOutputs, Simulation
from milling_twin.orchestrator.calibrate.pairing import LEARNING
from milling_twin.orchestrator.calibrate.scenario_fit import pairs_for, prepare
from milling_twin.orchestrator.master import SimulationError
from milling_twin.orchestrator.study.executor import SerialExecutor

REPO = Path(__file__).resolve().parents[1]
SLOT_SPEC = REPO / "scenarios" / "calibration" / "slot_forces_synthetic.toml"


def slot_spec(folder: Path, solver: str = "") -> Path:
    """The bundled FMU-path spec (six CuttingForce coefficients, three starts) in ``folder``, ``solver`` lines
    added to its [solver] table."""
    text = SLOT_SPEC.read_text().replace('scenario = "slot_milling_synthetic.toml"',
                                         f'scenario = "{SLOT_SPEC.parent / "slot_milling_synthetic.toml"}"')
    text = text.replace('parameter_set = "slot_forces_synthetic.params.toml"', 'parameter_set = "set.params.toml"')
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "spec.toml").write_text(text + solver)
    return folder / "spec.toml"


@pytest.fixture(scope="module")
def slot(tmp_path_factory, fmu_dir: Path):
    """The prepared slot spec, its learning pairs and a fresh FMU-path model per call."""
    require_fmu(fmu_dir / "CuttingForce.fmu")
    folder = tmp_path_factory.mktemp("parallel")
    spec = load_spec(slot_spec(folder))
    prepared = prepare(spec, fmu_dir, folder / "out")
    learning = pairs_for(prepared)[0].select(LEARNING)
    return spec, prepared, learning


class CountingPool(ThreadPoolExecutor):
    """Threads of this process (a test can patch what they run), counting the tasks."""

    def __init__(self) -> None:
        super().__init__(2)
        self.tasks = 0

    def submit(self, fn, /, *args, **kwargs):
        self.tasks += 1
        return super().submit(fn, *args, **kwargs)


def fresh_fmu(slot, method: str = "forward") -> FmuOutputs:
    spec, prepared, learning = slot
    return FmuOutputs(prepared.scenario, prepared.parameters, [o.ref for o in prepared.outputs], learning.row_time,
                      prepared.run_dir.parent / "evaluations", method=method)


def test_workers_and_scheduler_in_the_spec(tmp_path: Path) -> None:
    solver = load_spec(slot_spec(tmp_path)).solver
    assert (solver.workers, solver.scheduler) == (0, None)
    solver = load_spec(slot_spec(tmp_path, "workers = 2\n")).solver
    assert (solver.workers, solver.scheduler) == (2, None)
    solver = load_spec(slot_spec(tmp_path, 'scheduler = "tcp://10.0.0.1:8786"\n')).solver
    assert (solver.workers, solver.scheduler) == (0, "tcp://10.0.0.1:8786")
    solver = load_spec(slot_spec(tmp_path, 'scheduler = "cluster.json"\n')).solver  # a file beside the spec
    assert solver.scheduler == str(tmp_path / "cluster.json")
    with pytest.raises(CalibrationSpecError, match=r"spec.toml: \[solver\].workers: workers = 2 and scheduler"):
        load_spec(slot_spec(tmp_path, 'workers = 2\nscheduler = "tcp://10.0.0.1:8786"\n'))
    with pytest.raises(CalibrationSpecError, match=r"\[solver\].workers: expected a whole number >= 0, got -1"):
        load_spec(slot_spec(tmp_path, "workers = -1\n"))


@pytest.mark.parametrize("method", ["forward", "central"])
def test_jacobian_columns_on_an_executor_are_the_serial_loop(slot, method: str) -> None:
    """Same Jacobian to the bit, same cache (keys and order), same count of simulations."""
    theta = np.array([q.initial for q in slot[1].parameters])
    serial, parallel = fresh_fmu(slot, method), fresh_fmu(slot, method)
    with CountingPool() as pool:
        parallel.executor = pool
        jac_parallel = parallel.jacobian(theta)
        parallel.jacobian(theta * 1.01)
    assert pool.tasks == 2 * 6 * (1 if method == "forward" else 2)  # the moved runs; the nominal ones here
    grouped = fresh_fmu(slot, method)
    grouped.tasks = 2  # a Jacobian's columns in two tasks (as with two workers)
    with CountingPool() as pool:
        grouped.executor = pool
        jac_grouped = grouped.jacobian(theta)
    assert pool.tasks == 2
    jac = serial.jacobian(theta)
    serial.jacobian(theta * 1.01)
    assert np.array_equal(jac, jac_parallel) and np.array_equal(jac, jac_grouped) and np.all(np.isfinite(jac))
    # per Jacobian: the nominal run, and per coefficient one (forward) or two (central) moved runs
    assert serial.simulations == parallel.simulations == 2 * (1 + 6 * (1 if method == "forward" else 2))
    assert list(serial._cache) == list(parallel._cache)
    assert grouped.simulations == serial.simulations // 2 and list(grouped._cache) == list(serial._cache)[:len(
        grouped._cache)]


def test_a_failed_evaluation_on_a_worker_is_reported_as_in_the_serial_loop(slot, monkeypatch) -> None:
    """A simulation failing on a worker (any with Kac above 200 N/mm2) is a failure with its cause and the
    parameter values, NaN outputs and a non-finite column, as when it fails in this process."""
    real = Simulation.__call__

    def failing(self, theta, work_dir):
        if theta[3 - 1] > 200e6:  # force.Kac, the third parameter
            raise SimulationError("force", 0.0, "Error", "doStep", ["chip thickness out of range (test)"])
        return real(self, theta, work_dir)

    monkeypatch.setattr(Simulation, "__call__", failing)
    theta = np.array([q.initial for q in slot[1].parameters])
    theta[2] = 200e6 - 1.0  # the Kac column steps above 200e6
    serial, parallel = fresh_fmu(slot), fresh_fmu(slot)
    with CountingPool() as pool:
        parallel.executor = pool
        jac_parallel = parallel.jacobian(theta)
    assert pool.tasks == 6
    jac = serial.jacobian(theta)
    assert [f.message for f in serial.failures] == [f.message for f in parallel.failures]
    assert len(serial.failures) == 1 and "force.Kac = 2e+08" in serial.failures[0].message
    assert "SimulationError" in serial.failures[0].message
    assert np.array_equal(np.isnan(jac), np.isnan(jac_parallel)) and np.all(np.isnan(jac[:, 2]))
    assert np.array_equal(np.nan_to_num(jac), np.nan_to_num(jac_parallel))


def test_starts_at_once_with_the_in_process_executor_are_the_serial_fit(slot) -> None:
    """The starts solved at once (threads), each with its own cache, their simulations on the in-process executor
    of the studies, their logs replayed in start order: the fit's numbers and the count of simulations are the
    serial loop's."""
    spec, prepared, learning = slot
    solver = replace(spec.solver, starts=2)
    outcomes = []
    for executor in (None, SerialExecutor()):
        model = prepared.residual_model(learning, solver)
        outcome = fit(model, learning.recorded, weights=[1.0] * 3, sigma=[None] * 3, solver=solver,
                      statistics=spec.statistics, executor=executor)
        outcomes.append((outcome, model.keep_alive.fmu.simulations))
    (a, sims_a), (b, sims_b) = outcomes
    assert sims_a == sims_b
    assert np.array_equal(a.theta, b.theta)
    assert [(s.objective, s.iterations, s.message) for s in a.starts] == \
        [(s.objective, s.iterations, s.message) for s in b.starts]
    assert np.array_equal(a.statistics.covariance, b.statistics.covariance)


def _section(text: str, title: str) -> str:
    return text.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_two_worker_processes_give_the_serial_calibration_bit_for_bit(tmp_path: Path, fmu_dir: Path) -> None:
    """calibrate() of the slot spec (3 starts, 6 coefficients through the FMU) with 2 local dask worker
    processes and serially: every number of the fit, the statistics, the re-simulation's errors, the parameter
    set and the report's tables are the same."""
    require_fmu(fmu_dir / "CuttingForce.fmu")
    spec = slot_spec(tmp_path / "spec")
    serial = calibrate(spec, fmu_dir, tmp_path / "serial", progress=False)
    parallel = calibrate(spec, fmu_dir, tmp_path / "parallel", progress=False, workers=2)
    a, b = serial.fit, parallel.fit
    assert np.array_equal(a.theta, b.theta)
    for s, p in zip(a.starts + [a.refit], b.starts + [b.refit]):
        assert (s.index, s.status, s.message, s.objective, s.iterations) == \
            (p.index, p.status, p.message, p.objective, p.iterations)
        assert np.array_equal(s.x0, p.x0) and np.array_equal(s.x, p.x) and s.trace == p.trace
    assert np.array_equal(a.sigma, b.sigma)
    for field in ("covariance", "correlation", "singular_values", "directions"):
        assert np.array_equal(getattr(a.statistics, field), getattr(b.statistics, field)), field
    assert a.statistics.parameters == b.statistics.parameters
    assert serial.errors == parallel.errors
    assert serial.parameter_set.read_text() == parallel.parameter_set.read_text()
    md_a, md_b = serial.report_md.read_text(), parallel.report_md.read_text()
    for title in ("Parameters", "Directions of the parameter space (SVD of the column-normalised Jacobian)",
                  "Errors of the FMU simulation against the recording, before and after calibration"):
        assert _section(md_a, title) == _section(md_b, title), title
    count = re.compile(r"FMU evaluations: (\d+) simulations")
    assert count.search(md_a).group(1) == count.search(md_b).group(1)
    assert "Parallel fit on 2 local worker processes" in md_b and "Parallel fit" not in md_a
    assert "start the workers" in parallel.timings


def test_the_command_line_takes_workers_or_a_scheduler(capsys) -> None:
    from milling_twin.cli import build_parser

    args = build_parser().parse_args(["calibrate", "spec.toml", "--workers", "2"])
    assert (args.workers, args.scheduler) == (2, None)
    args = build_parser().parse_args(["calibrate", "spec.toml", "--scheduler", "tcp://10.0.0.1:8786"])
    assert (args.workers, args.scheduler) == (None, "tcp://10.0.0.1:8786")
    for wrong in (["--workers", "-1"], ["--workers", "2", "--scheduler", "tcp://10.0.0.1:8786"]):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["calibrate", "spec.toml", *wrong])
    assert "--workers" in capsys.readouterr().err


def test_the_exact_path_starts_no_workers_and_says_so(tmp_path: Path, fmu_dir: Path) -> None:
    """SpindlePower (its outputs are models/ expressions): no simulation in the fit, so no worker is started
    for it, and the report says why the workers asked for were not used."""
    from cases.calibration_synthetic import write_power_case

    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir)
    result = calibrate(spec, fmu_dir, tmp_path / "out", progress=False, workers=2)
    assert result.fit.derivatives.startswith("exact derivatives")
    assert "start the workers" not in result.timings
    assert any(n.startswith("[solver] workers / scheduler: not used") for n in result.notes), result.notes


def test_the_spec_chooses_the_executor(monkeypatch) -> None:
    """workers = 0 without a scheduler: no executor (the serial fit); else the studies' executor with the local
    workers or the scheduler."""
    from contextlib import contextmanager

    from milling_twin.orchestrator.calibrate import parallel
    from milling_twin.orchestrator.calibrate.spec import SolverSpec
    from milling_twin.orchestrator.study import executor as study_executor

    opened = []

    @contextmanager
    def fake(workers=None, scheduler=None):
        opened.append((workers, scheduler))
        yield SerialExecutor()

    monkeypatch.setattr(study_executor, "open_executor", fake)
    for solver, expected in ((SolverSpec(), None), (SolverSpec(workers=3), (3, None)),
                             (SolverSpec(scheduler="tcp://10.0.0.1:8786"), (None, "tcp://10.0.0.1:8786"))):
        opened.clear()
        with parallel.calibration_executor(solver) as executor:
            assert (executor is None) == (expected is None)
        assert opened == ([] if expected is None else [expected])

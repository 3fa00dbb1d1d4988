"""Fits on data the FMUs made with known parameters, the statistics, and robustness against failing starts."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import require_fmu
from milling_twin.orchestrator.calibrate import CalibrationError, load_spec
from milling_twin.orchestrator.calibrate.fit import fit
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresSolver
from milling_twin.orchestrator.calibrate.parameters import Parameter
from cases.calibration_recovery import RecoveryStudy
from milling_twin.orchestrator.calibrate.spec import SolverSpec, StatisticsSpec
from milling_twin.orchestrator.calibrate.statistics import fit_statistics
from cases.calibration_synthetic import IMPULSE_TRUTH, POWER_TRUTH, write_power_case

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def power_study(tmp_path_factory, fmu_dir: Path) -> RecoveryStudy:
    folder = tmp_path_factory.mktemp("power_case")
    return RecoveryStudy(load_spec(write_power_case(folder)), fmu_dir, folder / "out", POWER_TRUTH)


def test_models_reproduce_the_fmu(power_study: RecoveryStudy) -> None:
    """What is fitted is what the FMU runs: models/ at the initial values equals the FMU's run."""
    theta0 = np.array([q.initial for q in power_study.prepared.parameters])
    learning = power_study.learning
    assert np.max(np.abs(power_study.model.predict(theta0) - learning.fmu)) <= 1e-12 * np.max(np.abs(learning.fmu))


def test_noise_free_recovery_to_1e6(power_study: RecoveryStudy) -> None:
    run = power_study.run([0.0], None)
    assert run.converged
    assert np.all(run.relative_error < 1e-6), run.relative_error


def test_noisy_recovery_within_the_intervals(power_study: RecoveryStudy) -> None:
    runs = power_study.repeats([5.0], range(10))
    identifiable = np.array([r.identifiable for r in runs])
    covered = np.array([r.covered for r in runs])
    assert identifiable.all(), [r.outcome.statistics.parameters for r in runs if not r.identifiable.all()]
    assert covered.mean(axis=0).min() >= 0.8, covered.mean(axis=0)
    # the estimated noise level (residual variance with unit weights) matches the 5 W added
    sigma = [np.sqrt(r.outcome.statistics.sigma2) / r.outcome.weights[0] * r.outcome.sigma[0] for r in runs]
    assert np.median(sigma) == pytest.approx(5.0, rel=0.1)


def test_levenberg_marquardt_finds_what_ipopt_finds(power_study: RecoveryStudy) -> None:
    """[solver].algorithm picks the method: on the noise-free power case both recover the truth to 1e-6."""
    recorded = power_study.model.predict(power_study.truth)
    start = np.array([q.initial for q in power_study.prepared.parameters])[None, :]
    outcomes = {algorithm: fit(power_study.model, recorded, weights=[1.0], sigma=[None],
                               solver=SolverSpec(starts=1, noise="sigma", algorithm=algorithm),
                               statistics=StatisticsSpec(), starts=start)
                for algorithm in ("ipopt", "levenberg-marquardt")}
    for algorithm, outcome in outcomes.items():
        assert outcome.best.converged, (algorithm, outcome.best.message)
        assert np.all(np.abs(outcome.theta - power_study.truth) / power_study.truth < 1e-6), algorithm
    assert outcomes["levenberg-marquardt"].best.message.startswith("Converged")
    assert outcomes["ipopt"].best.message == "Solve_Succeeded"


def test_levenberg_marquardt_refuses_multiple_shooting(fmu_dir: Path, tmp_path: Path) -> None:
    """Continuity constraints need IPOPT: the error names the key and the ways out, before any start runs."""
    require_fmu(fmu_dir / "ToolVibration.fmu")
    spec = load_spec(REPO / "scenarios" / "calibration" / "modal_impulse.toml")
    spec = replace(spec, learning=((0.0, 0.01),), validation=(),
                   solver=replace(spec.solver, starts=1, algorithm="levenberg-marquardt"))
    study = RecoveryStudy(spec, fmu_dir, tmp_path, IMPULSE_TRUTH)
    with pytest.raises(CalibrationError, match=r'\[solver\]\.algorithm = "levenberg-marquardt" takes no '
                                               r'constraints.*\[solver\]\.shooting = "single"'):
        fit(study.model, study.learning.recorded, weights=[1.0], sigma=[None], solver=spec.solver,
            statistics=spec.statistics)


def test_modal_parameters_from_an_impulse_noise_free(tmp_path: Path, fmu_dir: Path) -> None:
    """The dynamic path (ToolVibration, multiple shooting) recovers the mode that made the response."""
    require_fmu(fmu_dir / "ToolVibration.fmu")
    spec = load_spec(REPO / "scenarios" / "calibration" / "modal_impulse.toml")
    spec = replace(spec, learning=((0.0, 0.01),), validation=(), solver=replace(spec.solver, starts=2))
    study = RecoveryStudy(spec, fmu_dir, tmp_path, IMPULSE_TRUTH)
    assert study.model.node_start is not None  # multiple shooting
    run = study.run([0.0], None)
    assert run.converged and np.all(run.relative_error < 1e-6), run.relative_error


def test_a_failing_start_is_reported_and_the_next_runs(power_study: RecoveryStudy, monkeypatch) -> None:
    """Start 0 evaluates to NaN (reported with the residual and parameter), the solver breaks on start 1
    (reported with its cause), start 2 runs and is the result."""
    study = power_study
    truth = study.truth
    bad = truth.copy()
    bad[1] = np.nan
    starts = np.array([bad, truth * 1.1, truth * 0.9])
    real_solve = LeastSquaresSolver.solve

    def flaky(self, x0, p, index=0, lbx=None, ubx=None):
        if index == 1:
            raise RuntimeError("simulated IPOPT crash")
        return real_solve(self, x0, p, index, lbx, ubx)

    monkeypatch.setattr(LeastSquaresSolver, "solve", flaky)
    noise = np.random.default_rng(0).normal(0, 5.0, study.learning.recorded.shape)
    outcome = fit(study.model, study.learning.recorded + noise, weights=[1.0], sigma=[None], solver=study.spec.solver,
                  statistics=study.spec.statistics, lsq=study.solver, starts=starts)
    first, second, third = outcome.starts
    assert first.status == "failed" and "non-finite value (nan) for power.P_total at recorded t = " in first.message
    assert second.status == "failed" and "RuntimeError: simulated IPOPT crash" in second.message
    assert third.converged and outcome.best.index == 2
    assert np.all(np.abs(outcome.theta - truth) / truth < 0.1)


def test_solver_exception_inside_ipopt_is_a_failed_start(power_study: RecoveryStudy, monkeypatch) -> None:
    """An exception raised by the NLP solver itself becomes a failed start with its cause."""
    solver = LeastSquaresSolver(power_study.model.problem)

    def boom(**kwargs):
        raise RuntimeError("Error in Function::call for 'calibration' [IpoptInterface]")

    solver.nlp = boom
    p = power_study.model.data_vector(power_study.learning.recorded, [1.0])
    outcome = solver.solve(power_study.model.start(power_study.truth), p, index=0)
    assert outcome.status == "failed" and "IpoptInterface" in outcome.message


def test_undefined_derivative_is_named_and_all_failing_starts_stop_the_fit(tmp_path: Path, fmu_dir: Path) -> None:
    """Without the mrr floor, d/dc3 of (mrr/ref)^c3 is NaN where mrr = 0: every start fails, and the error says
    which derivative, for which parameter, at which sample."""
    spec_path = write_power_case(tmp_path)
    spec_path.write_text(spec_path.read_text().replace('[inputs."power.mrr"]\nfloor = 1e-300\n', ""))
    spec = load_spec(spec_path)
    study = RecoveryStudy(spec, fmu_dir, tmp_path / "out", POWER_TRUTH)
    with pytest.raises(CalibrationError) as info:
        study.run([0.0], None)
    message = str(info.value)
    print(message)
    assert "every start failed" in message and "start 2" in message
    assert "with respect to power.c3" in message and "power.mrr = 0" in message


def test_statistics_of_a_straight_line() -> None:
    """Standard errors, intervals and flags against the textbook formulas of a line fit."""
    rng = np.random.default_rng(3)
    x = np.linspace(0, 1, 50)
    J = np.column_stack([np.ones_like(x), x, 2 * x])  # the third column repeats the second: not identifiable
    r = rng.normal(0, 0.1, x.size)
    params = [Parameter(n, 1.0, -10, 10, 1.0, "", "", 1.0, (0, 1), False) for n in ("a", "b", "c")]
    st = fit_statistics(J[:, :2], r, [1.0, 2.0], params[:2], StatisticsSpec())
    sigma2 = r @ r / 48
    cov = sigma2 * np.linalg.inv(J[:, :2].T @ J[:, :2])
    assert st.parameters[1].standard_error == pytest.approx(np.sqrt(cov[1, 1]), rel=1e-10)
    assert st.correlation[0, 1] == pytest.approx(cov[0, 1] / np.sqrt(cov[0, 0] * cov[1, 1]), rel=1e-10)
    assert st.parameters[0].ci_high - st.parameters[0].estimate == pytest.approx(2.0106 * np.sqrt(cov[0, 0]), rel=1e-4)
    singular = fit_statistics(J, r, [1.0, 2.0, 0.5], params, StatisticsSpec())
    assert not singular.parameters[1].identifiable and not singular.parameters[2].identifiable
    assert singular.parameters[0].identifiable
    assert np.isinf(singular.parameters[2].standard_error)


def test_bound_hits_are_flagged(power_study: RecoveryStudy) -> None:
    """A bound that excludes the truth: the estimate sits on it and says so."""
    params = list(power_study.prepared.parameters)
    study = power_study
    idle = [q.name for q in params].index("power.P_idle")
    capped = [replace(q, upper=100.0) if i == idle else q for i, q in enumerate(params)]
    from milling_twin.orchestrator.calibrate.residuals import build_residuals
    model = build_residuals(study.prepared.graph, study.learning, capped, study.prepared.results)
    recorded = study.model.predict(study.truth)  # noise-free truth at the learning pairs
    start = np.array([q.initial for q in capped])
    start[idle] = 90.0
    outcome = fit(model, recorded, weights=[1.0], sigma=[None], solver=SolverSpec(starts=1),
                  statistics=StatisticsSpec(), starts=start[None, :])
    st = outcome.statistics.parameters[idle]
    assert st.at_bound == "upper" and "at upper bound" in st.flags and not st.identifiable
    assert outcome.theta[idle] == 100.0


def test_a_parameter_upstream_is_fitted_through_the_connection(tmp_path: Path, fmu_dir: Path) -> None:
    """mrr.depth_of_cut (MrrEstimator) reaches power.P_total only through the mrr -> power connection: the graph
    composes both models' equations, and the FMUs' truth is recovered."""
    spec_path = write_power_case(tmp_path)
    text = spec_path.read_text()
    start = text.index('[parameters."power.P_standby"]')
    end = text.index("[[outputs]]")
    spec_path.write_text(text[:start] + '[parameters."mrr.depth_of_cut"]\nmin = 0.1\nmax = 10.0\nunit = "mm"\n\n'
                         '[parameters."power.P_idle"]\nmin = 0.0\nmax = 2000.0\n\n'
                         + text[end:])
    spec = load_spec(spec_path)
    truth = {"mrr.depth_of_cut": 0.0035, "power.P_idle": 250.0}
    study = RecoveryStudy(spec, fmu_dir, tmp_path / "out", truth)
    assert set(study.prepared.graph.instances) == {"mrr", "power"}
    assert "mrr.feed_velocity_x" in [c.ref for c in study.prepared.graph.data]
    run = study.run([0.0], None)
    assert run.converged and np.all(run.relative_error < 1e-6), run.relative_error

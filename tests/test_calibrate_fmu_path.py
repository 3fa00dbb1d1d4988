"""The generic spec on models whose outputs only the FMU computes (CuttingForce: its chip depends on the
displacement history kept by model.c): fitted through the FMU with finite differences, with the same
solver module, multi-start and statistics as the exact path."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import require_fmu
from milling_twin.orchestrator.calibrate import CalibrationSpecError, calibrate, load_spec
from milling_twin.orchestrator.calibrate import fmu_outputs
from milling_twin.orchestrator.calibrate.fit import fit
from cases.calibration_recovery import RecoveryStudy
from milling_twin.orchestrator.calibrate.scenario_fit import prepare
from cases.calibration_synthetic import POWER_TRUTH, SLOT_TRUTH, write_power_case
from milling_twin.orchestrator.master import SimulationError

REPO = Path(__file__).resolve().parents[1]
SLOT_SPEC = REPO / "scenarios" / "calibration" / "slot_forces_synthetic.toml"


def slot_spec(folder: Path, *edits: tuple[str, str], append: str = "") -> Path:
    """The bundled slot spec in ``folder`` (scenario by absolute path, parameter set there), edited."""
    text = SLOT_SPEC.read_text().replace('scenario = "slot_milling_synthetic.toml"',
                                         f'scenario = "{SLOT_SPEC.parent / "slot_milling_synthetic.toml"}"')
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "slot_spec.toml"
    path.write_text(text + append)
    return path


@pytest.fixture(scope="module")
def slot_study(tmp_path_factory, fmu_dir: Path) -> RecoveryStudy:
    require_fmu(fmu_dir / "CuttingForce.fmu")
    folder = tmp_path_factory.mktemp("slot_fd")
    spec = load_spec(slot_spec(folder))
    spec = replace(spec, learning=((0.0, 0.02),), solver=replace(spec.solver, starts=2))
    return RecoveryStudy(spec, fmu_dir, folder / "out", SLOT_TRUTH)


def test_cutting_force_takes_the_fmu_path(slot_study: RecoveryStudy) -> None:
    prepared = slot_study.prepared
    assert prepared.graph is None
    assert "delayed_displacement_x" in prepared.fd_reason and "[[outputs]][0].simulated" in prepared.fd_reason
    assert "finite differences" in slot_study.model.derivatives
    # the FMU re-run at the initial values reproduces the initial run exactly
    theta0 = np.array([q.initial for q in prepared.parameters])
    assert np.array_equal(slot_study.model.predict(theta0), slot_study.learning.fmu)


def test_noise_free_recovery_through_the_fmu(slot_study: RecoveryStudy) -> None:
    """Outputs linear in the coefficients: the forward difference has no truncation error, only the rounding
    of the outputs (1e-16 relative / 1.5e-8 step); the data are the FMU's own outputs, so the residual
    vanishes at the truth whatever the Jacobian's error and the fit returns it to the rounding."""
    run = slot_study.run([0.0, 0.0, 0.0], None)
    assert run.converged
    assert np.all(run.relative_error < 1e-9), run.relative_error


def test_noisy_fit_covers_the_truth(slot_study: RecoveryStudy) -> None:
    run = slot_study.run([5.0, 5.0, 5.0], seed=3)
    assert run.converged and run.identifiable.all()
    assert run.covered.all(), (run.estimates, run.ci_low, run.ci_high)


def test_a_failing_fmu_evaluation_is_reported_and_the_next_start_runs(slot_study: RecoveryStudy,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A simulation that fails (here: any with Kac above 200 N/mm2) fails its start with the cause; the next
    start runs and converges."""
    real = fmu_outputs.FmuOutputs._simulate

    def failing(self, theta: np.ndarray) -> np.ndarray:
        if theta[self.names.index("force.Kac")] > 200e6:
            raise SimulationError("force", 0.0, "Error", "doStep", ["chip thickness out of range (test)"])
        return real(self, theta)

    monkeypatch.setattr(fmu_outputs.FmuOutputs, "_simulate", failing)
    study = slot_study
    truth = study.truth
    starts = np.array([truth * 1.2, truth * 0.8])
    starts[0, [q.name for q in study.prepared.parameters].index("force.Kac")] = 250e6
    recorded = study.model.predict(truth)  # noise-free data at the learning pairs
    outcome = fit(study.model, recorded, weights=[1.0] * 3, sigma=[None] * 3, solver=study.spec.solver,
                  statistics=study.spec.statistics, lsq=study.solver, starts=starts)
    first, second = outcome.starts
    assert first.status == "failed"
    assert "SimulationError" in first.message and "force.Kac = 2.5e+08" in first.message, first.message
    assert second.converged
    assert np.all(np.abs(outcome.theta - truth) / truth < 1e-6)


def test_same_estimates_as_the_exact_path(tmp_path: Path, fmu_dir: Path) -> None:
    """SpindlePower (expressible): FMU finite differences and exact derivatives agree on noisy data."""
    spec = load_spec(write_power_case(tmp_path / "case"))
    spec = replace(spec, solver=replace(spec.solver, starts=1))
    exact = RecoveryStudy(spec, fmu_dir, tmp_path / "exact", POWER_TRUTH).run([5.0], 4).outcome
    fd_spec = replace(spec, solver=replace(spec.solver, derivatives="finite-differences"))
    study = RecoveryStudy(fd_spec, fmu_dir, tmp_path / "fd", POWER_TRUTH)
    assert study.prepared.graph is None
    fd = study.run([5.0], 4).outcome
    assert exact.derivatives.startswith("exact derivatives of the models/ equations")
    assert fd.derivatives.startswith("FMU re-simulation with forward finite differences")
    se = np.array([p.standard_error for p in exact.statistics.parameters])
    assert np.all(np.abs(fd.theta - exact.theta) <= 1e-3 * se), (fd.theta - exact.theta) / se
    fd_se = np.array([p.standard_error for p in fd.statistics.parameters])
    np.testing.assert_allclose(fd_se, se, rtol=1e-4)


def test_exact_derivatives_refused_for_native_states_naming_the_key(tmp_path: Path, fmu_dir: Path) -> None:
    require_fmu(fmu_dir / "CuttingForce.fmu")
    spec = slot_spec(tmp_path, ("starts = 3", 'starts = 3\nderivatives = "exact"'))
    with pytest.raises(CalibrationSpecError) as info:
        prepare(load_spec(spec), fmu_dir, tmp_path / "out")
    message = str(info.value)
    assert message.startswith(f"{spec}: [[outputs]][0].simulated: "), message
    assert "delayed_displacement_x" in message and '"finite-differences"' in message
    assert not (tmp_path / "out" / "runs").exists()


@pytest.mark.parametrize("name, words", [
    ("force.n_flutes", "parameter (only Float64 parameters are fitted)"),
    ("force.Fx", "output variable"),
    ("force.K_tc", "unknown parameter"),
])
def test_a_parameter_that_is_not_tunable_names_the_key(tmp_path: Path, fmu_dir: Path, name: str, words: str) -> None:
    require_fmu(fmu_dir / "CuttingForce.fmu")
    spec = slot_spec(tmp_path, ('[parameters."force.Kae"]\nmin = -200.0\nmax = 500.0\nunit = "N/mm"\n',
                                f'[parameters."{name}"]\n'))
    with pytest.raises(CalibrationSpecError) as info:
        prepare(load_spec(spec), fmu_dir, tmp_path / "out")
    assert str(info.value).startswith(f'{spec}: [parameters."{name}"]: '), str(info.value)
    assert words in str(info.value)


def test_fd_settings_are_checked(tmp_path: Path) -> None:
    spec = slot_spec(tmp_path, ("starts = 3", "starts = 3\nfd_step = 0.5"))
    with pytest.raises(CalibrationSpecError, match=r"\[solver\].fd_step: 0.5: a relative step"):
        load_spec(spec)
    spec = slot_spec(tmp_path, ("starts = 3", 'starts = 3\nfd_method = "backward"'))
    with pytest.raises(CalibrationSpecError, match=r"\[solver\].fd_method"):
        load_spec(spec)


def test_the_whole_loop_writes_the_path_in_the_report(tmp_path: Path, fmu_dir: Path) -> None:
    """calibrate(): report, parameter set and re-simulation, with the derivative path said."""
    require_fmu(fmu_dir / "CuttingForce.fmu")
    spec = slot_spec(tmp_path, ("starts = 3", "starts = 1"),
                     ('parameter_set = "slot_forces_synthetic.params.toml"', 'parameter_set = "set.params.toml"'))
    result = calibrate(spec, fmu_dir, tmp_path / "out", progress=False)
    text = result.report_md.read_text()
    assert "derivatives: FMU re-simulation with forward finite differences" in text
    assert "Fitted through the FMUs because" in text
    assert result.parameter_set == result.out_dir / "set.params.toml" and result.parameter_set.is_file()
    assert not (tmp_path / "set.params.toml").exists()  # nothing beside the spec unless write_set asks
    validation = [e for e in result.errors if e.dataset == "validation"]
    assert validation and all(e.rms_after < e.rms_before for e in validation)
    assert all(e.rms_after < 6.0 for e in validation)  # the recording's noise is 5 N


def test_closed_force_vibration_loop_through_the_fmus(tmp_path: Path, fmu_dir: Path) -> None:
    """scenarios/chatter.toml (CuttingForce and ToolVibration, the displacement fed back with a delay): a
    cutting coefficient and a modal stiffness by name from the force and the tip displacement, which only the
    co-simulation of both FMUs gives; noise-free data from the FMUs with known values come back."""
    from cases.calibration_synthetic import edited, load_scenario_without_data

    require_fmu(fmu_dir / "CuttingForce.fmu")
    require_fmu(fmu_dir / "ToolVibration.fmu")
    text = edited((REPO / "scenarios" / "chatter.toml").read_text(), ("stop_time = 0.2", "stop_time = 0.02"),
                  ("output_interval = 1e-5 ", "output_interval = 1e-4 "))
    text += ('\n[recorded]\nfile = "loop.csv"\ntime_column = "time"\n[recorded.channels]\n'
             'fx = { column = "fx", unit = "N" }\ndx = { column = "dx", unit = "m" }\n')
    (tmp_path / "loop.toml").write_text(text)
    load_scenario_without_data(tmp_path / "loop.toml", fmu_dir, tmp_path)
    (tmp_path / "spec.toml").write_text(
        '[calibration]\nname = "loop"\nscenario = "loop.toml"\nparameter_set = "loop.params.toml"\n'
        '[parameters."force.Ktc"]\nmin = 100.0\nmax = 3000.0\nunit = "N/mm2"\n'
        '[parameters."vibration.stiffness_x1"]\nmin = 1e5\nmax = 1e8\n'
        '[[outputs]]\nsimulated = "force.Fx"\nrecorded = "fx"\n'
        '[[outputs]]\nsimulated = "vibration.tip_displacement_x"\nrecorded = "dx"\n'
        '[segments]\nlearning = [[0.0, 0.02]]\n[solver]\nstarts = 1\n')
    truth = {"force.Ktc": 900e6, "vibration.stiffness_x1": 1.0e6}
    study = RecoveryStudy(load_spec(tmp_path / "spec.toml"), fmu_dir, tmp_path / "out", truth)
    assert study.prepared.graph is None and "fit one dynamic instance at a time" in study.prepared.fd_reason
    run = study.run([0.0, 0.0], None)
    assert run.converged
    assert np.all(run.relative_error < 1e-6), run.relative_error

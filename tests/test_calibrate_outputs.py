"""Where a calibration writes: only under its output folder (the committed parameter sets change only when
published with write_set), with --set overrides applied before the fit. These tests run the fit (IPOPT), so
the sanitizer stage leaves them out like the other calibration runs (Makefile)."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from milling_twin.orchestrator.scenario import ScenarioError

REPO = Path(__file__).resolve().parents[1]


def test_calibrate_writes_only_under_its_output_folder(fmu_dir: Path, tmp_path: Path) -> None:
    """calibrate() leaves the committed parameter sets byte for byte as they were: the set goes to
    <out>/calibration/<name>/ (and the re-simulation applies that one); write_set publishes it elsewhere."""
    from milling_twin.orchestrator.calibrate import calibrate

    committed = {p: p.read_bytes() for p in sorted((REPO / "scenarios" / "calibration").glob("*.params.toml"))}
    spec = REPO / "scenarios" / "calibration" / "umich_power.toml"
    result = calibrate(spec, fmu_dir, tmp_path / "out", progress=False)
    assert {p: p.read_bytes() for p in committed} == committed
    out = tmp_path / "out" / "calibration" / "umich_power"
    assert result.parameter_set == out / "umich_power.params.toml" and result.published_set is None
    assert result.ssv == out / "umich_power.params.ssv"
    assert result.identities["runs"]["calibrated"].startswith(str(out))
    written = tomllib.loads(result.parameter_set.read_text())
    assert (result.parameter_set.parent / written["source"]["spec"]).resolve() == spec.resolve()
    assert (result.parameter_set.parent / written["source"]["recorded"]).is_file()
    # the report names the file written
    assert str(result.parameter_set) in result.report_md.read_text()
    # published on request: the same set, its provenance paths relative to where it lies
    target = tmp_path / "published" / "umich_power.params.toml"
    again = calibrate(spec, fmu_dir, tmp_path / "out2", progress=False, write_set=target)
    assert again.published_set == target and target.is_file()
    assert {p: p.read_bytes() for p in committed} == committed
    published = tomllib.loads(target.read_text())
    assert published["parameters"] == written["parameters"]
    assert (target.parent / published["source"]["scenario"]).resolve() == (REPO / "scenarios" / "umich_power.toml")
    assert str(target) in again.report_md.read_text()


def test_calibrate_applies_overrides_before_the_fit(fmu_dir: Path, tmp_path: Path) -> None:
    """overrides ("instance.variable" -> value or (value, unit)) change the scenario as a parameter set would:
    here the start value of a fitted parameter, and a parameter that is not fitted; an unknown name fails
    before any simulation."""
    from cases.calibration_synthetic import write_power_case
    from milling_twin.orchestrator.calibrate import calibrate

    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir, noise=5.0, seed=4)
    spec.write_text(spec.read_text().replace("starts = 3", "starts = 1"))
    result = calibrate(spec, fmu_dir, tmp_path / "out", progress=False,
                       overrides={"power.c3": 0.9, "mrr.width_of_cut": (5.0, "mm")})
    assert result.fit.parameters[4].name == "power.c3" and result.fit.parameters[4].initial == 0.9
    assert result.identities["overrides"] == "power.c3 = 0.9; mrr.width_of_cut = 5.0 mm"
    assert 'overrides = "power.c3 = 0.9; mrr.width_of_cut = 5.0 mm"' in result.parameter_set.read_text()
    assert not (tmp_path / "case" / "power_case.params.toml").exists()
    with pytest.raises(ScenarioError, match="unknown variable 'c9'"):
        calibrate(spec, fmu_dir, tmp_path / "out", progress=False, overrides={"power.c9": 1.0})


def test_a_calibrated_scenario_must_apply_the_spec_parameter_set(fmu_dir: Path, tmp_path: Path) -> None:
    from cases.calibration_synthetic import write_power_case
    from milling_twin.orchestrator.calibrate import CalibrationSpecError, calibrate

    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir, noise=5.0, seed=5)
    spec.write_text(spec.read_text().replace("starts = 3", "starts = 1")
                    .replace('parameter_set = "power_case.params.toml"',
                             'parameter_set = "power_case.params.toml"\ncalibrated_scenario = "power_case.toml"'))
    with pytest.raises(CalibrationSpecError, match=r"\[calibration\].calibrated_scenario: power_case.toml does not "
                                                   r"apply the parameter set power_case.params.toml"):
        calibrate(spec, fmu_dir, tmp_path / "out", progress=False)

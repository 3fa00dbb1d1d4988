"""Parameter sets a scenario applies by name ([scenario].parameter_sets, orchestrator/scenario.py)."""
from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from milling_twin.orchestrator.scenario import ScenarioError, load_scenario, with_values

REPO = Path(__file__).resolve().parents[1]


def write_set(path: Path, body: str) -> Path:
    path.write_text('description = "test"\n[source]\nby = "hand"\n' + body)
    return path


def test_a_set_overrides_the_scenario_values(make_case, fmu_dir: Path, tmp_path: Path) -> None:
    write_set(tmp_path / "set.toml", '[parameters.power]\nc1 = 0.75\nP_idle = { value = 0.3, unit = "kW" }\n'
                                     "[parameters.mrr]\nwidth_of_cut = 0.004\n")
    case = make_case(('output_interval = 0.1', 'output_interval = 0.1\nparameter_sets = ["set.toml"]'))
    scenario = load_scenario(case, fmu_dir)
    assert scenario.instance("power").parameters["c1"] == 0.75
    assert scenario.instance("power").parameters["P_idle"] == pytest.approx(300.0)
    assert scenario.instance("power").parameters["c2"] == 1000.0  # untouched
    assert scenario.instance("mrr").parameters["width_of_cut"] == 0.004
    # the same through the argument, and a later set wins
    write_set(tmp_path / "later.toml", "[parameters.power]\nc1 = 0.5\n")
    later = load_scenario(case, fmu_dir, parameter_sets=[tmp_path / "later.toml"])
    assert later.instance("power").parameters["c1"] == 0.5
    # the same values as with_values gives
    assert with_values(load_scenario(make_case(), fmu_dir), {"power.c1": 0.75, "power.P_idle": 300.0,
                                                              "mrr.width_of_cut": 0.004}).instances == \
        scenario.instances


@pytest.mark.parametrize("body, key, words", [
    ("[parameters.power]\nc9 = 1.0\n", "[parameters.power].c9", "unknown variable 'c9'"),
    ("[parameters.power]\nc3 = 10.0\n", "[parameters.power].c3", "outside the range"),
    ("[parameters.power]\nmrr = 1e-6\n", "[parameters.power].mrr", "input variable 'mrr'"),
    ("[parameters.spindle]\nc1 = 1.0\n", "[parameters.spindle]", "unknown instance 'spindle'"),
    ('[parameters.power]\nc1 = { value = 1.0, unit = "mm" }\n', "[parameters.power].c1", "unit 'mm' does not fit"),
    ("[parameter.power]\nc1 = 1.0\n", "parameter", "unknown key 'parameter'"),
])
def test_errors_name_the_scenario_key_the_set_file_and_its_key(make_case, fmu_dir: Path, tmp_path: Path, body: str,
                                                               key: str, words: str) -> None:
    set_path = write_set(tmp_path / "bad.toml", body)
    case = make_case(('output_interval = 0.1', 'output_interval = 0.1\nparameter_sets = ["bad.toml"]'))
    with pytest.raises(ScenarioError) as info:
        load_scenario(case, fmu_dir)
    message = str(info.value)
    assert message.startswith(f"{case}: [scenario].parameter_sets[0]: {set_path}: {key}: "), message
    assert words in message, message


def test_missing_set_and_bad_list(make_case, fmu_dir: Path) -> None:
    case = make_case(('output_interval = 0.1', 'output_interval = 0.1\nparameter_sets = ["none.toml"]'))
    with pytest.raises(ScenarioError, match=r"\[scenario\].parameter_sets\[0\]: .*none.toml: parameter set file not found"):
        load_scenario(case, fmu_dir)
    case = make_case(('output_interval = 0.1', 'output_interval = 0.1\nparameter_sets = "set.toml"'), name="b.toml")
    with pytest.raises(ScenarioError, match=r"\[scenario\].parameter_sets: expected a list of file names"):
        load_scenario(case, fmu_dir)


def _without(doc: dict, keys: tuple[str, ...]) -> dict:
    return {k: v for k, v in doc.items() if k not in keys}


def test_the_calibrated_umich_scenario_is_umich_power_plus_the_set(fmu_dir: Path) -> None:
    """scenarios/calibration/umich_power_calibrated.toml must not drift from scenarios/umich_power.toml."""
    base = tomllib.loads((REPO / "scenarios" / "umich_power.toml").read_text())
    calibrated = tomllib.loads((REPO / "scenarios" / "calibration" / "umich_power_calibrated.toml").read_text())
    assert calibrated["scenario"]["parameter_sets"] == ["umich_power.params.toml"]
    names = ("name", "description", "parameter_sets")
    assert _without(calibrated["scenario"], names) == _without(base["scenario"], names)
    assert calibrated["recorded"]["file"] == "../" + base["recorded"]["file"]
    assert _without(calibrated["recorded"], ("file",)) == _without(base["recorded"], ("file",))
    assert _without(calibrated, ("scenario", "recorded")) == _without(base, ("scenario", "recorded"))
    # and it loads with the committed parameter set, whose values it applies
    scenario = load_scenario(REPO / "scenarios" / "calibration" / "umich_power_calibrated.toml", fmu_dir)
    written = tomllib.loads((REPO / "scenarios" / "calibration" / "umich_power.params.toml").read_text())
    for name, value in written["parameters"]["power"].items():
        assert scenario.instance("power").parameters[name] == value


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

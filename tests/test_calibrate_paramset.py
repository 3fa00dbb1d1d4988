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

"""Calibration specs: every mistake fails fast, before any simulation, naming the spec file and the key."""
from __future__ import annotations

from pathlib import Path

import pytest

from milling_twin.orchestrator.calibrate import CalibrationSpecError, calibrate, load_spec
from milling_twin.orchestrator.calibrate.scenario_fit import pairs_for, prepare
from cases.calibration_synthetic import write_power_case

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def case(tmp_path: Path) -> Path:
    """The synthetic power case (scenario, recording, spec) in tmp_path; returns the spec."""
    return write_power_case(tmp_path / "case")


def edited(spec: Path, *edits: tuple[str, str], append: str = "") -> Path:
    text = spec.read_text()
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    spec.write_text(text + append)
    return spec


def fails(spec: Path, key: str, words: str, fmu_dir: Path, tmp_path: Path) -> str:
    out = tmp_path / "out"
    with pytest.raises(CalibrationSpecError) as info:
        prepare(load_spec(spec), fmu_dir, out)
    message = str(info.value)
    assert message.startswith(f"{spec}: {key}: "), message
    assert words in message, message
    assert not (out / "runs").exists(), "a bad spec must fail before any simulation"
    return message


def test_the_bundled_specs_parse() -> None:
    for name in ("umich_power", "modal_impulse", "slot_forces"):
        spec = load_spec(REPO / "scenarios" / "calibration" / f"{name}.toml")
        assert spec.name == name and spec.parameters


def test_unknown_parameter_names_the_key(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('[parameters."power.c3"]', '[parameters."power.c9"]'))
    message = fails(case, '[parameters."power.c9"]', "unknown parameter 'c9'", fmu_dir, tmp_path)
    assert "P_standby" in message  # the candidates are listed


def test_unknown_instance(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('[parameters."power.c3"]', '[parameters."spindle.c3"]'))
    fails(case, '[parameters."spindle.c3"]', "unknown instance 'spindle'", fmu_dir, tmp_path)


def test_a_fixed_or_input_variable_is_no_parameter(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('[parameters."power.c3"]\nmin = 0.2\nmax = 2.0', '[parameters."power.mrr"]'))
    fails(case, '[parameters."power.mrr"]', "input variable 'mrr'", fmu_dir, tmp_path)


def test_bounds_reversed(case: Path, tmp_path: Path) -> None:
    edited(case, ('[parameters."power.c1"]\nmin = 0.0\nmax = 10.0', '[parameters."power.c1"]\nmin = 5.0\nmax = 1.0'))
    with pytest.raises(CalibrationSpecError, match=r'\[parameters."power.c1"\].max: bounds reversed'):
        load_spec(case)


def test_initial_outside_bounds(case: Path) -> None:
    edited(case, ('[parameters."power.c1"]\nmin = 0.0', '[parameters."power.c1"]\ninitial = 20.0\nmin = 0.0'))
    with pytest.raises(CalibrationSpecError, match=r'\[parameters."power.c1"\].initial: 20.0 lies outside'):
        load_spec(case)


def test_bounds_outside_the_fmu_range(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('[parameters."power.c3"]\nmin = 0.2', '[parameters."power.c3"]\nmin = 0.01'))
    fails(case, '[parameters."power.c3"].min', "leave the FMU's range", fmu_dir, tmp_path)


def test_scenario_value_outside_the_bounds(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('[parameters."power.c2"]\nmin = 0.0\nmax = 20000.0', '[parameters."power.c2"]\nmin = 0.0\nmax = 10.0'))
    fails(case, '[parameters."power.c2"].min', "from the scenario", fmu_dir, tmp_path)


def test_no_overlapping_data(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ("learning = [[0.0, 29.95]]", "learning = [[100.0, 200.0]]"),
           ("validation = [[30.0, 40.0]]", "validation = [[300.0, 400.0]]"))
    fails(case, "[segments].learning", "do not overlap the recording power_case.csv (0 .. 39.9 s)", fmu_dir, tmp_path)


def test_no_paired_sample_in_a_window(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    """A window that overlaps the recording but holds no sample (between two samples)."""
    edited(case, ("learning = [[0.0, 29.95]]", "learning = [[0.01, 0.02]]"))
    prepared = prepare(load_spec(case), fmu_dir, tmp_path / "out")
    with pytest.raises(CalibrationSpecError, match=r"\[segments\].learning: no paired sample .*recorded 0 .. 39.9 s"):
        pairs_for(prepared)


def test_validation_must_not_overlap_learning(case: Path) -> None:
    edited(case, ("validation = [[30.0, 40.0]]", "validation = [[20.0, 40.0]]"))
    with pytest.raises(CalibrationSpecError, match=r"\[segments\].validation\[0\]: .* overlaps the learning window"):
        load_spec(case)


def test_unknown_recorded_channel(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('recorded = "power"', 'recorded = "spindle_power"'))
    fails(case, "[[outputs]][0].recorded", "unknown recorded channel 'spindle_power'", fmu_dir, tmp_path)


def test_output_must_be_an_output(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('simulated = "power.P_total"', 'simulated = "power.c1"'))
    fails(case, "[[outputs]][0].simulated", "not a Float64 output", fmu_dir, tmp_path)


def test_unknown_keys_and_types(case: Path) -> None:
    edited(case, ("[solver]\nstarts = 3", "[solver]\nstarts = 0"))
    with pytest.raises(CalibrationSpecError, match=r"\[solver\].starts: expected a whole number >= 1"):
        load_spec(case)
    edited(case, ("[solver]\nstarts = 0", "[solver]\nstart = 3"))
    with pytest.raises(CalibrationSpecError, match=r"\[solver\].start: unknown key 'start'"):
        load_spec(case)
    edited(case, ("[solver]\nstart = 3", '[solver]\nalgorithm = "newton"'))
    with pytest.raises(CalibrationSpecError, match=r"\[solver\].algorithm: 'newton' is not one of auto, ipopt, "
                                                   r"levenberg-marquardt"):
        load_spec(case)


def test_alignment_channels_are_checked(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, append='\n[alignment]\nmethod = "dtw"\nsimulated = ["power.spindle_speed", "mrr.feed_velocity_x", '
                        '"mrr.feed_velocity_y"]\nrecorded = ["speed", "vx", "velocity_y"]\n')
    fails(case, "[alignment].recorded[2]", "unknown recorded channel 'velocity_y'", fmu_dir, tmp_path)


def test_a_floor_must_name_a_data_input(case: Path, fmu_dir: Path, tmp_path: Path) -> None:
    edited(case, ('[inputs."power.mrr"]', '[inputs."mrr.feed_velocity_x"]'))
    fails(case, '[inputs."mrr.feed_velocity_x"]', "not an input of the fitted outputs' equations", fmu_dir, tmp_path)


def test_missing_scenario_and_bad_toml(case: Path) -> None:
    edited(case, ('scenario = "power_case.toml"', 'scenario = "nowhere.toml"'))
    with pytest.raises(CalibrationSpecError, match=r"\[calibration\].scenario: scenario file .*nowhere.toml not found"):
        load_spec(case)
    case.write_text("[calibration\n")
    with pytest.raises(CalibrationSpecError, match="invalid TOML"):
        load_spec(case)


def test_slot_forces_spec_errors(tmp_path: Path, fmu_dir: Path) -> None:
    source = (REPO / "scenarios" / "calibration" / "slot_forces.toml").read_text()
    spec = tmp_path / "slot.toml"
    spec.write_text(source.replace('scenario = "../slot_milling.toml"', f'scenario = "{REPO / "scenarios" / "slot_milling.toml"}"')
                    .replace("validation_feeds = [600, 1200]", "validation_feeds = [600, 900]"))
    with pytest.raises(CalibrationSpecError, match=r"\[slot_forces\].validation_feeds: feed\(s\) \[900.0\] are also "
                                                   "learning feeds"):
        load_spec(spec)
    spec.write_text(spec.read_text().replace("validation_feeds = [600, 900]", "validation_feeds = [600, 1200]")
                    + '\n[[outputs]]\nsimulated = "force.Fx"\nrecorded = "Fx"\n')
    with pytest.raises(CalibrationSpecError, match=r"\[outputs\]: not used by kind"):
        load_spec(spec)
    # a feed the data folder does not hold, found before any fit (synthetic folder of two files)
    data = tmp_path / "data"
    data.mkdir()
    from test_slot_milling_validation import write_dynoware
    import numpy as np
    t = 3.0 + np.arange(2000) * 1e-4
    for feed in (300, 900):
        write_dynoware(data / f"6-n6000f{feed}ap3ae25.csv", t, np.ones((t.size, 3)))
    spec.write_text(source.replace('scenario = "../slot_milling.toml"', f'scenario = "{REPO / "scenarios" / "slot_milling.toml"}"'))
    with pytest.raises(CalibrationSpecError, match=r"\[slot_forces\].learning_feeds: no recording at \[1500.0\] mm/min"):
        calibrate(spec, fmu_dir, tmp_path / "out", data=data, progress=False)


def test_the_default_confidence_threshold_is_the_aligners():
    from milling_twin.orchestrator.align.segments import DEFAULT_MIN_CONFIDENCE
    from milling_twin.orchestrator.calibrate.spec import AlignmentSpec

    assert AlignmentSpec().refuse_below == DEFAULT_MIN_CONFIDENCE

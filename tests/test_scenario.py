"""Scenario parsing and validation: every error names the scenario file and the TOML key."""
from __future__ import annotations

import math
import re
import zipfile
from pathlib import Path

import pytest

from milling_twin.orchestrator.scenario import Ref, ScenarioError, load_scenario


def error_of(path: Path, fmu_dir: Path) -> str:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    return message


def test_valid_case(make_case, fmu_dir):
    sc = load_scenario(make_case(), fmu_dir)
    assert sc.name == "case"
    assert sc.execution_order == ("mrr", "power")  # mrr feeds power, though listed second
    assert sc.start_time == 0.0 and sc.stop_time == pytest.approx(0.4)  # last recorded time
    assert sc.base_step == pytest.approx(0.1) and sc.ticks_per_output == 1
    power = sc.instance("power")
    assert power.fmi_version == 3 and power.path == fmu_dir / "SpindlePower.fmu"
    assert power.parameters == {"P_standby": 100.0, "P_idle": 200.0, "c1": 0.5, "c2": 1000.0, "c3": 1.0}
    assert sc.instance("mrr").parameters == pytest.approx({"width_of_cut": 0.005, "depth_of_cut": 0.002})
    assert [str(i.target) for i in sc.inputs][:2] == ["power.spindle_speed", "power.spindle_on"]
    assert all(i.factor == 1.0 for i in sc.inputs)  # channels are SI already, inputs too
    assert sc.connections[0].source == Ref("mrr", "mrr") and not sc.connections[0].delay
    assert [str(r) for r in sc.outputs] == ["power.P_total", "mrr.mrr", "power.spindle_on"]
    assert sc.recorded.units["speed"] == "rad/s"
    assert sc.recorded.channels["speed"][1] == pytest.approx(20 * math.pi)


def test_fmi2_and_defaults(make_case, fmu_dir):
    sc = load_scenario(make_case(('fmi = 3\nstep_size = 0.1\n[fmus.power.parameters]',
                                  'fmi = 2\nstep_size = 0.05\n[fmus.power.parameters]'),
                                 ("output_interval = 0.1", "output_interval = 0.1\nstop_time = 0.3"),
                                 ('[outputs]\nrecord = ["power.P_total", "mrr.mrr", "power.spindle_on"]', "")),
                       fmu_dir)
    assert sc.instance("power").path == fmu_dir / "SpindlePower_fmi2.fmu"
    assert sc.base_step == pytest.approx(0.05) and sc.ticks_per_output == 2
    assert sc.instance("power").ticks_per_step == 1 and sc.instance("mrr").ticks_per_step == 2
    assert sc.stop_time == 0.3
    # default record list: every output, plus the compared variable (already in it)
    assert [str(r) for r in sc.outputs] == ["power.P_total", "power.P_spindle", "power.P_cutting",
                                            "power.spindle_acceleration", "power.P_dynamic", "mrr.mrr"]


def test_unknown_fmu(make_case, fmu_dir):
    path = make_case(('fmu = "SpindlePower"', 'fmu = "SpindlePowr"'))
    msg = error_of(path, fmu_dir)
    assert "[fmus.power].fmu" in msg
    assert str(fmu_dir / "SpindlePowr.fmu") in msg  # where it looked
    assert "MrrEstimator" in msg and "SpindlePower" in msg  # what exists


def test_fmu_dir_missing(make_case, tmp_path):
    msg = error_of(make_case(), tmp_path / "nowhere")
    assert "[fmus.power].fmu" in msg and "does not exist" in msg


def test_unknown_parameter(make_case, fmu_dir):
    msg = error_of(make_case(("c3 = 1.0", "c3 = 1.0\nc9 = 2.0")), fmu_dir)
    assert "[fmus.power].parameters.c9: unknown variable 'c9' in SpindlePower" in msg
    assert "known parameters: P_standby, P_idle, c1, c2, c3" in msg


def test_parameter_that_is_an_input(make_case, fmu_dir):
    msg = error_of(make_case(("c3 = 1.0", "c3 = 1.0\nmrr = 2.0")), fmu_dir)
    assert "[fmus.power].parameters.mrr: input variable 'mrr'" in msg


def test_parameter_unit_mismatch(make_case, fmu_dir):
    msg = error_of(make_case(('P_idle = { value = 0.2, unit = "kW" }', 'P_idle = { value = 0.2, unit = "mm" }')),
                   fmu_dir)
    assert "[fmus.power].parameters.P_idle" in msg and "dimensions differ" in msg


def test_parameter_out_of_range(make_case, fmu_dir):
    msg = error_of(make_case(("c3 = 1.0", "c3 = 5.0")), fmu_dir)
    assert "[fmus.power].parameters.c3" in msg and "outside the range" in msg


def test_unknown_variable_in_input(make_case, fmu_dir):
    msg = error_of(make_case(('to = "power.spindle_speed"', 'to = "power.spindle_sped"')), fmu_dir)
    assert "[[inputs]][0].to: unknown variable 'spindle_sped' in power (SpindlePower)" in msg
    assert "known inputs: spindle_speed, mrr, spindle_on" in msg


def test_unknown_instance(make_case, fmu_dir):
    msg = error_of(make_case(('from = "mrr.mrr"', 'from = "mr.mrr"')), fmu_dir)
    assert "[[connections]][0].from: unknown instance 'mr'; instances: power, mrr" in msg


def test_unknown_channel(make_case, fmu_dir):
    msg = error_of(make_case(('from = "speed"', 'from = "sped"')), fmu_dir)
    assert "[[inputs]][0].from: unknown recorded channel 'sped'" in msg and "speed" in msg


def test_connection_to_an_output(make_case, fmu_dir):
    msg = error_of(make_case(('to = "power.mrr"', 'to = "power.P_total"')), fmu_dir)
    assert "[[connections]][0].to: power.P_total is an output, not an input; inputs of power: " in msg


def test_channel_unit_mismatch(make_case, fmu_dir):
    msg = error_of(make_case(('from = "speed"\nto = "power.spindle_speed"', 'from = "speed"\nto = "power.mrr"')),
                   fmu_dir)
    assert "[[inputs]][0].to: channel 'speed' (rad/s) cannot feed power.mrr (m3/s)" in msg
    assert "dimensions differ" in msg


def test_connection_unit_mismatch(make_case, fmu_dir):
    msg = error_of(make_case(('from = "mrr.mrr"\nto = "power.mrr"', 'from = "mrr.mrr"\nto = "power.spindle_speed"')),
                   fmu_dir)
    assert "[[connections]][0].to: unit mismatch: mrr.mrr (m3/s) -> power.spindle_speed (rad/s)" in msg
    assert "dimensions differ" in msg


def test_boolean_channel_into_real_input(make_case, fmu_dir):
    msg = error_of(make_case(('from = "vx"', 'from = "cutting"'), ('from = "cutting"\nto = "mrr.cutting"',
                                                                    'from = "vx"\nto = "mrr.cutting"')), fmu_dir)
    assert "[[inputs]][2].to" in msg and "bool" in msg


def test_input_fed_twice(make_case, fmu_dir):
    msg = error_of(make_case(('from = "vy"\nto = "mrr.feed_velocity_y"', 'from = "vy"\nto = "mrr.feed_velocity_x"')),
                   fmu_dir)
    assert "[[inputs]][3].to: input mrr.feed_velocity_x is already fed by [[inputs]][2]" in msg


def test_missing_data_column(make_case, fmu_dir):
    msg = error_of(make_case(('vy = { column = "vy"', 'vy = { column = "VY"')), fmu_dir)
    assert "[recorded.channels].vy:" in msg and "'VY'" in msg and "column not found" in msg
    assert "data.csv" in msg


def test_bad_step_sizes(make_case, fmu_dir):
    msg = error_of(make_case(("step_size = 0.1", "step_size = 0.0")), fmu_dir)
    assert "[fmus.power].step_size: must be > 0" in msg
    msg = error_of(make_case(("step_size = 0.1", "step_size = -0.1")), fmu_dir)
    assert "[fmus.power].step_size: must be > 0" in msg
    msg = error_of(make_case(("output_interval = 0.1", "output_interval = 0.15")), fmu_dir)
    assert "[scenario].output_interval: 0.15 s is not an integer multiple of the base step 0.1 s" in msg
    msg = error_of(make_case(("step_size = 0.1", "step_size = 0.1000001")), fmu_dir)
    assert re.search(r"\[fmus\.\w+\]\.step_size: step sizes .* are not integer multiples", msg), msg


def test_multi_rate_base_step(make_case, fmu_dir):
    sc = load_scenario(make_case(("step_size = 0.1", "step_size = 0.3"),
                                 ("output_interval = 0.1", "output_interval = 0.2\nstop_time = 0.4")), fmu_dir)
    assert sc.base_step == pytest.approx(0.1)
    assert sc.instance("power").ticks_per_step == 3 and sc.ticks_per_output == 2


def test_toml_errors(make_case, fmu_dir):
    msg = error_of(make_case(("output_interval = 0.1", "output_interval = = 0.1")), fmu_dir)
    assert "invalid TOML" in msg
    msg = error_of(make_case(("output_interval = 0.1", "output_interval = 0.1\nstop_tme = 3")), fmu_dir)
    assert "[scenario].stop_tme: unknown key 'stop_tme'" in msg
    msg = error_of(make_case(("[scenario]", "[scenaro]\nx = 1\n[scenario]")), fmu_dir)
    assert ": scenaro: unknown key 'scenaro'; known keys: scenario, fmus" in msg
    msg = error_of(make_case(("output_interval = 0.1", 'output_interval = "0.1"')), fmu_dir)
    assert "[scenario].output_interval: expected a finite number" in msg


def test_stop_time_beyond_recording(make_case, fmu_dir):
    msg = error_of(make_case(("output_interval = 0.1", "output_interval = 0.1\nstop_time = 2.0")), fmu_dir)
    assert "[scenario].stop_time" in msg and "exceeds the recorded data" in msg


def _power_fmu_with_mrr_in_watts(src: Path, dst: Path) -> None:
    """A copy of SpindlePower whose input "mrr" claims unit W, so that two of them can be
    connected in a loop without a unit mismatch (only the model description is read)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                text, n = re.subn(r'(name="mrr"[^>]*?)unit="m3/s" displayUnit="cm3/min"',
                                 r'\1unit="W" displayUnit="kW"', text)
                assert n == 1
                data = text.encode()
            zout.writestr(item, data)


LOOP_TOML = """\
[scenario]
name = "loop"
stop_time = 1.0
output_interval = 0.1
[fmus.a]
fmu = "looped.fmu"
step_size = 0.1
[fmus.b]
fmu = "looped.fmu"
step_size = 0.1
[fmus.c]
fmu = "looped.fmu"
step_size = 0.1
[[connections]]
from = "c.P_total"
to = "a.mrr"
[[connections]]
from = "a.P_total"
to = "b.mrr"
[[connections]]
from = "b.P_total"
to = "a.spindle_speed"
"""


def test_algebraic_loop(tmp_path, fmu_dir):
    _power_fmu_with_mrr_in_watts(fmu_dir / "SpindlePower.fmu", tmp_path / "looped.fmu")
    path = tmp_path / "loop.toml"
    # b.P_total -> a.spindle_speed is W -> rad/s: the unit check comes first
    path.write_text(LOOP_TOML)
    assert "[[connections]][2].to: unit mismatch" in error_of(path, fmu_dir)
    path.write_text(LOOP_TOML.replace('to = "a.spindle_speed"', 'to = "c.mrr"'))
    msg = error_of(path, fmu_dir)
    assert "algebraic loop" in msg and "delay = true" in msg
    for text in ("c.P_total -> a.mrr ([[connections]][0])", "a.P_total -> b.mrr ([[connections]][1])",
                 "b.P_total -> c.mrr ([[connections]][2])"):
        assert text in msg
    # breaking the loop anywhere is accepted; the order then follows the remaining edges
    path.write_text(LOOP_TOML.replace('to = "a.spindle_speed"', 'to = "c.mrr"\ndelay = true'))
    assert load_scenario(path, fmu_dir).execution_order == ("c", "a", "b")
    path.write_text(LOOP_TOML.replace('from = "c.P_total"\nto = "a.mrr"', 'from = "c.P_total"\nto = "a.mrr"\n'
                                      'delay = true').replace('to = "a.spindle_speed"', 'to = "c.mrr"'))
    assert load_scenario(path, fmu_dir).execution_order == ("a", "b", "c")
    path.write_text(LOOP_TOML.replace('from = "a.P_total"\nto = "b.mrr"', 'from = "a.P_total"\nto = "b.mrr"\n'
                                      'delay = true').replace('to = "a.spindle_speed"', 'to = "c.mrr"'))
    assert load_scenario(path, fmu_dir).execution_order == ("b", "c", "a")


def test_self_loop(tmp_path, fmu_dir):
    _power_fmu_with_mrr_in_watts(fmu_dir / "SpindlePower.fmu", tmp_path / "looped.fmu")
    path = tmp_path / "self.toml"
    path.write_text('[scenario]\nname = "s"\nstop_time = 1.0\noutput_interval = 0.1\n'
                    '[fmus.a]\nfmu = "looped.fmu"\nstep_size = 0.1\n'
                    '[[connections]]\nfrom = "a.P_total"\nto = "a.mrr"\n')
    msg = error_of(path, fmu_dir)
    assert "[[connections]][0]: algebraic loop between instances through a.P_total -> a.mrr" in msg


def test_scenario_file_missing(tmp_path, fmu_dir):
    msg = error_of(tmp_path / "none.toml", fmu_dir)
    assert "scenario file not found" in msg


# ---- constant inputs ([fmus.<name>.inputs]) and integer parameters ----

CONSTANT_INPUTS = ('[fmus.mrr.parameters]', '[fmus.mrr.inputs]\nfeed_velocity_y = { value = 600.0, unit = "mm/min" }\n'
                                            'cutting = true\n[fmus.mrr.parameters]')


def test_constant_inputs(make_case, fmu_dir):
    sc = load_scenario(make_case(CONSTANT_INPUTS, ('[[inputs]]\nfrom = "vy"\nto = "mrr.feed_velocity_y"\n', ""),
                                 ('[[inputs]]\nfrom = "cutting"\nto = "mrr.cutting"\n', "")), fmu_dir)
    assert sc.instance("mrr").inputs == {"feed_velocity_y": pytest.approx(0.01), "cutting": True}
    assert sc.instance("power").inputs == {}


def test_constant_input_fed_by_a_channel_too(make_case, fmu_dir):
    msg = error_of(make_case(CONSTANT_INPUTS), fmu_dir)
    assert "[[inputs]][3].to: input mrr.feed_velocity_y is already fed by [fmus.mrr].inputs.feed_velocity_y" in msg


def test_constant_input_errors(make_case, fmu_dir):
    msg = error_of(make_case(('[fmus.mrr.parameters]', '[fmus.mrr.inputs]\nwidth_of_cut = 1.0\n[fmus.mrr.parameters]')),
                   fmu_dir)
    assert "[fmus.mrr].inputs.width_of_cut: parameter variable 'width_of_cut' in MrrEstimator; known inputs: " \
           "feed_velocity_x, feed_velocity_y, cutting" in msg
    msg = error_of(make_case(('[fmus.mrr.parameters]', '[fmus.mrr.inputs]\nfeed_velocity_x = { value = 11, unit = "m/s" }'
                                                       '\n[fmus.mrr.parameters]')), fmu_dir)
    assert "[fmus.mrr].inputs.feed_velocity_x: 11.0 m/s is outside the range [-10.0, 10.0] m/s" in msg


INTEGER_TOML = """\
[scenario]
name = "integers"
stop_time = 0.001
output_interval = 0.0005
[fmus.force]
fmu = "CuttingForce"
step_size = 0.0001
[fmus.force.parameters]
n_flutes = 3
[fmus.force.inputs]
spindle_speed = { value = 6000, unit = "rpm" }
feed_velocity_x = { value = 900, unit = "mm/min" }
"""


def test_integer_parameters(tmp_path, fmu_dir):
    path = tmp_path / "integers.toml"
    path.write_text(INTEGER_TOML)
    sc = load_scenario(path, fmu_dir)
    assert sc.instance("force").parameters == {"n_flutes": 3}
    assert sc.instance("force").inputs == pytest.approx({"spindle_speed": 200 * math.pi, "feed_velocity_x": 0.015})
    for value, expected in (("3.0", "'n_flutes' is an integer: give a whole number without unit, got 3.0"),
                            ("7", "7 is outside the range [1, 6] that CuttingForce allows for 'n_flutes'")):
        path.write_text(INTEGER_TOML.replace("n_flutes = 3", f"n_flutes = {value}"))
        assert f"[fmus.force].parameters.n_flutes: {expected}" in error_of(path, fmu_dir)


def test_constant_inputs_and_integer_parameters_reach_the_fmu(tmp_path, fmu_dir):
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.results import load_results

    path = tmp_path / "integers.toml"
    path.write_text(INTEGER_TOML)
    result = run(load_scenario(path, fmu_dir), tmp_path / "runs", progress=False)
    feed_per_tooth = load_results(result.run_dir)["force.feed_per_tooth"].to_numpy()
    assert feed_per_tooth == pytest.approx(0.015 / (3 * 100.0))  # 900 mm/min, 3 flutes, 100 rev/s


# ---- with_values: checked changes for sweeps and calibration ----


def test_with_values_changes_parameters_and_constant_inputs(make_case, fmu_dir):
    from milling_twin.orchestrator.scenario import with_values

    sc = load_scenario(make_case(CONSTANT_INPUTS, ('[[inputs]]\nfrom = "vy"\nto = "mrr.feed_velocity_y"\n', ""),
                                 ('[[inputs]]\nfrom = "cutting"\nto = "mrr.cutting"\n', "")), fmu_dir)
    changed = with_values(sc, {"mrr.feed_velocity_y": {"value": 1200.0, "unit": "mm/min"},
                               "power.c3": 1.5, "mrr.cutting": False}, name="case_sweep_1")
    assert changed.name == "case_sweep_1" and sc.name == "case"
    assert changed.instance("mrr").inputs == {"feed_velocity_y": pytest.approx(0.02), "cutting": False}
    assert changed.instance("power").parameters["c3"] == 1.5
    assert sc.instance("power").parameters["c3"] == 1.0  # the original is untouched
    assert changed.execution_order == sc.execution_order


def test_with_values_rejects_what_the_file_would_reject(make_case, fmu_dir):
    from milling_twin.orchestrator.scenario import with_values

    sc = load_scenario(make_case(), fmu_dir)
    cases = [
        ("power.c3", 10.0, "[fmus.power].parameters.c3: 10.0 is outside the range [0.1, 3.0]"),
        ("power.P_total", 1.0, "[fmus.power].parameters.P_total: output variable 'P_total' in SpindlePower"),
        ("power.c9", 1.0, "[fmus.power].parameters.c9: unknown variable 'c9' in SpindlePower"),
        ("drill.c3", 1.0, "with_values['drill.c3']: unknown instance 'drill'; instances: mrr, power"),
        ("power.mrr", 0.0, "with_values['power.mrr']: this input is fed by [[inputs]] or [[connections]]"),
        ("power.P_idle", {"value": 1.0, "unit": "mm"}, "[fmus.power].parameters.P_idle: unit 'mm' does not fit"),
    ]
    for key, value, expected in cases:
        with pytest.raises(ScenarioError) as info:
            with_values(sc, {key: value})
        assert str(info.value).startswith(f"{sc.path}: {expected}"), str(info.value)
    with pytest.raises(ScenarioError, match="use letters, digits"):
        with_values(sc, {}, name="a b")


STRING_TOML = """\
[scenario]
name = "strings"
stop_time = 0.01
output_interval = 0.01
[fmus.interp]
fmu = "Interpolator"
step_size = 0.01
[fmus.interp.parameters]
program = {program}
"""


def test_string_parameters(tmp_path, fmu_dir):
    (tmp_path / "part.nc").write_text("G21 G90 G54\nF600\nG1 X1\nM30\n")
    path = tmp_path / "strings.toml"
    path.write_text(STRING_TOML.format(program='{ path = "part.nc" }'))
    assert load_scenario(path, fmu_dir).instance("interp").parameters["program"] == str((tmp_path / "part.nc").resolve())
    path.write_text(STRING_TOML.format(program='"/some/absolute/file.nc"'))  # plain text is passed as given
    assert load_scenario(path, fmu_dir).instance("interp").parameters["program"] == "/some/absolute/file.nc"
    path.write_text(STRING_TOML.format(program='{ path = "missing.nc" }'))
    assert f"[fmus.interp].parameters.program.path: no file {tmp_path / 'missing.nc'}" in error_of(path, fmu_dir)
    path.write_text(STRING_TOML.format(program="3"))
    assert "[fmus.interp].parameters.program: 'program' is a String: give text or" in error_of(path, fmu_dir)

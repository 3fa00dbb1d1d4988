"""The whole-part scenario's [part]: read, expanded into the five instances, written out by `milling-twin expand`,
and every mistake named by file and key."""
from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import zipfile
from pathlib import Path

import pytest

from cases.part_case import MODES, write_part
from milling_twin.cli import main
from milling_twin.models.cutting_force import AL7075_CARBIDE
from milling_twin.models.materials import MATERIALS
from milling_twin.orchestrator.part.expand import explicit_scenario
from milling_twin.orchestrator.scenario import Ref, ScenarioError, load_scenario, with_values


def _links(scenario) -> set[tuple[str, str, bool]]:
    return {(str(c.source), str(c.target), c.delay) for c in scenario.connections}


def test_a_minimal_part_expands_to_the_five_instances(tmp_path: Path, fmu_dir: Path) -> None:
    scenario = load_scenario(write_part(tmp_path), fmu_dir)
    assert scenario.execution_order == ("interp", "workpiece", "force", "vibration", "power")
    models = {i.name: i.model_identifier for i in scenario.instances}
    assert models == {"interp": "Interpolator", "workpiece": "Workpiece", "force": "CuttingForce",
                      "vibration": "ToolVibration", "power": "SpindlePower"}
    steps = {i.name: i.step_size for i in scenario.instances}
    assert steps == {"interp": 1e-3, "workpiece": 1e-3, "force": 1e-5, "vibration": 1e-5, "power": 1e-3}
    interp = scenario.instance("interp").parameters
    assert interp["program"] == str(tmp_path / "prog.nc") and interp["tool_table"] == str(tmp_path / "tool.tbl")
    assert interp["dialect"] == "fanuc" and interp["rapid_feed"] == pytest.approx(0.25)
    assert interp["start_x"] == pytest.approx(-0.01) and interp["period"] == 1e-3
    assert scenario.instance("interp").inputs == {"feed_override": 1.0}
    work = scenario.instance("workpiece").parameters
    expected = {"stock_x_min": 0.0, "stock_y_min": 0.0, "stock_z_min": -0.01, "stock_length": 0.05,
                "stock_width": 0.02, "stock_height": 0.01, "resolution": 5e-4, "tool_diameter": 0.01,
                "corner_radius": 5e-4, "flute_count": 3, "helix_angle": math.radians(30), "flute_length": 0.025}
    assert {k: work[k] for k in expected} == pytest.approx(expected)
    force = scenario.instance("force").parameters
    assert force["n_flutes"] == 3 and force["tool_diameter"] == pytest.approx(0.01)
    assert {k: force[k] for k in AL7075_CARBIDE} == pytest.approx(AL7075_CARBIDE)
    assert "regeneration_passes" not in force  # one delay unless [fmus.force.parameters] says more (models.md)
    vib = scenario.instance("vibration").parameters
    assert (vib["n_modes_x"], vib["n_modes_y"]) == (1, 2)
    assert vib["stiffness_y1"] == pytest.approx(3e7) and vib["frequency_y2"] == 3000.0
    assert scenario.instance("power").parameters["P_idle"] == pytest.approx(300.0)
    links = _links(scenario)
    for link in [("interp.x", "workpiece.tool_x", False), ("interp.z", "workpiece.tool_z", False),
                 ("interp.feed_velocity_y", "force.feed_velocity_y", False),
                 ("workpiece.axial_depth", "force.axial_depth", False), ("force.Fx", "vibration.force_x", False),
                 ("vibration.tip_displacement_x", "force.displacement_x", True),
                 ("vibration.tip_displacement_y", "force.displacement_y", True),
                 ("workpiece.mrr", "power.mrr", False), ("interp.spindle_on", "power.spindle_on", False)]:
        assert link in links
    assert not any(target == "force.engagement" for _, target, _ in links)
    assert scenario.output_interval == 1e-4
    assert scenario.stop_time == pytest.approx(scenario.part.machining_time + 0.05)
    assert 7.0 < scenario.part.machining_time < 10.0  # 7 mm down at 300 mm/min, 70 mm at 600 mm/min, rapids
    assert Ref("force", "Fx") in scenario.outputs and Ref("power", "P_total") in scenario.outputs
    assert scenario.part.tool.number == 1 and scenario.part.warnings == ()
    if scenario.stepping is not None:  # the variable step: force and vibration fine in and near material
        assert scenario.stepping.variable == ("force", "vibration")
        assert scenario.stepping.fine_when[0].output == Ref("workpiece", "axial_depth")


def test_cutting_power_from_the_force_model_or_the_mrr_law(tmp_path: Path, fmu_dir: Path) -> None:
    by_force = load_scenario(write_part(tmp_path / "force"), fmu_dir)
    by_mrr = load_scenario(write_part(tmp_path / "mrr", ('material = ', 'cutting_power = "mrr"\nmaterial = ')),
                           fmu_dir)
    variables = by_force.instance("power").variables
    if "cutting_power_from_force" not in variables:
        pytest.fail("SpindlePower has no parameter cutting_power_from_force: rebuild the FMUs")
    assert by_force.instance("power").parameters["cutting_power_from_force"] is True
    assert ("force.power", "power.cutting_power", False) in _links(by_force)
    assert by_mrr.instance("power").parameters["cutting_power_from_force"] is False
    assert not any(target == "power.cutting_power" for _, target, _ in _links(by_mrr))


def test_one_line_swaps_the_force_model_to_forcenet(tmp_path: Path, fmu_dir: Path) -> None:
    scenario = load_scenario(write_part(tmp_path, ('material = ', 'force_model = "ForceNet"\nmaterial = ')), fmu_dir)
    force = scenario.instance("force")
    assert force.model_identifier == "ForceNet"
    assert "Ktc" not in force.parameters and force.parameters["n_flutes"] == 3
    assert ("workpiece.engagement", "force.engagement", False) in {
        (str(c.source).split("[")[0], str(c.target).split("[")[0], c.delay) for c in scenario.connections}
    assert ("force.Fy", "vibration.force_y", False) in _links(scenario)


def test_forcenet_with_another_material_warns(tmp_path: Path, fmu_dir: Path) -> None:
    path = write_part(tmp_path, ('material = "Al7075-T6"', 'force_model = "ForceNet"\nmaterial = "Al6061-T6"'))
    warnings = load_scenario(path, fmu_dir).part.warnings
    assert warnings == ("[part].material: ForceNet learned the forces of Al7075-T6; the material 'Al6061-T6' is not "
                        "used by it (use force_model = \"CuttingForce\")",)


def test_a_material_table_and_the_presets(tmp_path: Path, fmu_dir: Path) -> None:
    table = ('material = "Al7075-T6"', 'material = { Ktc = { value = 700, unit = "N/mm2" }, Krc = 2.0e8, '
             'Kac = 1.0e8, Kte = { value = 20, unit = "N/mm" }, Kre = 1.0e4, Kae = 0.0, name = "mine" }')
    force = load_scenario(write_part(tmp_path, table), fmu_dir).instance("force").parameters
    assert force["Ktc"] == pytest.approx(7e8) and force["Kte"] == pytest.approx(2e4) and force["Kae"] == 0.0
    assert set(MATERIALS) == {"Al7075-T6", "Al6061-T6", "machining-wax"}
    assert MATERIALS["machining-wax"].estimate and "ESTIMATE" in MATERIALS["machining-wax"].source
    assert all(p.source for p in MATERIALS.values())


def test_parameters_beside_the_part_override_single_values(tmp_path: Path, fmu_dir: Path) -> None:
    extra = ("[part.tool_modes]", "[fmus.force.parameters]\nrunout_offset = { value = 5, unit = \"um\" }\n"
                                  "[fmus.workpiece.parameters]\nresolution = 0.001\n[part.tool_modes]")
    scenario = load_scenario(write_part(tmp_path, extra), fmu_dir)
    assert scenario.instance("force").parameters["runout_offset"] == pytest.approx(5e-6)
    assert scenario.instance("workpiece").parameters["resolution"] == 0.001
    assert scenario.instance("force").parameters["n_flutes"] == 3  # the rest stays expanded


def test_recorded_outputs_and_stop_time_beside_the_part_are_kept(tmp_path: Path, fmu_dir: Path) -> None:
    edits = (('name = "tiny_part"', 'name = "tiny_part"\nstop_time = 1.5\noutput_interval = 1e-3'),
             ("[part.tool_modes]", "[outputs]\nrecord = [\"force.Fx\"]\n[part.tool_modes]"))
    scenario = load_scenario(write_part(tmp_path, *edits), fmu_dir)
    assert scenario.stop_time == 1.5 and scenario.output_interval == 1e-3
    assert scenario.outputs == (Ref("force", "Fx"),)


def test_the_written_explicit_scenario_loads_as_the_same_scenario(tmp_path: Path, fmu_dir: Path,
                                                                  capsys: pytest.CaptureFixture) -> None:
    part_file = write_part(tmp_path / "part", ("[part.tool_modes]", "[fmus.force.parameters]\nrunout_offset = "
                                                                    "{ value = 5, unit = \"um\" }\n[part.tool_modes]"))
    out = tmp_path / "elsewhere" / "explicit.toml"
    assert main(["expand", str(part_file), "-o", str(out), "--fmu-dir", str(fmu_dir)]) == 0
    assert str(out) in capsys.readouterr().out
    doc = tomllib.loads(out.read_text())
    assert "part" not in doc and doc["fmus"]["interp"]["parameters"]["program"] == {"path": "../part/prog.nc"}
    assert doc["fmus"]["force"]["parameters"]["runout_offset"] == {"value": 5, "unit": "um"}
    assert list(doc) == ["scenario", "fmus", "connections", "stepping", "outputs"]
    from_part, explicit = load_scenario(part_file, fmu_dir), load_scenario(out, fmu_dir)
    assert explicit.part is None
    for name in ("name", "description", "start_time", "stop_time", "output_interval", "base_step", "outputs",
                 "connections", "stepping", "execution_order"):
        assert getattr(explicit, name) == getattr(from_part, name), name
    for a, b in zip(from_part.instances, explicit.instances):
        assert (a.name, a.path, a.step_size, a.parameters, a.inputs) == (b.name, b.path, b.step_size, b.parameters,
                                                                         b.inputs)


def test_expand_without_output_prints_the_scenario(tmp_path: Path, fmu_dir: Path, capsys: pytest.CaptureFixture,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    part_file = write_part(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert main(["expand", str(part_file), "--fmu-dir", str(fmu_dir)]) == 0
    doc = tomllib.loads(capsys.readouterr().out)
    assert doc["fmus"]["interp"]["parameters"]["tool_table"] == {"path": "tool.tbl"}
    assert list(doc["fmus"]) == ["interp", "workpiece", "force", "vibration", "power"]


def test_the_expansion_uses_optional_variables_only_where_the_fmus_have_them(tmp_path: Path, fmu_dir: Path) -> None:
    part = load_scenario(write_part(tmp_path), fmu_dir).part
    names = {"interp": {"x"}, "workpiece": {"axial_depth", "mrr"}, "force": {"Fx"}, "vibration": set(),
             "power": {"P_total", "spindle_speed"}}
    doc = explicit_scenario(part, {k: dict.fromkeys(v) for k, v in names.items()}, {"name": "p"})
    assert doc["stepping"]["fine_when"] == [{"output": "workpiece.axial_depth", "above": 0.0}]
    assert "clearance_range" not in doc["fmus"]["workpiece"]["parameters"]
    assert "cutting_power_from_force" not in doc["fmus"]["power"]["parameters"]
    assert "regeneration_passes" not in doc["fmus"]["force"]["parameters"]
    assert not any(c["to"] in ("power.cutting_power", "power.spindle_speed_command") for c in doc["connections"])
    assert doc["outputs"]["record"] == ["interp.x", "workpiece.axial_depth", "workpiece.mrr", "force.Fx",
                                        "power.P_total"]
    full = {"workpiece": {"clearance", "clearance_range"}, "power": {"cutting_power", "cutting_power_from_force"}}
    variables = {**{k: dict.fromkeys(v) for k, v in names.items()}, **{k: dict.fromkeys(v) for k, v in full.items()}}
    doc = explicit_scenario(part, variables, {"name": "p"})
    assert doc["stepping"]["fine_when"] == [{"output": "workpiece.axial_depth", "above": 0.0}]  # no lookahead
    assert doc["fmus"]["workpiece"]["parameters"]["clearance_range"] == pytest.approx(0.003)   # recorded only
    assert {"from": "force.power", "to": "power.cutting_power"} in doc["connections"]
    doc = explicit_scenario(dataclasses.replace(part, lookahead=0.002), variables, {"name": "p"})
    assert doc["stepping"]["fine_when"][1] == {"output": "workpiece.clearance", "below": 0.002}
    assert doc["fmus"]["workpiece"]["parameters"]["clearance_range"] == pytest.approx(0.003)


# The slowest of MODES rings down: 1300 Hz at 2 % damping, its envelope exp(-0.02 2 pi 1300 t) down to 1e-6
RING_DOWN_MODES = math.log(1e6) / (0.02 * 2 * math.pi * 1300)   # 84.6 ms


@pytest.mark.parametrize("edits, hold", [
    ((), RING_DOWN_MODES),
    ((("[part.tool_modes]", "[part.stepping]\nhold = { value = 20, unit = \"ms\" }\n[part.tool_modes]"),), 0.02),
    ((("[part.tool_modes]", "[part.stepping]\nlookahead = { value = 2, unit = \"mm\" }\n[part.tool_modes]"),),
     RING_DOWN_MODES),
    # an override of the expanded modes: the x mode, 1200 Hz, now at 1 % damping, is the slowest; a second x mode
    ((("[part.tool_modes]", "[fmus.vibration.parameters]\nn_modes_x = 2\nfrequency_x2 = 2000.0\ndamping_x2 = 0.05\n"
                            "stiffness_x2 = 5e7\n[part.tool_modes]"),), RING_DOWN_MODES),
    ((("[part.tool_modes]", "[fmus.vibration.parameters]\ndamping_x1 = 0.01\n[part.tool_modes]"),),
     math.log(1e6) / (0.01 * 2 * math.pi * 1200)),
])
def test_force_and_vibration_stay_fine_until_the_tool_has_rung_down(tmp_path: Path, fmu_dir: Path, edits,
                                                                   hold) -> None:
    """After the tool leaves material, [stepping].hold keeps force and vibration at the fine step until the
    slowest mode of the tool has rung down to 1e-6 of its amplitude (or as long as [part.stepping].hold says);
    a lookahead adds the clearance condition."""
    path = write_part(tmp_path, *edits)
    stepping = load_scenario(path, fmu_dir).stepping
    assert stepping.hold_intervals == math.ceil(hold / 1e-3 - 1e-9)
    out = tmp_path / "explicit.toml"
    assert main(["expand", str(path), "-o", str(out), "--fmu-dir", str(fmu_dir)]) == 0
    doc = tomllib.loads(out.read_text())
    assert doc["stepping"]["hold"] == pytest.approx(hold, rel=1e-12)
    lookahead = any("lookahead" in new for _, new in edits)
    assert [c["output"] for c in doc["stepping"]["fine_when"]] == \
        ["workpiece.axial_depth"] + (["workpiece.clearance"] if lookahead else [])


SPEC_ERRORS = [  # (id, edits of the part file, key, what the message says)
    ("unknown-key", [("[part]\n", "[part]\nspeed = 3\n")], "[part].speed",
     "unknown key 'speed'; known keys: program"),
    ("no-program", [('program = "prog.nc"\n', "")], "[part].program", "missing required key"),
    ("program-not-found", [('"prog.nc"', '"nope.nc"')], "[part].program", "no file "),
    ("dialect", [("[part]\n", '[part]\ndialect = "heidenhain"\n')], "[part].dialect",
     "'heidenhain' is not one of fanuc, linuxcnc, sinumerik"),
    ("tool-table-not-found", [('"tool.tbl"', '"none.tbl"')], "[part].tool_table", "no file "),
    ("force-model", [("[part]\n", '[part]\nforce_model = "Magic"\n')], "[part].force_model",
     "'Magic' is not one of CuttingForce, ForceNet"),
    ("cutting-power", [("[part]\n", '[part]\ncutting_power = "torque"\n')], "[part].cutting_power",
     "'torque' is not one of force, mrr"),
    ("material-unknown", [('"Al7075-T6"', '"steel"')], "[part].material",
     "unknown material 'steel'; presets (models/materials.py): Al7075-T6, Al6061-T6, machining-wax"),
    ("material-missing", [('material = "Al7075-T6"\n', "")], "[part].material", "missing required key"),
    ("material-coefficient-missing", [('"Al7075-T6"', "{ Ktc = 1e8, Krc = 1e8, Kac = 1e8, Kte = 1e3, Kre = 1e3 }")],
     "[part].material.Kae", "missing required key"),
    ("material-unit", [('"Al7075-T6"', '{ Ktc = { value = 700, unit = "N/mm" }, Krc = 1e8, Kac = 1e8, Kte = 1e3, '
                                       'Kre = 1e3, Kae = 0 }')],
     "[part].material.Ktc", "unit 'N/mm' does not fit (expected a unit convertible to 'N/m2')"),
    ("feed-override", [("[part]\n", "[part]\nfeed_override = -1\n")], "[part].feed_override", "must be >= 0.0"),
    ("stock-missing", [("[part.stock]", "[part.stockx]")], "[part].stockx", "unknown key 'stockx'"),
    ("stock-size", [("[50.0, 20.0, 10.0]", "[50.0, -20.0, 10.0]")], "[part.stock].size",
     "every value must be > 0, got [50.0, -20.0, 10.0]"),
    ("stock-origin", [("[0.0, 0.0, -10.0]", "[0.0, -10.0]")], "[part.stock].origin",
     "expected three finite numbers [x, y, z]"),
    ("stock-resolution-unit", [('value = 0.5, unit = "mm"', 'value = 0.5, unit = "s"')],
     "[part.stock].resolution", "unit 's' does not fit (expected a unit convertible to 'm')"),
    ("machine-unknown", [("[part.machine]\n", "[part.machine]\nspeed = 1\n")], "[part.machine].speed",
     "unknown variable 'speed' in Interpolator; known parameters: program"),
    ("machine-program", [("[part.machine]\n", '[part.machine]\nprogram = "x.nc"\n')], "[part.machine].program",
     "set by [part].program, not here"),
    ("machine-range", [("[part.machine]\n", '[part.machine]\nacceleration = -1.0\n')],
     "[part.machine].acceleration", "is outside the range"),
    ("spindle-unknown", [("[part.spindle]\n", "[part.spindle]\nc9 = 1\n")], "[part.spindle].c9",
     "unknown variable 'c9' in SpindlePower"),
    ("spindle-cutting-power", [("[part.spindle]\n", "[part.spindle]\ncutting_power_from_force = true\n")],
     "[part.spindle].cutting_power_from_force", "set by [part].cutting_power, not here"),
    ("modes-missing", [(MODES, "")], "[part.tool_modes]", "missing required table"),
    ("modes-too-many", [("x = [ {", "x = [ {}, {}, {}, {}, {")], "[part.tool_modes].x",
     "expected a list of at most 4 modes"),
    ("mode-damping", [("damping = 0.03, ", "")], "[part.tool_modes].x[0].damping", "missing required key"),
    ("mode-stiffness-unit", [('unit = "N/um"', 'unit = "N"')], "[part.tool_modes].y[0].stiffness",
     "unit 'N' does not fit (expected a unit convertible to 'N/m')"),
    ("fine-step", [("[part.tool_modes]", "[part.stepping]\nfine_step = 0.01\n[part.tool_modes]")],
     "[part.stepping].fine_step", "0.01 s is longer than coarse_step 0.001 s"),
    ("coarse-step", [("[part.machine]\n", "[part.machine]\nperiod = 0.002\n"),
                     ("[part.tool_modes]", "[part.stepping]\ncoarse_step = 0.001\n[part.tool_modes]")],
     "[part.stepping].coarse_step", "0.001 s differs from the machine's period 0.002 s ([part.machine].period)"),
    ("fine-step-divide", [("[part.tool_modes]", "[part.stepping]\nfine_step = 3e-6\n[part.tool_modes]")],
     "[part.stepping].fine_step", "3e-06 s does not divide coarse_step 0.001 s a whole number of times"),
    ("mode-damping-range", [("damping = 0.03,", "damping = 0.99,")], "[part.tool_modes]",
     "0.99 is outside the range [0.0001, 0.95] that ToolVibration allows for 'damping_x1' (as "
     "[fmus.vibration].parameters.damping_x1 of the expanded scenario)"),
    ("feed-override-range", [("[part]\n", "[part]\nfeed_override = 100.0\n")], "[part].feed_override",
     "that Interpolator allows for 'feed_override' (as [fmus.interp].inputs.feed_override of the expanded scenario)"),
    ("lookahead", [("[part.tool_modes]", "[part.stepping]\nlookahead = { value = -2, unit = \"mm\" }\n"
                                          "[part.tool_modes]")], "[part.stepping].lookahead", "must be > 0"),
    ("hold-of-an-unknown-mode", [("[part.tool_modes]", "[fmus.vibration.parameters]\nn_modes_x = 2\n[part.tool_modes]")],
     "[fmus.vibration].parameters", "a mode is switched on without its frequency_x2: give it, or "
                                    "[part.stepping].hold (the hold is the modes' ring-down)"),
    ("hold", [("[part.tool_modes]", "[part.stepping]\nhold = { value = 0.2, unit = \"ms\" }\n[part.tool_modes]")],
     "[part.stepping].hold", "0.0002 s is shorter than coarse_step 0.001 s: the interval in which the tool leaves "
                             "material must be stepped finely"),
    ("override-unknown-instance", [("[part.tool_modes]", "[fmus.mrr.parameters]\nc2 = 1\n[part.tool_modes]")],
     "[fmus.mrr]", "beside [part], [fmus] only overrides parameters of the part's instances interp, workpiece, "
                   "force, vibration, power; 'mrr' is not one of them"),
    ("override-unknown-parameter", [("[part.tool_modes]", "[fmus.force.parameters]\nKxy = 1\n[part.tool_modes]")],
     "[fmus.force].parameters.Kxy", "unknown variable 'Kxy' in CuttingForce"),
    ("connections-beside-part", [("[part]\n", '[[connections]]\nfrom = "a.b"\nto = "c.d"\n[part]\n')],
     "connections", "unknown key 'connections'; known keys: scenario, part, fmus, recorded, inputs, outputs"),
]


@pytest.mark.parametrize("edits, key, message", [case[1:] for case in SPEC_ERRORS], ids=[c[0] for c in SPEC_ERRORS])
def test_spec_error(tmp_path: Path, fmu_dir: Path, edits: list, key: str, message: str) -> None:
    path = write_part(tmp_path, *edits)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert str(info.value).startswith(f"{path}: {key}: "), str(info.value)
    assert message in info.value.detail


TOOL_ERRORS = [  # (id, tool table, key, message)
    ("no-flutes", "T1 P1 D10 ; stick_out=25\n", "[part].tool_table",
     "T1 of {tools} gives no flutes= (the force model's number of flutes): add flutes=<n> to its comment"),
    ("no-stick-out", "T1 P1 D10 ; flutes=3\n", "[part].flute_length",
     "T1 of {tools} gives no stick_out= (the flute length of the Workpiece and the depth check): add "
     "stick_out=<mm> to its comment or set [part].flute_length"),
    ("too-many-flutes", "T1 P1 D10 ; flutes=8 stick_out=20\n", "[part].tool_table",
     "8 is outside the range [1, 6] that CuttingForce allows for 'n_flutes' (as [fmus.force].parameters.n_flutes of "
     "the expanded scenario)"),
    ("no-diameter", "T1 P1 ; flutes=3 stick_out=20\n", "[part].tool_table", "T1 of {tools} has no diameter D (> 0 mm)"),
    ("malformed", "T1 P1 D10 K3\n", "[part].tool_table",
     "{tools} line 1: \"T1 P1 D10 K3\": a tool table word T, P, X, Y, Z, A, B, C, U, V, W, D, I, J, Q (letter and "
     "number), got 'K3'"),
]


@pytest.mark.parametrize("tools, key, message", [case[1:] for case in TOOL_ERRORS], ids=[c[0] for c in TOOL_ERRORS])
def test_tool_table_error(tmp_path: Path, fmu_dir: Path, tools: str, key: str, message: str) -> None:
    path = write_part(tmp_path, tools=tools)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert str(info.value) == f"{path}: {key}: {message.format(tools=tmp_path / 'tool.tbl')}"


def test_a_flute_length_in_the_part_stands_for_a_missing_stick_out(tmp_path: Path, fmu_dir: Path) -> None:
    path = write_part(tmp_path, ("[part]\n", '[part]\nflute_length = { value = 30, unit = "mm" }\n'),
                      tools="T1 P1 D10 ; flutes=3\n")
    assert load_scenario(path, fmu_dir).instance("workpiece").parameters["flute_length"] == pytest.approx(0.03)


def test_a_recording_beside_the_part_feeds_the_override_and_moves_with_the_written_file(
        tmp_path: Path, fmu_dir: Path) -> None:
    recorded = ("[part.tool_modes]", '[recorded]\nfile = "override.csv"\nsample_period = 0.5\n'
                                     '[recorded.channels]\noverride = { column = "ovr" }\n'
                                     '[[inputs]]\nfrom = "override"\nto = "interp.feed_override"\n'
                                     'interpolation = "hold"\n[part.tool_modes]')
    part_file = write_part(tmp_path / "part", recorded)
    (tmp_path / "part" / "override.csv").write_text("ovr\n1.0\n0.5\n0.5\n1.2\n1.2\n")
    scenario = load_scenario(part_file, fmu_dir)
    assert scenario.stop_time == 2.0  # the recording's end, not the program's machining time
    assert scenario.instance("interp").inputs == {}
    assert [(i.channel, str(i.target)) for i in scenario.inputs] == [("override", "interp.feed_override")]
    out = tmp_path / "out" / "explicit.toml"
    assert main(["expand", str(part_file), "-o", str(out), "--fmu-dir", str(fmu_dir)]) == 0
    assert tomllib.loads(out.read_text())["recorded"]["file"] == "../part/override.csv"
    assert load_scenario(out, fmu_dir).inputs == scenario.inputs


def test_cutting_power_from_the_force_needs_an_fmu_that_takes_it(tmp_path: Path, fmu_dir: Path) -> None:
    """A SpindlePower built before the input cutting_power (its model description without it) is named."""
    old = tmp_path / "fmus"
    old.mkdir()
    for name in ("Interpolator", "Workpiece", "CuttingForce", "ToolVibration"):
        (old / f"{name}.fmu").symlink_to(fmu_dir / f"{name}.fmu")
    with zipfile.ZipFile(fmu_dir / "SpindlePower.fmu") as source, \
            zipfile.ZipFile(old / "SpindlePower.fmu", "w") as target:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb'\s*<Float64 name="cutting_power" [^>]*/>', b"", data)
                data = re.sub(rb' dependencies(Kind)?="[^"]*"', b"", data)  # an FMU of then declared none
            target.writestr(item, data)
    path = write_part(tmp_path / "part")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, old)
    assert str(info.value) == (f"{path}: [part].cutting_power: \"force\" needs SpindlePower's input cutting_power, "
                               f"which the FMU in {old} does not have (built before it was added): rebuild the FMUs, "
                               f"or use cutting_power = \"mrr\"")
    mrr = write_part(tmp_path / "mrr", ("material = ", 'cutting_power = "mrr"\nmaterial = '))
    assert not any(str(c.target) == "power.cutting_power" for c in load_scenario(mrr, old).connections)


@pytest.mark.parametrize("seed", range(1, 11))
def test_random_programs_of_the_benchmark_expand_as_whole_parts(tmp_path: Path, fmu_dir: Path, seed: int) -> None:
    """The seeded random programs of tests/benchmarks/generated_parts.py (the whole-part benchmark's --generated)
    pass the checks before the run and expand, with the bracket's tool, the ring-down hold and the program's
    machining time."""
    from benchmarks.generated_parts import write_generated_part

    scenario = load_scenario(write_generated_part(tmp_path, seed), fmu_dir)
    assert scenario.name == f"generated_{seed}" and scenario.part.tool.diameter == pytest.approx(0.01)
    assert scenario.stepping.hold_intervals == math.ceil(math.log(1e6) / (0.03 * 2 * math.pi * 2800) / 1e-3)
    assert 10.0 < scenario.part.machining_time < 120.0


def test_values_changed_after_the_expansion_move_the_ring_down_hold(tmp_path: Path, fmu_dir: Path) -> None:
    """``with_values`` (``--set``, a study's cases) on a whole part: a lower damping rings down longer, so the hold
    follows the modes as they are now; a hold the part file fixes stays; a mode switched on without its values is
    an error naming the missing one."""
    scenario = load_scenario(write_part(tmp_path / "a"), fmu_dir)
    assert scenario.stepping.hold_intervals == math.ceil(RING_DOWN_MODES / 1e-3 - 1e-9)
    lower = with_values(scenario, {"vibration.damping_y1": 0.005})
    assert lower.stepping.hold_intervals == math.ceil(math.log(1e6) / (0.005 * 2 * math.pi * 1300) / 1e-3 - 1e-9)
    assert with_values(scenario, {"force.Ktc": 7e8}).stepping == scenario.stepping
    fixed = load_scenario(write_part(tmp_path / "b", ("[part.tool_modes]", "[part.stepping]\nhold = 0.02\n"
                                                                            "[part.tool_modes]")), fmu_dir)
    assert with_values(fixed, {"vibration.damping_y1": 0.005}).stepping.hold_intervals == 20
    with pytest.raises(ScenarioError) as info:
        with_values(scenario, {"vibration.n_modes_x": 2})
    assert "a mode of the tool is switched on without its frequency_x2" in info.value.detail

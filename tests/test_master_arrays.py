"""Array variables in scenarios: the Workpiece's 8 x 24 engagement map connected to ForceNet's map input as one
connection of the whole array (FMI 3: one variable with one value reference and 192 values per call; FMI 2:
192 scalars engagement[i,j]), on both stepping paths, with the mistakes a scenario can make named. The run is
scenarios/slot_entry_forcenet.toml, shortened: the tool starts with its centre 6 mm before the block, so the
entry (where the map and the window differ) and the full slot (where they agree) both happen within 0.7 s."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from milling_twin.orchestrator import fastpath
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario

REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / "scenarios" / "slot_entry_forcenet.toml"
MAP_CONNECTION = ('[[connections]]\nfrom = "workpiece.engagement"       # the whole 8 x 24 map\n'
                  'to = "force.engagement"\n')


def scenario_text(fmi: int = 3, stop_time: float = 0.7, start_x_mm: float = -6.0, with_map: bool = True) -> str:
    text = SCENARIO.read_text()
    assert MAP_CONNECTION in text
    text = text.replace('program = { path = "programs/slot_entry.nc" }',
                        f'program = {{ path = "{REPO / "scenarios" / "programs" / "slot_entry.nc"}" }}')
    text = text.replace("stop_time = 1.2", f"stop_time = {stop_time}")
    text = text.replace('start_x = { value = -14.0, unit = "mm" }',
                        f'start_x = {{ value = {start_x_mm}, unit = "mm" }}')
    text = re.sub(r'(fmu = "\w+"\n)', rf"\1fmi = {fmi}\n", text)
    return text if with_map else text.replace(MAP_CONNECTION, "")


def write(tmp_path: Path, text: str, name: str = "case.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def run_case(tmp_path: Path, fmu_dir: Path, text: str, stepping: str = "auto", name: str = "case"):
    scenario = load_scenario(write(tmp_path, text, f"{name}.toml"), fmu_dir)
    result = run(scenario, tmp_path / name, progress=False, stepping=stepping)
    assert result.status == "completed"
    return result, load_results(result.run_dir)


def test_the_map_reaches_forcenet_in_fmi3_and_fmi2_on_both_paths(tmp_path: Path, fmu_dir: Path) -> None:
    fmi3, frame3 = run_case(tmp_path, fmu_dir, scenario_text(3), stepping="python", name="fmi3")
    fast3, frame3f = run_case(tmp_path, fmu_dir, scenario_text(3), name="fmi3fast")
    fmi2, frame2 = run_case(tmp_path, fmu_dir, scenario_text(2), name="fmi2")
    python2, frame2p = run_case(tmp_path, fmu_dir, scenario_text(2), stepping="python", name="fmi2python")
    if fastpath.find_library(load_scenario(write(tmp_path, scenario_text(2)), fmu_dir))[0] is not None:
        assert fmi2.stepping == fast3.stepping == "fast"  # the FMI 3 array too: one value reference, 192 values
    for frame in (frame2, frame2p, frame3f):  # FMI 2 scalars and the FMI 3 array, compiled and Python loop: the same
        assert list(frame.columns) == list(frame3.columns)
        assert np.array_equal(frame.to_numpy(), frame3.to_numpy())
    without, frame_window = run_case(tmp_path, fmu_dir, scenario_text(3, with_map=False), name="window")
    t = frame3["time"].to_numpy()
    x = frame3["interp.x"].to_numpy()
    full_slot = x > 1e-3  # the front half in material: map columns 0..11 (0..180 deg) all 1, window 0..180 deg
    entry = frame3["workpiece.entry_angle"].to_numpy() > 0.3  # the Workpiece's window is 0..180 deg from 16 deg
    assert full_slot.sum() > 1000 and entry.sum() > 500, (full_slot.sum(), entry.sum())
    fx, fx_window = frame3["force.Fx"].to_numpy(), frame_window["force.Fx"].to_numpy()
    # a full slot's map holds the window's elements exactly; while entering, the map's 15 deg cells differ
    # from the window's exact angles (but not by much)
    assert np.array_equal(fx[full_slot], fx_window[full_slot])
    assert np.count_nonzero(fx[entry] != fx_window[entry]) > 100
    assert np.abs(fx - fx_window)[entry].mean() < 0.2 * np.abs(fx_window[entry]).mean()
    assert np.any(np.abs(fx[t < 0.1]) > 10.0)  # the tool cuts from the start (its edge is in the block)


MISTAKES = {  # edit of the scenario text -> (the key, the message)
    "array to scalar": (('to = "force.engagement"', 'to = "force.axial_depth"'),
                        ("[[connections]][10].to", "shape mismatch: workpiece.engagement is an array of 8x24 "
                                                   "values, force.axial_depth is a scalar")),
    "one element of an FMI 3 array": ((MAP_CONNECTION.removeprefix("[[connections]]\n"),
                                       'from = "workpiece.radial_depth"\nto = "force.engagement[2,3]"\n'),
                                      ("[[connections]][10].to", "force.engagement[2,3] is an element of the FMI 3 "
                                                                 "array force.engagement, which is set whole")),
    "recorded channel into an array": (("[outputs]", '[recorded]\nfile = "data.csv"\nsample_period = 0.1\n'
                                                   '[recorded.channels]\nc = { column = "c" }\n'
                                                   '[[inputs]]\nfrom = "c"\nto = "force.engagement"\n[outputs]'),
                                        ("[[inputs]][0].to", "force.engagement is an array of 8x24 values: connect "
                                                             "it to an array input of the same shape")),
    "array as a constant": (("[fmus.force.parameters]", "[fmus.force.inputs]\nengagement = 1.0\n"
                                                        "[fmus.force.parameters]"),
                            ("[fmus.force].inputs.engagement", "input 'engagement' is of unsupported type real[]: "
                                                               "arrays are set from connections only")),
}


@pytest.mark.parametrize("case", list(MISTAKES))
def test_array_mistakes_are_named(tmp_path: Path, fmu_dir: Path, case: str) -> None:
    (old, new), (key, message) = MISTAKES[case]
    text = scenario_text(3)
    (tmp_path / "data.csv").write_text("c\n0\n1\n2\n3\n4\n5\n6\n7\n8\n")
    assert old in text
    with pytest.raises(ScenarioError) as error:
        load_scenario(write(tmp_path, text.replace(old, new, 1)), fmu_dir)
    assert error.value.key == key and message in error.value.detail, str(error.value)


def test_arrays_are_recorded_whole_or_by_element(tmp_path: Path, fmu_dir: Path) -> None:
    text = scenario_text(3, stop_time=0.01).replace('record = ["interp.x",',
                                                    'record = ["workpiece.engagement", "force.engagement[1,5]", '
                                                    '"interp.x",')
    _, frame = run_case(tmp_path, fmu_dir, text)
    names = [f"workpiece.engagement[{i},{j}]" for i in range(1, 9) for j in range(1, 25)]
    assert list(frame.columns[1:194]) == names + ["force.engagement[1,5]"]
    # an input recorded is the value set before the step: the Workpiece's map of the same tick (it steps first)
    assert np.array_equal(frame["force.engagement[1,5]"], frame["workpiece.engagement[1,5]"])
    assert frame[names].to_numpy().max() == 1.0

"""The process report of a whole-part run: the per-block table on a synthetic frame (exact numbers), the chatter
indicator on synthetic signals and on co-simulations either side of the stability limit, and the whole report of
a real part run (every section, nothing external, a run without the power instance)."""
from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from stl import mesh

from cases.part_case import MODES, write_part
from milling_twin.models.interpolator.parser import Tool
from milling_twin.models.stability import Mode
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.part import chatter
from milling_twin.orchestrator.part.blocks import (PLUNGE_SLOPE, Signals, block_spans, block_table, plunge_note,
                                                   write_block_table)
from milling_twin.orchestrator.part.model import Material, Part, Stock
from milling_twin.orchestrator.part.report import write_process_report
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Ref, load_scenario, with_values

REPO = Path(__file__).resolve().parents[1]

# ---- the per-block table on a synthetic frame ----

LINES = [0, 3, 3, 3, 5, 5, 5, 5, 3, 3]   # blocks: line 3 (samples 1-3), line 5 (4-7), line 3 again (8-9)


def _frame(power: bool = True) -> pd.DataFrame:
    z = [0.0] * 10
    data = {
        "time": np.arange(10) * 0.1,
        "interp.line_number": pd.array(LINES, dtype="Int32"),
        "interp.feed": [0, .01, .01, .02, .03, .03, .03, .03, 0, 0],
        "interp.spindle_speed": [100.0] * 8 + [50.0] * 2,
        "interp.tool_number": [1] * 8 + [2] * 2,
        "interp.x": z, "interp.y": z, "interp.z": z,
        "workpiece.axial_depth": [0, 0, 1e-3, 1e-3, 2e-3, 2e-3, 0, 0, 0, 0],
        "workpiece.radial_depth": [0, 0, 5e-3, 5e-3, 10e-3, 10e-3, 0, 0, 0, 0],
        "workpiece.mrr": [0, 0, 1e-5, 1e-5, 1e-5, 2e-5, 0, 0, 0, 0],
        "workpiece.removed_volume": [0, 0, 1e-6, 2e-6, 3e-6, 5e-6, 5e-6, 5e-6, 5e-6, 5e-6],
        "force.Fx": [0, 0, 10, 20, -30, 50, 0, 0, 0, 0],
        "force.Fy": [0, 0, 0, 0, 40, 0, 0, 0, 0, 0],
        "force.Fz": z,
        "force.torque": [0, 0, 1, 3, 2, 2, 0, 0, 0, 0],
        "vibration.tip_displacement_x": [0, 0, 3e-6, 0, 0, 0, 0, 0, 0, 0],
        "vibration.tip_displacement_y": [0, 0, 4e-6, 0, 0, 0, 0, 0, 0, 0],
    }
    if power:
        data["power.P_total"] = [500, 600, 700, 800, 900, 1000, 1100, 1200, 1300, 1400]
    return pd.DataFrame(data)


def test_block_table_on_a_synthetic_frame(tmp_path: Path) -> None:
    signals = Signals(_frame())
    spans = block_spans(signals["interp.line_number"])
    table = block_table(signals, spans, {3: 0.01, 5: 0.0})
    assert table["line"].tolist() == [3, 5, 3]
    assert table["start_time"].tolist() == pytest.approx([0.1, 0.4, 0.8])
    assert table["end_time"].tolist() == pytest.approx([0.4, 0.8, 0.9])
    assert table["duration"].tolist() == pytest.approx([0.3, 0.4, 0.1])
    assert table["feed_programmed"].tolist() == [0.01, 0.0, 0.01]
    assert table["feed_mean"].tolist() == pytest.approx([0.04 / 3, 0.03, 0.0])
    assert table["spindle_speed"].tolist() == pytest.approx([100.0, 100.0, 50.0])
    assert table["tool"].tolist() == [1, 1, 2]
    assert table["mrr_mean"].tolist() == pytest.approx([2e-5 / 3, 3e-5 / 4, 0.0])
    assert table["mrr_max"].tolist() == pytest.approx([1e-5, 2e-5, 0.0])
    assert table["removed_volume"].tolist() == pytest.approx([2e-6, 3e-6, 0.0])
    assert table["removed_volume"].sum() == pytest.approx(5e-6)
    assert table["force_x_mean"].tolist()[:2] == pytest.approx([15.0, 10.0])   # over the in-cut samples
    assert math.isnan(table["force_x_mean"].iloc[2])
    assert table["force_x_max"].tolist() == pytest.approx([20.0, 50.0, 0.0])   # of |Fx|
    assert table["force_y_mean"].tolist()[:2] == pytest.approx([0.0, 20.0])
    assert table["force_mean"].tolist()[:2] == pytest.approx([15.0, 50.0])
    assert table["force_max"].tolist() == pytest.approx([20.0, 50.0, 0.0])
    assert table["torque_mean"].tolist()[:2] == pytest.approx([2.0, 2.0])
    assert table["torque_max"].tolist() == pytest.approx([3.0, 2.0, 0.0])
    assert table["spindle_power_mean"].tolist() == pytest.approx([700.0, 1050.0, 1350.0])
    assert table["spindle_power_max"].tolist() == pytest.approx([800.0, 1200.0, 1400.0])
    assert table["cutting_power_mean"].isna().all()             # neither power.P_cutting nor force.power
    assert table["deflection_max"].tolist() == pytest.approx([5e-6, 0.0, 0.0])
    assert table["axial_depth_max"].tolist() == pytest.approx([1e-3, 2e-3, 0.0])
    assert table["radial_depth_max"].tolist() == pytest.approx([5e-3, 10e-3, 0.0])
    assert table["in_cut_fraction"].tolist() == pytest.approx([2 / 3, 0.5, 0.0])

    write_block_table(table, tmp_path / "b.parquet", tmp_path / "b.csv")
    csv = pd.read_csv(tmp_path / "b.csv")
    assert csv["feed_mean [mm/min]"].tolist() == pytest.approx([800.0, 1800.0, 0.0])
    assert csv["spindle_speed [rpm]"].tolist() == pytest.approx([954.93, 954.93, 477.465], rel=1e-5)
    assert csv["removed_volume [cm3]"].tolist() == pytest.approx([2.0, 3.0, 0.0])
    assert csv["deflection_max [um]"].tolist() == pytest.approx([5.0, 0.0, 0.0])
    assert csv["force_max [N]"].tolist() == pytest.approx([20.0, 50.0, 0.0])
    assert csv["in_cut_fraction"].tolist() == pytest.approx([2 / 3, 0.5, 0.0])
    assert csv["chatter"].tolist() == [False] * 3                     # no unit in the header of a flag
    assert csv["plunge"].tolist() == [False] * 3                      # no descents given: no plunge
    parquet = pq.read_table(tmp_path / "b.parquet")
    field = parquet.schema.field("feed_mean")
    assert field.metadata[b"unit"] == b"m/s" and field.metadata[b"display_unit"] == b"mm/min"
    assert parquet.column("feed_mean").to_pylist() == pytest.approx([0.04 / 3, 0.03, 0.0])


def test_a_block_is_a_plunge_when_its_line_descends_steeply_and_it_removes_material() -> None:
    signals = Signals(_frame())
    spans = block_spans(signals["interp.line_number"])
    # line 3 steep: its first block removes material, its second (after line 5) none; line 5 is just not steep
    table = block_table(signals, spans, {3: 0.01, 5: 0.01}, {3: 1.0, 5: PLUNGE_SLOPE})
    assert table["plunge"].tolist() == [True, False, False]
    assert plunge_note(table) == [
        "plunging or steeply ramping while cutting (descending more than 0.25 per length of path), line 3: the "
        "force models have flank edges only, so the end cutting is not in these blocks' force, torque, cutting "
        "power, deflection and chatter (their MRR and removed volume are the Workpiece's)"]
    table.loc[:, "plunge"] = True
    assert "lines 3, 5: " in plunge_note(table)[0]     # each line once, in the order of the run
    assert plunge_note(table.iloc[:0]) == []


def test_blocks_of_a_line_executed_twice_and_no_line_zero() -> None:
    spans = block_spans(np.array([0, 0, 7, 7, 8, 7, 7, 0]))
    assert spans.lines.tolist() == [7, 8, 7]
    assert spans.starts.tolist() == [2, 4, 5] and spans.stops.tolist() == [4, 5, 7]


# ---- the chatter indicator ----

FS, F_TP = 1e4, 200.0        # sampling 1e-4 s; 6000 rpm, 2 flutes


def _harmonics(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = 2e-6 * np.cos(2 * np.pi * F_TP * t) + 0.7e-6 * np.cos(4 * np.pi * F_TP * t + 0.3) + 5e-6
    y = 1e-6 * np.sin(2 * np.pi * F_TP * t) + 0.4e-6 * np.cos(6 * np.pi * F_TP * t)
    return x, y


def test_chatter_indicator_of_pure_harmonics_is_near_zero() -> None:
    t = np.arange(0, 0.2, 1 / FS)
    x, y = _harmonics(t)
    result = chatter.analyse(t, x, y, np.ones(t.size, bool), 2 * np.pi * F_TP / 2, 2)
    assert result.indicator < 1e-3
    assert abs(result.growth) < 0.5
    assert not result.chatter


def test_chatter_indicator_of_a_growing_mode_is_large() -> None:
    t = np.arange(0, 0.2, 1 / FS)
    x, y = _harmonics(t)
    growing = 0.2e-6 * np.exp(30.0 * t)                      # 1/s
    x, y = x + growing * np.cos(2 * np.pi * 922.0 * t), y + growing * np.sin(2 * np.pi * 922.0 * t)
    result = chatter.analyse(t, x, y, np.ones(t.size, bool), 2 * np.pi * F_TP / 2, 2)
    assert result.indicator > 0.8
    assert 10.0 < result.growth < 35.0
    assert result.chatter
    # too few tooth periods in cut: no indicator
    short = chatter.analyse(t[:100], x[:100], y[:100], np.ones(100, bool), 2 * np.pi * F_TP / 2, 2)
    assert math.isnan(short.indicator)


def test_a_dying_mode_vibration_is_no_chatter() -> None:
    """The free vibration after the flutes leave a cut: at the mode's frequency (a high indicator) but dying out
    (by e^-6 over the 0.2 s; the fitted rate is lower, the harmonics being in the RMS); the same vibration held at
    its amplitude (saturated chatter) is chatter."""
    t = np.arange(0, 0.2, 1 / FS)
    x, y = _harmonics(t)
    for rate, chatters in ((-30.0, False), (0.0, True)):
        mode = 20e-6 * np.exp(rate * t)
        result = chatter.analyse(t, x + mode * np.cos(2 * np.pi * 922.0 * t), y + mode * np.sin(2 * np.pi * 922.0 * t),
                                 np.ones(t.size, bool), 2 * np.pi * F_TP / 2, 2)
        assert result.indicator > chatter.CHATTER_THRESHOLD and result.duration == pytest.approx(0.2, abs=2e-4)
        assert result.dies_out is not chatters and result.chatter is chatters, (rate, result)


def test_chatter_indicator_separates_stable_and_chattering_co_simulations(fmu_dir: Path, tmp_path: Path) -> None:
    """scenarios/chatter.toml at 0.03 mm (stable, 0.75 of the zero-order limit) and at 0.08 mm (twice the limit)."""
    base = load_scenario(REPO / "scenarios" / "chatter.toml", fmu_dir)
    results = {}
    for name, depth in (("stable", 0.03), ("chatter", 0.08)):
        scenario = with_values(base, {"force.axial_depth": {"value": depth, "unit": "mm"}}, name=name)
        frame = load_results(run(scenario, tmp_path, progress=False).run_dir)
        t = frame["time"].to_numpy()
        results[name] = chatter.analyse(t, frame["vibration.tip_displacement_x"].to_numpy(),
                                        frame["vibration.tip_displacement_y"].to_numpy(), np.ones(t.size, bool),
                                        6000 * 2 * np.pi / 60, 2)
    stable, unstable = results["stable"], results["chatter"]
    assert stable.indicator < 0.01 < 0.9 < unstable.indicator
    assert stable.indicator < chatter.CHATTER_THRESHOLD < unstable.indicator
    assert stable.growth < 1.0 and unstable.growth > 10.0


# ---- the whole report on a real part run ----

PROGRAM = """\
G21 G90 G17
T1 M6
S6000 M3
G43 G0 X-10 Y10 Z5 H1
G1 Z-2 F300
G1 X60 F600
G0 Z5
G0 X60 Y18
G1 Z-2 F300
G1 X-10 F600
G0 Z5
M5
M30
"""
TOOLS = "T1 P1 D10 Z50 ; end mill flutes=3 helix=30 stick_out=25\n"
# the tiny part of tests/cases/part_case.py, changed into this one
PART_EDITS = (
    ('name = "tiny_part"', 'name = "report_part"'),
    ('description = "one slot through a small block"',
     'description = "a slot, then a down-milling side cut 8 mm wide along its wall; G43 H1 (tool length 50 mm)"'),
    ('size = { value = [50.0, 20.0, 10.0], unit = "mm" }', 'size = { value = [50.0, 30.0, 10.0], unit = "mm" }'),
    ('start_z = { value = 5, unit = "mm" }', 'start_z = { value = 55, unit = "mm" }'),
    ('[part.spindle]\nP_idle = { value = 0.3, unit = "kW" }\n', ''),
    (MODES, """[part.tool_modes]
x = [ { frequency = 1200.0, damping = 0.03, stiffness = 2.0e7 } ]
y = [ { frequency = 1300.0, damping = 0.02, stiffness = 3.0e7 } ]
"""),
)


@pytest.fixture(scope="module")
def part_run(tmp_path_factory: pytest.TempPathFactory, fmu_dir: Path) -> tuple[Part, pd.DataFrame, Path, Path]:
    folder = tmp_path_factory.mktemp("part")
    scenario = load_scenario(write_part(folder, *PART_EDITS, program=PROGRAM, tools=TOOLS), fmu_dir)
    zmap = folder / "final.asc"
    scenario = with_values(scenario, {"workpiece.zmap_file": str(zmap)})
    scenario = replace(scenario, outputs=(*scenario.outputs, Ref("force", "spindle_angle")))
    result = run(scenario, folder / "runs", progress=False)
    assert scenario.part is not None
    return scenario.part, load_results(result.run_dir), result.run_dir, zmap


def test_process_report_of_a_part_run(part_run: tuple[Part, pd.DataFrame, Path, Path]) -> None:
    part, frame, run_dir, zmap = part_run
    report = write_process_report(part, frame, run_dir / "report", zmap_file=zmap, warnings=("a run warning",))
    assert report.wall_time < 10.0
    text = report.html.read_text(encoding="utf-8")
    for section in ("Headline", "Force, torque and power over time", "Tool path: resultant force",
                    "Tool path: chatter indicator", "Machined surface: final Z-map heights",
                    "Stability lobes of T1 and its cutting blocks", "Blocks", "a run warning"):
        assert section in text, section
    assert "http://" not in text and "https://" not in text and "<script" not in text
    assert set(re.findall(r"src='([a-z]+):", text)) == {"data"} and text.count("src=") == 5
    table = pd.read_parquet(report.blocks_parquet)
    assert len(table) == report.blocks and report.chatter_blocks == 0
    # the same cells: the run's removed volume and stock - final Z-map
    assert report.removed_volume_zmap == pytest.approx(report.removed_volume, rel=1e-9)
    assert table["removed_volume"].sum() == pytest.approx(report.removed_volume, rel=1e-12)
    slot = table[table["line"] == 6].iloc[0]
    side = table[table["line"] == 10].iloc[0]
    assert slot["radial_depth_max"] == pytest.approx(10e-3, rel=1e-6)
    assert side["radial_depth_max"] == pytest.approx(8e-3, abs=0.5e-3)
    # straight cuts at constant depth: the removed volume against width x length x depth (cells of 0.5 mm
    # across 10 and 8 mm: within about 1/20 and 1/16)
    assert slot["volume_ratio"] == pytest.approx(1.0, abs=0.05)
    assert side["volume_ratio"] == pytest.approx(1.0, abs=0.07)
    assert slot["chatter_indicator"] < chatter.CHATTER_THRESHOLD
    # the walls' surface location error is a deflection: finite, and within the largest deflection
    for block in (slot, side):
        assert np.isfinite(block["sle_mean"]) and 0 < block["sle_max"] <= block["deflection_max"] * (1 + 1e-9)
    # the program zero (G43 H1: the tool length 50 mm) is taken off: the Z-map and the STL in the part's coordinates
    assert part.program_zero[2] == pytest.approx(0.05)
    assert report.stl is not None
    corners = mesh.Mesh.from_file(str(report.stl)).vectors.reshape(-1, 3)
    assert corners.min(axis=0).tolist() == pytest.approx([0.0, 0.0, -10.0], abs=1e-4)
    assert corners.max(axis=0).tolist() == pytest.approx([50.0, 30.0, 0.0], abs=1e-4)
    assert report.cutting_time < report.machining_time
    assert report.json.is_file() and report.blocks_csv.is_file()
    # its G1 Z-2 lines plunge beside the stock, removing nothing: no plunge block, no plunge note
    assert not table["plunge"].any() and "plunging" not in text


def test_process_report_without_power_or_z_map(part_run: tuple[Part, pd.DataFrame, Path, Path],
                                               tmp_path: Path) -> None:
    part, frame, _, _ = part_run
    no_power = frame.drop(columns=[c for c in frame.columns if c.startswith("power.")])
    report = write_process_report(part, no_power, tmp_path, zmap_file=None)
    text = report.html.read_text(encoding="utf-8")
    assert "Headline" in text and "Blocks" in text and "Machined surface" not in text
    assert any("no Z-map file" in w for w in report.warnings)
    table = pd.read_parquet(report.blocks_parquet)
    assert table["spindle_power_max"].isna().all()
    assert table["cutting_power_max"].max() > 0          # force.power stands in
    assert report.max_power == pytest.approx(np.abs(frame["force.power"]).max())
    assert report.stl is None and report.removed_volume_zmap is None


def test_process_report_names_a_tool_without_flutes(tmp_path: Path) -> None:
    part = Part(program=tmp_path / "missing.nc", dialect="fanuc", tool_table=None,
                tool=Tool(number=4, diameter=0.01), stock=Stock((0.0, 0.0, 0.0), (0.05, 0.03, 0.01), 5e-4),
                material=Material("test", {"Ktc": 7e8, "Krc": 2e8}), modes_x=(Mode(1000.0, 0.03, 2e7),),
                modes_y=())
    report = write_process_report(part, _frame(power=False), tmp_path, zmap_file=tmp_path / "absent.asc")
    assert any("tool T4 has no flute count" in w for w in report.warnings)
    assert any("missing.nc: programmed feeds not read" in w for w in report.warnings)
    assert any("absent.asc: the Z-map file was not written" in w for w in report.warnings)
    assert report.blocks == 3 and report.removed_volume == pytest.approx(5e-6)


def test_a_slot_beyond_the_lobes_chatters_and_a_side_cut_within_them_does_not(fmu_dir: Path, tmp_path: Path) -> None:
    """The part above 0.2 mm deep on the flexible tool of scenarios/chatter.toml (922 Hz, 1.1 %, 1.34e6 N/m in x
    and y). Zero-order limits at 6000 rpm with 3 flutes: 0.15 mm slotting, 1.2 mm for the side cut's immersion
    (53..180 deg): the slot chatters, the side cut does not."""
    mode = "[ { frequency = 922.0, damping = 0.011, stiffness = 1.34e6 } ]"
    flexible = (*PART_EDITS[:-1], (MODES, f"[part.tool_modes]\nx = {mode}\ny = {mode}\n"))
    scenario = load_scenario(write_part(tmp_path, *flexible, program=PROGRAM.replace("G1 Z-2 F300", "G1 Z-0.2 F300"),
                                        tools=TOOLS), fmu_dir)
    result = run(scenario, tmp_path / "runs", progress=False)
    assert scenario.part is not None and scenario.part.modes_x[0].frequency == 922.0
    report = write_process_report(scenario.part, load_results(result.run_dir), tmp_path / "report", zmap_file=None)
    table = pd.read_parquet(report.blocks_parquet)
    slot, side = table[table["line"] == 6].iloc[0], table[table["line"] == 10].iloc[0]
    assert slot["chatter"] and slot["chatter_indicator"] > 0.9
    assert not side["chatter"] and side["chatter_indicator"] < 0.01
    assert report.chatter_blocks == 1
    assert "<tr class='chatter'>" in report.html.read_text(encoding="utf-8")


def test_long_programs_and_comparisons_in_the_html(tmp_path: Path) -> None:
    """250 blocks: the HTML shows the 200 with the largest resultant force, the CSV all; a recorded comparison is
    listed with its RMS error in its display unit and its plot embedded."""
    from matplotlib.figure import Figure

    from milling_twin.orchestrator.report import Comparison

    n = 250 * 20
    load = (np.arange(n) // 20 * 37 % 250).astype(float)       # block b's force: a permutation of 0..249
    frame = pd.DataFrame({"time": np.arange(n) * 1e-3, "interp.line_number": np.arange(n) // 20 + 1,
                          "interp.x": np.zeros(n), "interp.y": np.zeros(n), "interp.z": np.zeros(n),
                          "workpiece.axial_depth": np.full(n, 1e-3), "force.Fx": load})
    figure = Figure(figsize=(2, 1))
    figure.subplots().plot([0, 1])
    figure.savefig(tmp_path / "compare_power_P_total.png")
    comparison = Comparison(simulated="power.P_total", recorded="spindle_power", unit="W", display_unit="kW",
                            n_samples=1055, rms_error=22.82, mean_abs_error=15.0, max_error=90.0,
                            mean_recorded=300.0, relative_rms=0.13, plot="compare_power_P_total.png")
    part = Part(program=tmp_path / "p.nc", dialect="fanuc", tool_table=None, tool=Tool(1, 0.01, flutes=2),
                stock=Stock((0.0, 0.0, 0.0), (0.05, 0.03, 0.01), 5e-4), material=Material("m", {}), modes_x=(),
                modes_y=())
    report = write_process_report(part, frame, tmp_path, zmap_file=None, comparisons=[comparison])
    text = report.html.read_text(encoding="utf-8")
    assert "The 200 most loaded of 250 blocks" in text
    rows = re.findall(r"<tr(?: class='chatter')?><td>(\d+)</td><td>(\d+)</td>", text)
    assert len(rows) == 200
    shown = sorted(int(line) for _, line in rows)
    loads = {b + 1: b * 37 % 250 for b in range(250)}
    assert min(loads[line] for line in shown) == 50                 # the 200 largest: 50 .. 249
    assert shown == sorted(shown) and [int(b) for b, _ in rows] == sorted(int(b) for b, _ in rows)
    assert len(pd.read_csv(report.blocks_csv)) == 250
    assert "Comparisons with the recording" in text and "0.02282 kW" in text and "13 %" in text
    assert "power.P_total vs spindle_power" in text
    assert set(re.findall(r"src='([a-z]+):", text)) == {"data"}


def test_no_stl_of_a_z_map_too_large(part_run: tuple[Part, pd.DataFrame, Path, Path], tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from milling_twin.orchestrator.part import report as report_module

    part, frame, _, zmap = part_run
    monkeypatch.setattr(report_module, "STL_MAX_CELLS", 5999)        # the part's Z-map: 100 x 60 cells
    report = write_process_report(part, frame, tmp_path, zmap_file=zmap)
    assert report.stl is None and not (tmp_path / "part.stl").exists()
    assert any("final.asc: no STL: the Z-map has 6000 cells, more than 5999" in w for w in report.warnings)
    assert report.removed_volume_zmap == pytest.approx(report.removed_volume, rel=1e-9)


def test_surface_location_error_without_the_force_models_spindle_angle(
        part_run: tuple[Part, pd.DataFrame, Path, Path]) -> None:
    """The flute angle summed from the commanded spindle speed is the force model's: the same SLE per block."""
    from milling_twin.orchestrator.part.surface import surface_location_errors

    part, frame, _, _ = part_run
    with_angle = Signals(frame)
    without = Signals(frame.drop(columns=["force.spindle_angle"]))
    spans = block_spans(with_angle["interp.line_number"])
    mean, largest, count = surface_location_errors(with_angle, spans, 3, part.coarse_step)
    mean2, largest2, count2 = surface_location_errors(without, spans, 3, part.coarse_step)
    assert count.tolist() == count2.tolist() and count.max() > 1000
    cut = count > 0
    assert mean2[cut] == pytest.approx(mean[cut], rel=1e-4) and largest2[cut] == pytest.approx(largest[cut], rel=1e-4)
    # down milling along the wall: the tool pushed off it (material left), a few um
    side = int(np.flatnonzero(spans.lines == 10)[0])
    assert 0.5e-6 < mean[side] < 10e-6

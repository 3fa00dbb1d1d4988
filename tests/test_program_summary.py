"""``milling-twin program``: a part program read as the Interpolator reads it, summarised for a person; a
program the FMU refuses is refused with the same message and exit code 2."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from milling_twin.models.interpolator.tool_table import read_tool_table
from milling_twin.orchestrator.gcode.program_summary import summarize

REPO = Path(__file__).resolve().parents[1]
CORPUS = REPO / "scenarios" / "programs" / "corpus"


def test_a_drilling_program_is_summarised_per_tool() -> None:
    tools = read_tool_table(CORPUS / "tool.tbl")
    summary = summarize(CORPUS / "fanuc" / "o1002_drill.nc", "fanuc", tools)
    assert summary.finished and summary.moves["dwell"] > 0 and summary.moves["rapid"] > 0
    assert [t.number for t in summary.tools] == sorted({t.number for t in summary.tools}, key=[
        t.number for t in summary.tools].index)  # in the order the program uses them
    assert sum(t.time for t in summary.tools) == pytest.approx(summary.time, abs=1e-9)
    assert sum(t.length for t in summary.tools) == pytest.approx(summary.length, rel=1e-12)
    assert all(t.diameter is not None for t in summary.tools if t.number)
    text = "\n".join(summary.lines())
    assert "machining time:" in text and "mm" in text


def test_without_a_tool_table_the_tools_are_reported_without_geometry() -> None:
    summary = summarize(CORPUS / "fanuc" / "o1002_drill.nc", "fanuc", ())
    assert all(t.diameter is None for t in summary.tools)
    assert any("no tool table" in note for note in summary.notes)


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "milling_twin", "program", *args], capture_output=True, text=True,
                          cwd=REPO)


def test_the_command_prints_the_summary(tmp_path: Path) -> None:
    result = run(str(CORPUS / "sinumerik" / "SURFACE.MPF"), "--dialect", "sinumerik", "--tool-table",
                 str(CORPUS / "tool.tbl"))
    assert result.returncode == 0, result.stderr
    assert "NURBS" in result.stdout and "machining time:" in result.stdout and "not modelled:" in result.stdout


def test_a_refused_program_exits_2_with_file_line_and_text(tmp_path: Path) -> None:
    program = tmp_path / "part.nc"
    program.write_text("O1001\nG21 G90\nG1 X10 F600\nG7 X1\nM30\n")
    result = run(str(program))
    assert result.returncode == 2
    assert result.stderr.startswith(f'error: {program} line 4: "G7 X1": a supported G code (G0 G1 G2 G3 ')
    assert result.stderr.strip().endswith("), got G7")


def test_a_bad_param_is_a_usage_error(tmp_path: Path) -> None:
    result = run(str(CORPUS / "fanuc" / "o1002_drill.nc"), "--param", "acceleration")
    assert result.returncode == 2 and "--param 'acceleration': expected NAME=VALUE" in result.stderr


def test_the_cam_scenario_runs_the_program_with_its_tools_and_coolant(tmp_path: Path) -> None:
    import milling_twin

    result = subprocess.run([sys.executable, "-m", "milling_twin", "run", "scenarios/cam_pocket.toml", "--out",
                             str(tmp_path)], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "M1: program stop not modelled" in result.stderr  # the FMU's warning reaches the user
    data = milling_twin.load_results(tmp_path / "cam_pocket")
    assert sorted(data["interp.tool_number"].unique()) == [0, 1, 5]
    assert set(data["interp.tool_diameter"][data["interp.tool_number"] == 5].unique()) == {0.012}
    assert set(data["interp.coolant"].unique()) == {0, 2} and data["interp.finished"].iloc[-1]
    # the tool length of G43 H1/H5 lies between the machine Z and the programmed Z of the tip
    cutting = data[data["interp.tool_number"] == 1]
    offset = (cutting["interp.z"] - cutting["interp.z_program"]).round(9).unique()
    assert 0.05 in offset

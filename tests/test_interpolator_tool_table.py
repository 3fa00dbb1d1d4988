"""The Interpolator's tool table (LinuxCNC format): the C reader (through the standalone driver and the FMU) and
the Python reference read the same tools and refuse the same lines with the same message."""
from __future__ import annotations

import math
import subprocess
from pathlib import Path

import pytest

from fmu_helpers import ERROR, Slave, fmu_dir, fmu_file_name, repo_root, require_fmu, status_of
from milling_twin.models.interpolator import parser as gp
from milling_twin.models.interpolator import tool_table as tt

DRIVER = repo_root() / "build" / "tools" / "interp_run"

GOOD_TABLE = """; the tools of a small job (LinuxCNC's own format)
T1 P1 D10.000 Z+50.000 ; 10 mm end mill corner_radius=0.5 flutes=3 helix=30 stick_out=40 name=END10
T2 P2 D6.8 Z+80.5 ;6.8 mm drill flutes=2 helix=30
t12 p3 x0 y0 z+40 d3.175 i0 j0 q0 ;lower case and the columns LinuxCNC writes
T99999 P99999 Z+0.100000 ;big tool number
"""

# (name, table, line, what was expected)
BAD = [
    ("no tool number", "P1 D10\n", 1, '"P1 D10": the tool number T'),
    ("unknown word", "T1 D10 R3\n", 1,
     '"T1 D10 R3": a tool table word T, P, X, Y, Z, A, B, C, U, V, W, D, I, J, Q (letter and number), got \'R3\''),
    ("not a number", "T1 D1e2\n", 1, '"T1 D1e2": a number after \'D\', got \'D1e2\''),
    ("tool 0", "T0 D10\n", 1, '"T0 D10": a whole tool number T of 1 to 99999'),
    ("fractional tool", "T1.5 D10\n", 1, '"T1.5 D10": a whole tool number T of 1 to 99999'),
    ("a tool twice", "T1 D10\nT2 D6\nT1 D8\n", 3, '"T1 D8": tool T1 once in the table'),
    ("negative diameter", "T1 D-10\n", 1, '"T1 D-10": a diameter D >= 0'),
    ("two D words", "T1 D10 D12\n", 1, '"T1 D10 D12": one D word per tool'),
    ("corner radius above half the diameter", "T1 D10 ; corner_radius=6\n", 1,
     '"T1 D10 ; corner_radius=6": a corner_radius of 0 to half the diameter (5 mm), got 6'),
    ("fractional flutes", "T1 D10 ; flutes=2.5\n", 1, '"T1 D10 ; flutes=2.5": a whole number of flutes >= 0, got 2.5'),
    ("helix of 90 degrees", "T1 D10 ; helix=90\n", 1,
     '"T1 D10 ; helix=90": a helix angle of 0 to less than 90 degrees, got 90'),
    ("bad stick-out", "T1 D10 ; stick_out=long\n", 1,
     '"T1 D10 ; stick_out=long": a number of magnitude at most 100000 after stick_out=, got \'long\''),
    ("a name twice", "T1 D10 ; name=A\nT2 D10 ; name=A\n", 2, '"T2 D10 ; name=A": the name A once in the table'),
    ("too many digits", "T1 D10.1234567890123456\n", 1,
     '"T1 D10.1234567890123456": a number after \'D\', got \'D10.1234567890123456\''),
]


def run_driver(tmp_path: Path, table: str, program: str = "G21 G90\nG1 X1 F600\n") -> subprocess.CompletedProcess:
    assert DRIVER.is_file(), f"{DRIVER} not built"
    (tmp_path / "tool.tbl").write_text(table)
    (tmp_path / "part.nc").write_text(program)
    return subprocess.run([str(DRIVER), "--tool-table", str(tmp_path / "tool.tbl"), str(tmp_path / "part.nc")],
                          capture_output=True, text=True)


def test_a_linuxcnc_tool_table_is_read_in_si() -> None:
    tools = tt.parse_tool_table(GOOD_TABLE, "tool.tbl")
    assert [t.number for t in tools] == [1, 2, 12, 99999]
    end_mill = tt.find_tool(tools, 1)
    assert end_mill == gp.Tool(number=1, name="END10", diameter=0.01, corner_radius=0.0005, length=0.05,
                               stick_out=0.04, helix=math.radians(30.0), flutes=3)
    assert tt.find_tool(tools, 12).diameter == pytest.approx(3.175e-3, rel=1e-15)
    assert tt.find_tool(tools, 3) is None


def test_the_written_table_reads_back() -> None:
    tools = tt.parse_tool_table(GOOD_TABLE)
    again = tt.parse_tool_table(tt.tool_table_text(tools))
    for a, b in zip(tools, again):
        assert a.number == b.number and a.name == b.name and a.flutes == b.flutes
        for field in ("diameter", "corner_radius", "length", "stick_out", "helix"):
            assert getattr(b, field) == pytest.approx(getattr(a, field), rel=1e-9, abs=1e-12)


def test_the_c_reader_accepts_the_good_table(tmp_path: Path) -> None:
    result = run_driver(tmp_path, GOOD_TABLE)
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("name, table, line, tail", BAD, ids=[b[0] for b in BAD])
def test_bad_tool_tables_are_refused_alike(tmp_path: Path, name: str, table: str, line: int, tail: str) -> None:
    result = run_driver(tmp_path, table)
    assert result.returncode == 1, result
    assert result.stderr.strip() == f"interp_run: {tmp_path / 'tool.tbl'} line {line}: {tail}"
    with pytest.raises(gp.ProgramError) as raised:
        tt.parse_tool_table(table, str(tmp_path / "tool.tbl"))
    assert str(raised.value) == f"{tmp_path / 'tool.tbl'} line {line}: {tail}"


@pytest.mark.parametrize("version", [3, 2])
def test_the_fmu_refuses_a_bad_tool_table_naming_the_parameter(tmp_path: Path, version: int) -> None:
    table = tmp_path / "tool.tbl"
    table.write_text("T1 D10\nT1 D12\n")
    with Slave(require_fmu(fmu_dir() / fmu_file_name("Interpolator", version))) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.fmu.setString([slave.vr["tool_table"]], [str(table)])
        assert status_of(lambda: slave.exit_initialization()) == ERROR
        assert slave.last_error() == (f"exitInitializationMode: parameter 'tool_table': {table} line 2: "
                                      "\"T1 D12\": tool T1 once in the table")


@pytest.mark.parametrize("version", [3, 2])
def test_the_fmu_refuses_an_unknown_dialect(version: int) -> None:
    with Slave(require_fmu(fmu_dir() / fmu_file_name("Interpolator", version))) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.fmu.setString([slave.vr["dialect"]], ["heidenhain"])
        assert status_of(lambda: slave.exit_initialization()) == ERROR
        assert slave.last_error() == ("exitInitializationMode: parameter 'dialect' is 'heidenhain': expected fanuc, "
                                      "linuxcnc or sinumerik")


TOOL_PROGRAM = """O1001 (TOOL CHANGE)
G21 G90 G17 G40 G49 G80
T1 M6
S8000 M3
G54 G0 X0 Y0
G43 Z5. H1 M8
G1 Z-1. F300.
X20.
T2 M6
G0 Z5. M9
G1 X30. F600.
M30
"""


def test_the_active_tool_and_its_geometry_are_outputs_in_c_and_python(tmp_path: Path) -> None:
    """The tool changes at M6 and the coolant at M8/M9; the FMU (C) and the Python reference give the same
    outputs tick for tick, the geometry from the tool table."""
    from milling_twin.models.interpolator.engine import Interpolator

    (tmp_path / "tool.tbl").write_text(GOOD_TABLE)
    (tmp_path / "part.nc").write_text(TOOL_PROGRAM)
    tools = tt.read_tool_table(tmp_path / "tool.tbl")
    ref = Interpolator(TOOL_PROGRAM, {}, str(tmp_path / "part.nc"), tools=tools)
    names = ("x", "z", "tool_number", "tool_diameter", "tool_corner_radius", "tool_length", "tool_stick_out",
             "tool_helix_angle", "tool_flutes", "coolant")
    ref.set_override(1.0, 0.0)
    expected = []
    while not ref.out["finished"]:
        ref.tick()
        expected.append([ref.out[n] for n in names])
    with Slave(require_fmu(fmu_dir() / fmu_file_name("Interpolator", 3))) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.fmu.setString([slave.vr["program"], slave.vr["tool_table"]],
                            [str(tmp_path / "part.nc"), str(tmp_path / "tool.tbl")])
        slave.exit_initialization()
        got = []
        for _ in expected:
            assert slave.step(1e-3) == 0
            got.append([float(x) for x in slave.get(names)])
    assert got == expected
    tool_column = [row[2] for row in got]
    first_one, first_two = tool_column.index(1), tool_column.index(2)
    assert got[first_one][3:9] == [0.01, 0.0005, 0.05, 0.04, pytest.approx(math.radians(30.0)), 3]
    assert got[first_two][3:9] == [0.0068, 0.0, 0.0805, 0.0, pytest.approx(math.radians(30.0)), 2]
    assert got[first_one][9] == gp.COOLANT_FLOOD and got[-1][9] == gp.COOLANT_OFF
    # G43 H1: the tool tip at Z-1 puts the gauge line at Z-1 + 50 mm (the length of tool 1)
    cutting = [r[1] for r in got if r[0] > 0.001 and r[2] == 1]  # along G1 X20 (tool 1)
    assert cutting and max(cutting) == min(cutting) == pytest.approx(-0.001 + 0.05, abs=1e-12)


@pytest.mark.parametrize("version", [3, 2])
def test_words_not_modelled_are_reported_once_each_as_warnings(tmp_path: Path, version: int) -> None:
    program = tmp_path / "part.nc"
    program.write_text("G21\nM0\nG1 X1 F100\nM1\nM0\nM30\n")
    with Slave(require_fmu(fmu_dir() / fmu_file_name("Interpolator", version))) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.fmu.setString([slave.vr["program"]], [str(program)])
        slave.exit_initialization()  # status Warning (fmpy returns normally)
        function = "exitInitializationMode"
        assert slave.warnings() == [
            f'{function}: part program {program} line 2: "M0": M0: program stop not modelled (the program runs on)',
            f'{function}: part program {program} line 4: "M1": M1: program stop not modelled (the program runs on)']
        assert slave.step(1e-3) == 0

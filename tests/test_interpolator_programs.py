"""The G-code subset of the Interpolator: malformed programs fail initialization with the file, the line
number, the line's text and what was expected; the C parser (through the FMU and the standalone driver) and
the Python reference accept and reject the same programs at the same line; the documented forms parse."""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import ERROR, Slave, fmu_dir, fmu_file_name, repo_root, require_fmu, status_of
from milling_twin.models import interpolator as ip

DRIVER = repo_root() / "build" / "tools" / "interp_run"

# (name, program, line, the message's tail after 'line <n>: ')
BAD = [
    ("unknown G code", "G21 G90\nG1 X10 F600\nG7 X1\n", 3,
     '"G7 X1": a supported G code (G0 G1 G2 G3 G6.2 G10 G17 G18 G19 G20 G21 G54-G59 G90 G91), got G7'),
    ("missing coordinate", "G21\nG0 X1 Y2\nG1 X F600\n", 3, '"G1 X F600": a number after \'X\''),
    ("missing arc centre", "G1 X10 F100\nG2 X20 Y0\n", 2,
     '"G2 X20 Y0": the arc centre (I, J) or the radius R with G2'),
    ("knots decreasing", "G0 X1\nG6.2 P3 K0 X1 Y0 R1 F600\nK0.5 X2 Y1 R1\nK0.2 X3 Y0 R1\nK1\nK1\nK1\n", 4,
     '"K0.2 X3 Y0 R1": non-decreasing knots, got K0.2 after 0.5'),
    ("weight zero", "G0 X1\nG6.2 P3 K0 X1 Y0 R1 F600\nK0 X2 Y1 R0\nK0 X3 Y0 R1\nK1\nK1\nK1\n", 3,
     '"K0 X2 Y1 R0": a weight R > 0 (and at most 1e+06), got R0'),
    ("weight negative", "G0 X1\nG6.2 P3 K0 X1 Y0 R1 F600\nK0 X2 Y1 R-2\nK0 X3 Y0 R1\nK1\nK1\nK1\n", 3,
     '"K0 X2 Y1 R-2": a weight R > 0 (and at most 1e+06), got R-2'),
    ("F missing on the first feed move", "(no feed)\nG21 G90\nG0 X5\nG1 X10 Y3\n", 4,
     '"G1 X10 Y3": F (feed) before the first feed move (G1, G2, G3, G6.2)'),
    ("F missing on the first NURBS", "G6.2 P3 K0 X0 Y0 R1\nK0 X1 Y1\nK0 X2 Y0\nK1\nK1\nK1\n", 1,
     '"G6.2 P3 K0 X0 Y0 R1": F (feed) before the first feed move (G1, G2, G3, G6.2)'),
    ("unclosed comment", "G1 X10 F100 (open\n", 1, '"G1 X10 F100 (open": \')\' to close the comment'),
    ("unknown letter", "T1 M6\n", 1, '"T1 M6": a word G, M, N, X, Y, Z, I, J, K, R, F, S, P or L, got \'T\''),
    ("unsupported M code", "M8\n", 1, '"M8": a supported M code (M2 M3 M4 M5 M30), got M8'),
    ("two motion codes", "G0 G1 X1 F100\n", 1, '"G0 G1 X1 F100": one G code of the motion group per line, got G0 and G1'),
    ("two X words", "G1 X1 X2 F100\n", 1, '"G1 X1 X2 F100": one X word per line'),
    ("coordinates without a motion mode", "G21\nX10\n", 2,
     '"X10": a motion mode G0, G1, G2 or G3 before coordinates'),
    ("text after the program end", "G1 X1 F100\nM30\nG1 X2\n", 3,
     '"G1 X2": nothing after the program end (M2/M30 in line 2)'),
    ("arc end not on the circle", "G1 X10 F100\nG2 X20 Y0 I4 J0\n", 2,
     '"G2 X20 Y0 I4 J0": the end point on the arc: its distance from the centre is 6, the start\'s 4'),
    ("radius too small", "G1 X10 F100\nG2 X30 R5\n", 2,
     '"G2 X30 R5": a radius R of at least half the distance to the end point (10)'),
    ("first control point elsewhere", "G6.2 P3 K0 X5 Y0 R1 F600\nK0 X2 Y1\nK0 X3 Y0\nK1\nK1\nK1\n", 1,
     '"G6.2 P3 K0 X5 Y0 R1 F600": the first control point at the current position (0, 0, 0)'),
    ("too few closing knots", "G0 X1\nG6.2 P3 K0 X1 Y0 R1 F600\nK0 X2 Y1\nK0 X3 Y0\nK1\nK1\n", 6,
     '"K1": degree + 1 = 3 knot-only lines (K) closing the NURBS block started in line 2, got 2'),
    ("unclamped knots", "G6.2 P3 K0 X0 Y0 F600\nK0 X1 Y1\nK0.5 X2 Y0\nK1\nK1\nK1\n", 1,
     '"G6.2 P3 K0 X0 Y0 F600": a clamped knot vector (the first and the last 3 knots equal) in the NURBS block '
     'started here'),
    ("order out of range", "G6.2 P7 K0 X0 Y0 F600\n", 1,
     '"G6.2 P7 K0 X0 Y0 F600": an order P (degree + 1) of 2 to 6, got P7'),
    ("NURBS in G91", "G91\nG6.2 P3 K0 X0 Y0 F600\n", 2,
     '"G6.2 P3 K0 X0 Y0 F600": G90 (absolute coordinates) for a NURBS block'),
    ("other words in a NURBS block", "G6.2 P3 K0 X0 Y0 F600\nK0 X1 Y1 F300\n", 2,
     '"K0 X1 Y1 F300": K, X, Y, Z, R in a NURBS block (started in line 1), got F'),
    ("too many digits", "G1 X1.234567890123456789 F100\n", 1,
     '"G1 X1.234567890123456789 F100": at most 17 significant digits in the number after \'X\''),
    ("G10 without L2", "G10 P1 X1\n", 1, '"G10 P1 X1": L2 with G10 (set a work offset)'),
    ("a stray character", "G1 X1 F100 #\n", 1,
     '"G1 X1 F100 #": a word (letter and number), a comment or the end of the line, got \'#\''),
    ("a control character", "G1 X1\x01 F100\n", 1,
     '"G1 X1? F100": a word (letter and number), a comment or the end of the line, got byte 0x01'),
    ("a line too long", "(" + "x" * 1000 + ")\n", 1, None),
]


def run_driver(text: str, tmp_path: Path) -> subprocess.CompletedProcess:
    assert DRIVER.is_file(), f"{DRIVER} not built"
    program = tmp_path / "part.nc"
    program.write_bytes(text.encode("latin-1"))
    return subprocess.run([str(DRIVER), str(program)], capture_output=True, text=True)


@pytest.mark.parametrize("name, text, line, tail", BAD, ids=[b[0] for b in BAD])
def test_bad_programs_are_rejected_with_line_text_and_expectation(tmp_path: Path, name: str, text: str, line: int,
                                                                  tail: str | None) -> None:
    result = run_driver(text, tmp_path)
    assert result.returncode == 1, result
    message = result.stderr.strip().removeprefix("interp_run: ")
    assert message.startswith(f"{tmp_path / 'part.nc'} line {line}: "), message
    if tail is not None:
        assert message == f"{tmp_path / 'part.nc'} line {line}: {tail}"
    with pytest.raises(ip.ProgramError) as raised:  # the Python reference agrees on the line
        ip.parse_program(text, ip.default_parameters(), "part.nc")
    assert raised.value.line == line, (raised.value, message)


@pytest.mark.parametrize("version", [3, 2])
def test_the_fmu_reports_a_bad_program_at_initialization(tmp_path: Path, version: int) -> None:
    program = tmp_path / "bad.nc"
    program.write_text("G21 G90\nG0 X1\nG1 X2 Y\n")
    with Slave(require_fmu(fmu_dir() / fmu_file_name("Interpolator", version))) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.fmu.setString([slave.vr["program"]], [str(program)])
        assert status_of(lambda: slave.exit_initialization()) == ERROR
        assert slave.last_error() == (f"exitInitializationMode: part program {program} line 3: \"G1 X2 Y\": "
                                      "a number after 'Y'")
        assert slave.messages[-1].category == "logStatusError"
        assert slave.step(1e-3) == ERROR  # in the error state
        slave.fmu.reset()  # a reset and a good program work again
        slave.enter_initialization()
        program.write_text("G1 X1 F600\n")
        slave.fmu.setString([slave.vr["program"]], [str(program)])
        slave.exit_initialization()
        assert slave.step(1e-3) == 0


GOOD = [
    ("comments, tape marks, N words, lower case, zero-padded codes",
     "%\n(header)\nN10 g21 g90 ; mm\nn20 g01 x1.5 y-.5 F600 (move)\nN30 G00 Z+2\n%\n", 2),
    ("an empty program", "", 0),
    ("only comments", "(a)\n; b\n\n", 0),
    ("inch and incremental", "G20 G91 G1 X1 F10\nG90 G21 G1 X0\n", 2),
    ("modal motion and a full circle", "G1 X10 F600\nX20\nG2 I-5 J0\n", 3),
    ("modal G2 with only a centre", "G1 X10 F600\nG3 X0 Y10 I-10\nG2 I0 J-10\n", 3),
    ("a degree-1 NURBS (a polyline with corners)", "G6.2 P2 K0 X0 Y0 F600\nK0 X1 Y0\nK1 X1 Y1\nK2\nK2\n", 2),
    ("G10 and offsets", "G10 L2 P6 X10\nG59 G0 X0\nG54 G0 X0\n", 2),
    ("M2 with blank lines and comments after it", "G1 X1 F100\nM2\n\n(end)\n", 1),
    ("spindle words", "S8000 M3\nG1 X1 F100\nM4\nG1 X0\nM5\n", 2),
]


@pytest.mark.parametrize("name, text, moves", GOOD, ids=[g[0] for g in GOOD])
def test_documented_forms_parse_in_c_and_python(tmp_path: Path, name: str, text: str, moves: int) -> None:
    result = run_driver(text, tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"moves {moves} ")
    program = ip.parse_program(text, ip.default_parameters())
    assert len(program.moves) == moves


def test_a_degree_1_nurbs_stops_at_its_corners(tmp_path: Path) -> None:
    text = "G6.2 P2 K0 X0 Y0 F600\nK0 X10 Y0\nK1 X10 Y10\nK2\nK2\n"
    interp = ip.Interpolator(text, {})
    assert [(m.u0, m.u1) for m in interp.program.moves] == [(0.0, 1.0), (1.0, 2.0)]
    path = interp.path
    junction = next(k for k in range(len(path.node_s)) if path.node_left[k] == 0 and path.node_right[k] == 1)
    assert abs(path.node_s[junction] - 0.01) < 1e-15
    assert interp.path.node_vh[junction] < 1e-4  # a 90 degree corner: (nearly) a stop


def test_numbers_are_read_exactly_as_python_reads_them() -> None:
    for text in ("0.008286", "54.4930", "-.5", "+3", "0.7071067811865476", "123456.78901234567", "1e0"[:1]):
        program = ip.parse_program(f"G1 X{text} F600\n", ip.default_parameters())
        assert program.moves[0].end[0] == float(text) / 1000.0, text


def test_parsing_is_linear_in_the_program_size(tmp_path: Path) -> None:
    """A 200,000-line program parses (and is scheduled) in well under a few seconds."""
    rng = np.random.default_rng(1)
    xy = np.cumsum(rng.uniform(-1, 1, (200_000, 2)), axis=0)
    text = "G21 G90 F3000\n" + "".join(f"G1 X{x:.3f} Y{y:.3f}\n" for x, y in xy)
    import time

    program = tmp_path / "long.nc"
    program.write_text(text)
    start = time.perf_counter()
    result = subprocess.run([str(DRIVER), "--param", "period=0.5", str(program)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert time.perf_counter() - start < 20.0

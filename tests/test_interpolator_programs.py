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
from milling_twin.models.interpolator import parser as gp

DRIVER = repo_root() / "build" / "tools" / "interp_run"

# (name, program, line, the message's tail after 'line <n>: ')
BAD = [
    ("unknown G code", "G21 G90\nG1 X10 F600\nG7 X1\n", 3,
     '"G7 X1": a supported G code (G0 G1 G2 G3 G4 G5 G5.1 G5.2 G5.3 G6.2 G9 G10 G15 G17 G18 G19 G20 G21 G28 G40 G41 '
     'G42 G43 G44 G49 G50 G50.1 G52 G53 G54-G59 G61 G61.1 G64 G69 G73 G80 G81 G82 G83 G90 G91 G94 G95 G98 G99), got '
     'G7'),
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
    ("unknown letter", "G1 X1 E2 F100\n", 1,
     '"G1 X1 E2 F100": a word G, M, N, O, T, X, Y, Z, I, J, K, R, F, S, P, L, H, D or Q, got \'E\''),
    ("a rotary axis", "G0 X1 A90.\n", 1,
     '"G0 X1 A90.": a word G, M, N, O, T, X, Y, Z, I, J, K, R, F, S, P, L, H, D or Q, got \'A\' (only the axes X, '
     'Y, Z are modelled)'),
    ("unsupported M code", "M50\n", 1,
     '"M50": a supported M code (M0 M1 M2 M3 M4 M5 M6 M7 M8 M9 M19 M30 M98 M99), got M50'),
    ("two motion codes", "G0 G1 X1 F100\n", 1,
     '"G0 G1 X1 F100": one G code of the motion group per line, got G0 and G1'),
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
     '"G1 X1 F100 #": a word (letter and number), a comment or the end of the line, got \'#\' (parameters and '
     'expressions are not supported)'),
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


# ---- real post-processor output: program structure, machine functions, tools, canned cycles, subprograms ----

FANUC_POST = """%
O1001 (BRACKET)
(T1 D=10. CR=0. - FLAT END MILL)
N10 G90 G94 G17 G49 G40 G80
N15 G21
N20 G28 G91 Z0.
N25 G90
/N27 M0
N30 T1 M6
N35 S5000 M3
N40 G54
N45 M8
N50 G0 X-5. Y-5.
N55 G43 Z15. H1
N65 G1 Z-1. F1000.
N70 X20. F1500.
N95 G0 Z15.
N100 G98 G81 X10. Y10. Z-5. R2. F200.
N105 X20.
N110 G99 G83 X30. Z-8. R2. Q3.
N115 G73 X40. Z-4. R2. Q1. K2
N120 G80
N125 M98 P21000
N130 M9
N135 G28 G91 Z0.
N140 G90 G53 G0 X0. Y0.
N145 M30
O1000 (SUB)
G91 G1 X1. F500.
G90
M99
%
"""

GOOD_POST = [
    ("a Fanuc post: O number, safety line, G28, T M6, G43 H, M8, canned cycles, M98 P21000, G53, subprogram",
     FANUC_POST, 55),
    ("':' program number, G52 local offset and its cancel, M0/M1 accepted", ":1001\nG21 G90 G17\nG52 X10 Y10\n"
     "G0 X0 Y0\nG52 X0 Y0\nG0 X0 Y0\nM0\nM1\nM30\n", 2),
    ("G61/G64 P/G9, coolant M7/M8/M9, M19", "G21 G90 G61\nG1 X1 F100\nG64 P0.01\nG1 X2\nG9 G1 X3\nM7\nM8\nM9\nM19\n"
     "M2\n", 3),
    ("block skip lines are skipped", "G1 X1 F100\n/G1 X50\n  /1 G1 Y50\nG1 X2\n", 2),
    ("cancel codes of features not modelled", "G15 G50 G69 G50.1\nG1 X1 F100\n", 1),
    ("the Mastercam safety line G0 G17 G40 G49 G80 G90", "G21\nG0 G17 G40 G49 G80 G90\nG0 X1\n", 1),
    ("a subprogram before the main program", "%\nO2000 (SUB)\nG91 G1 X1. F300\nG90\nM99\nO1000 (MAIN)\n"
     "M98 P2000 L3\nM30\n%\n", 3),
    ("G95 feed per revolution with the spindle turning", "S1000 M3\nG95 F0.1\nG1 X5\nG94 F300\nG1 X6\n", 2),
]

BAD_POST = [
    ("G5.2 in the fanuc dialect", "G1 X0 F100\nG5.2 X1 Y1\nX2 Y0\nG5.3\n", 2,
     '"G5.2 X1 Y1": G5.2 is LinuxCNC\'s NURBS: set dialect = linuxcnc (Fanuc\'s NURBS is G6.2)'),
    ("M6 without a tool", "M6\n", 1, '"M6": a tool T before M6 (no tool selected)'),
    ("G41 without a tool table", "T1 M6\nG41 D1 G1 X1 F100\n", 2,
     '"G41 D1 G1 X1 F100": a tool of the tool table for D1 (the tool table is empty: the cutter radius is unknown)'),
    ("G41 outside G17", "G18\nG42 D1\n", 2, '"G42 D1": G17 (the XY plane) for cutter radius compensation G42, got G18'),
    ("a canned cycle outside G17", "G18 F100\nG81 X1 Y1 Z-2 R1\n", 2,
     '"G81 X1 Y1 Z-2 R1": G17 (the XY plane) for the canned cycle G81, got G18'),
    ("a canned cycle without R", "F100\nG81 X1 Z-2\n", 2, '"G81 X1 Z-2": R (the retract plane) with G81'),
    ("a peck cycle without Q", "F100\nG83 X1 Z-2 R1\n", 2, '"G83 X1 Z-2 R1": Q (the peck depth) with G83'),
    ("a hole bottom above R", "F100\nG81 X1 Z2 R1\n", 2,
     '"G81 X1 Z2 R1": the hole bottom Z below the retract plane R in G81'),
    ("M98 of a program not in the file", "M98 P2000\nM30\n", 1,
     '"M98 P2000": a program O2000 in this file for M98 (subprograms are read from the same file)'),
    ("a recursive subprogram", "O1\nM98 P2\nM30\nO2\nM98 P2\nM99\n", 5,
     '"M98 P2": no recursive call: O2 is already running'),
    ("a subprogram without M99", "O1\nM98 P2\nM30\nO2\nG1 X1 F100\nO3\nM99\n", 2,
     '"M98 P2": M99 at the end of the subprogram O2'),
    ("a program number twice", "O1\nM30\nO1\nM99\n", 3, '"O1": one program O1 in the file (also in line 1)'),
    ("G95 with the spindle stopped", "G95 F0.1\nG1 X1\n", 2,
     '"G1 X1": a turning spindle (S > 0 and M3/M4) for a feed move in G95 (feed per revolution)'),
    ("G53 in G91", "G91\nG53 G0 Z0\n", 2, '"G53 G0 Z0": G90 with G53 (machine coordinates are absolute)'),
    ("H without G43", "H1\n", 1, '"H1": H only with G43/G44 (a tool length offset)'),
    ("a program number with other words", "O1 G1 X1\n", 1,
     '"O1 G1 X1": a program number O alone in its line (a comment may follow)'),
    ("G28 without axes (fanuc)", "G28\n", 1, '"G28": the axes to return (X, Y, Z: the intermediate point) with G28'),
    ("P on a G1 line", "G1 X1 P2 F100\n", 1,
     '"G1 X1 P2 F100": P only with G4, G5, G10, G64, G82, M98 (or with G6.2 or G5.2)'),
    ("G4 without a time", "G4\n", 1, '"G4": P (the dwell time) with G4 (or X, seconds)'),
    ("a tool number not whole", "T1.5\n", 1, '"T1.5": a whole tool number after T, got T1.5'),
    ("G5 in the fanuc dialect", "G1 X1 F100\nG5 X3 Y0 I1 J1 P1 Q1\n", 2,
     '"G5 X3 Y0 I1 J1 P1 Q1": G5 is LinuxCNC\'s cubic spline: set dialect = linuxcnc'),
    ("G80 with a canned cycle", "F100\nG80 G81 X1 Z-1 R1\n", 2,
     '"G80 G81 X1 Z-1 R1": either G80 or a canned cycle, got G80 and G81'),
    ("nested calls too deep", "".join(f"O{k}\nM98 P{k + 1}\nM99\n" for k in range(1, 11)).replace("M99", "M30", 1),
     26, '"M98 P10": subprogram calls nested at most 8 deep'),
    ("subprogram repeats beyond the limit", "O1\nM98 P2 L9999\nM30\nO2\nM98 P3 L9999\nM99\nO3\nG4 P0\nM99\n",
     5, '"M98 P3 L9999": at most 1000000 lines executed in subprogram calls'),
]



@pytest.mark.parametrize("name, text, line, tail", BAD_POST, ids=[b[0] for b in BAD_POST])
def test_bad_post_programs_are_rejected_with_line_text_and_expectation(tmp_path: Path, name: str, text: str,
                                                                       line: int, tail: str | None) -> None:
    test_bad_programs_are_rejected_with_line_text_and_expectation(tmp_path, name, text, line, tail)


@pytest.mark.parametrize("name, text, moves", GOOD_POST, ids=[g[0] for g in GOOD_POST])
def test_post_forms_parse_in_c_and_python(tmp_path: Path, name: str, text: str, moves: int) -> None:
    test_documented_forms_parse_in_c_and_python(tmp_path, name, text, moves)

def test_the_parser_limits_in_c_equal_the_reference() -> None:
    """The structure limits the C header defines (until generated into model_constants.h) are parser.py's."""
    header = (repo_root() / "fmus" / "interpolator" / "gcode_parser.h").read_text()
    from milling_twin.models.interpolator import parser
    for name in ("MAX_MOVES", "MAX_CALLED_LINES", "MAX_CALL_DEPTH", "MAX_REPEATS", "MAX_PROGRAM_NUMBER", "MAX_NOTES",
                 "NOTE_LENGTH", "PECK_CLEARANCE"):
        value = next(line.split()[2] for line in header.splitlines() if line.startswith(f"#define {name} "))
        assert float(value) == getattr(parser, name), name


# A driver of gcode_parser.c alone (dialect, tool table and home position are not FMU variables yet): prints
# every move, curve and note with 17 significant digits, or the error, as dump() below does for parser.py.
C_DRIVER = r'''
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "gcode_parser.h"
int main(int argc, char **argv) {
    static char text[1 << 22];
    FILE *f = fopen(argv[1], "rb");
    size_t n = fread(text, 1, sizeof text, f), k;
    GcSettings s;
    GcProgram g;
    GcTool tools[16];
    char error[1024];
    int i, j;
    fclose(f);
    memset(&s, 0, sizeof s);
    memset(tools, 0, sizeof tools);
    s.dialect = atoi(argv[2]);
    sscanf(argv[3], "%lf:%lf:%lf", &s.home[0], &s.home[1], &s.home[2]);
    for (i = 4; i < argc && s.n_tools < 16; i++) {
        GcTool *t = &tools[s.n_tools++];
        sscanf(argv[i], "%d:%lf:%lf", &t->number, &t->diameter, &t->length);
    }
    s.tools = tools;
    if (gc_parse(text, n, "part.nc", &s, &g, error, sizeof error) != 0) {
        printf("error %s\n", error);
        return 0;
    }
    for (k = 0; k < g.n_moves; k++) {
        const GcMove *m = &g.moves[k];
        printf("move %d %d %d", m->kind, m->line, m->block);
        for (j = 0; j < 3; j++) printf(" %.17g %.17g %.17g", m->start[j], m->end[j], m->offset[j]);
        printf(" %.17g %d %d %d %.17g %.17g %d %.17g %d %.17g %.17g\n", m->feed, m->tool, m->coolant, m->exact_stop,
               m->dwell, m->tolerance, m->comp, m->comp_radius, m->curve, m->u0, m->u1);
    }
    for (k = 0; k < g.n_curves; k++) {
        printf("curve %d %d", g.curves[k].degree, g.curves[k].n_points);
        for (j = 0; j < g.curves[k].n_points + g.curves[k].degree + 1; j++) printf(" %.17g", g.curves[k].knots[j]);
        for (j = 0; j < 3 * g.curves[k].n_points; j++) printf(" %.17g", g.curves[k].points[j]);
        for (j = 0; j < g.curves[k].n_points; j++) printf(" %.17g", g.curves[k].weights[j]);
        printf("\n");
    }
    for (i = 0; i < g.n_notes; i++) printf("note %s\n", g.notes[i]);
    printf("final %d %d\n", g.final_line, g.final_block);
    gc_free(&g);
    return 0;
}
'''


@pytest.fixture(scope="module")
def parser_driver(tmp_path_factory) -> Path:
    import shutil
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    generated = repo_root() / "build" / "generated" / "Interpolator"
    if cc is None or not (generated / "model_constants.h").is_file():
        pytest.skip("no C compiler or no generated model_constants.h (build first)")
    folder = tmp_path_factory.mktemp("parser_driver")
    (folder / "driver.c").write_text(C_DRIVER)
    binary = folder / "driver"
    source = repo_root() / "fmus" / "interpolator" / "gcode_parser.c"
    subprocess.run([cc, "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", f"-I{source.parent}", f"-I{generated}",
                    str(folder / "driver.c"), str(source), str(source.parent / "sinumerik.c"),
                    str(source.parent / "gcode_number.c"), str(source.parent / "cutter_comp.c"), "-lm", "-o",
                    str(binary)], check=True)
    return binary


TOOLS = (gp.Tool(1, 0.010, length=0.1), gp.Tool(2, 0.006, length=0.05), gp.Tool(7, 0.002, length=0.0625))
HOME = (0.1, 0.2, 0.3)


def dump(text: str, dialect: int, tools, home=HOME) -> str:
    """parser.py's result in the C driver's format."""
    p = dict(ip.default_parameters())
    p.update(home_x=home[0], home_y=home[1], home_z=home[2], start_x=0.0, start_y=0.0, start_z=0.0)
    p.update({f"{name}_{a}": 0.0 for name in ("g54", "g55", "g56", "g57", "g58", "g59") for a in "xyz"})
    try:
        g = ip.parse_program(text, p, "part.nc", dialect=dialect, tools=tools)
    except ip.ProgramError as error:
        return f"error {error}\n"

    def f(x: float) -> str:
        return f"{x:.17g}"
    out = []
    for m in g.moves:
        axes = [f(v) for j in range(3) for v in (m.start[j], m.end[j], m.offset[j])]
        out.append(" ".join(["move", str(m.kind), str(m.line), str(m.block)] + axes + [
            f(m.feed), str(m.tool), str(m.coolant), str(int(m.exact_stop)), f(m.dwell), f(m.tolerance), str(m.comp),
            f(m.comp_radius), str(m.curve), f(m.u0), f(m.u1)]))
    for c in g.curves:
        out.append(" ".join([f"curve {c.degree} {len(c.points)}"] + [f(k) for k in c.knots]
                            + [f(v) for point in c.points for v in point] + [f(w) for w in c.weights]))
    out += [f"note {n}" for n in g.notes]
    out.append(f"final {g.final_line} {g.final_block}")
    return "\n".join(out) + "\n"


def run_parser_driver(binary: Path, tmp_path: Path, text: str, dialect: int, tools, home=HOME) -> str:
    program = tmp_path / "part.nc"
    program.write_bytes(text.encode("latin-1"))
    args = [f"{t.number}:{t.diameter!r}:{t.length!r}" for t in tools]
    result = subprocess.run([str(binary), str(program), str(dialect), ":".join(repr(h) for h in home)] + args,
                            capture_output=True, text=True, check=True)
    return result.stdout.replace(str(program), "part.nc")


SINUMERIK_POST = """%_N_PART1_MPF
;$PATH=/_N_MPF_DIR
; Siemens 840D style, written by hand in the style of a post
N10 G17 G90 G54 G71
N20 T1 M6
N30 D1
N40 S8000 M3
N50 G0 X0 Y0 Z5
N60 CYCLE832(0.01, _ORI_FINISH, 1)
N70 G1 Z-1 F1200
N80 BSPLINE SD=3
N90 X10 Y5 PW=1
N100 X20 Y-5
N110 X30 Y0
N120 X40 Y5
N130 G1 X50
N140 TRANS X10
N150 L100 P2
N160 M30
%_N_L100_SPF
N10 G91 G1 X1
N20 G90
N30 M17
"""

# (name, program, dialect, with the tool table): the C parser and parser.py give the same moves, curves, notes
# and messages, byte for byte
SAME = [
    ("a Fanuc post with a tool table", FANUC_POST, gp.DIALECT_FANUC, True),
    ("a Fanuc post without a tool table", FANUC_POST, gp.DIALECT_FANUC, False),
    ("dwells: Fanuc P in ms without a point, seconds with one, X seconds; G82",
     "G21 F100\nG4 P500\nG4 P0.5\nG4 X0.25\nG82 X1 Y1 Z-2 R1 P250\nG80\nM30\n", gp.DIALECT_FANUC, False),
    ("dwells: LinuxCNC P in seconds; G98 clear level, L repeats in G91",
     "G21 G17 F100\nG0 Z5\nG4 P0.5\nG91 G81 X10 Y0 Z-3 R-4 L3\nG90 G80\nG99 G83 X1 Y1 Z-6 R1 Q2\nG80\nM2\n",
     gp.DIALECT_LINUXCNC, False),
    ("cutter compensation fields from the tool table",
     "T2 M6\nG0 X0 Y0\nG41 D2 G1 X5 F300\nY5\nG40 X0\nG42 G1 X3\nG40\nM30\n", gp.DIALECT_FANUC, True),
    ("G43 length from the table, G44, G49, G28 through the intermediate point to home",
     "T1 M6\nG43 H1 G0 Z10\nG1 Z1 F100\nG44 H2 G0 Z10\nG49 G0 Z10\nG28 G91 Z0\nG90 G28 X5 Y5\nM30\n",
     gp.DIALECT_FANUC, True),
    ("LinuxCNC G28 without axes, G53", "G0 X1 Y2 Z3\nG28\nG53 G0 X0.01\nM2\n", gp.DIALECT_LINUXCNC, False),
    ("LinuxCNC G5.2 NURBS: first control point the current position, weights, order, knot intervals",
     "G21 G90 F600\nG0 X0 Y0\nG5.2 P2 L3\nX10 Y0 P1\nX10 Y10 P3\nX0 Y10\nG5.3\nG5.2 X5 Y5 Z-1 L4\nX10 Y0 K2\n"
     "X20 Y5\nX25 Y0 K0.5\nG5.3\nM2\n", gp.DIALECT_LINUXCNC, False),
    ("G5.2 without G5.3", "G21 F600\nG5.2 X1 Y1\nX2 Y0\n", gp.DIALECT_LINUXCNC, False),
    ("LinuxCNC G5 cubic splines (the second one reflecting the first's P Q) and G5.1 quadratic",
     "G21 G17 F600\nG5 X10 Y0 I3 J4 P-3 Q4\nG5 X20 Y0 P-3 Q-4\nG1 X21\nG5.1 X25 Y5 I4 J0\nG5.1 I1 J1 X27 Y5\nM2\n",
     gp.DIALECT_LINUXCNC, False),
    ("G5 without I J after another move", "G21 F600\nG1 X1\nG5 X3 Y0 P1 Q1\n", gp.DIALECT_LINUXCNC, False),
    ("G6.2 in the linuxcnc dialect", "G6.2 P3 K0 X0 Y0 F600\n", gp.DIALECT_LINUXCNC, False),
    ("an unknown tool with a tool table", "T5 M6\n", gp.DIALECT_FANUC, True),
    ("an unknown H with a tool table", "G43 H9 Z1\n", gp.DIALECT_FANUC, True),
    ("LinuxCNC O-words", "o100 sub\n", gp.DIALECT_LINUXCNC, False),
    ("M99 in the main program, notes once per word", "M0\nM0\nG1 X1 F100\nM1\nM99\n", gp.DIALECT_FANUC, False),
    ("a Sinumerik program through the translator: D1, CYCLE832, BSPLINE (G5.2 ... G5.3 N.. G1), TRANS, L100 P2",
     SINUMERIK_POST, gp.DIALECT_SINUMERIK, True),
    ("a Sinumerik refusal quotes the file's line", "N10 G17 G90\nN20 CYCLE81(10, 0, 2, -5)\n", gp.DIALECT_SINUMERIK,
     False),
    ("a Sinumerik B spline open at the end", "G1 X0 F100\nBSPLINE\nX1 Y1\nX2 Y0\nX3 Y1\n", gp.DIALECT_SINUMERIK,
     False),
]


@pytest.mark.parametrize("name, text, dialect, with_tools", SAME, ids=[s[0] for s in SAME])
def test_c_and_python_parse_post_programs_identically(parser_driver: Path, tmp_path: Path, name: str, text: str,
                                                      dialect: int, with_tools: bool) -> None:
    tools = TOOLS if with_tools else ()
    assert run_parser_driver(parser_driver, tmp_path, text, dialect, tools) == dump(text, dialect, tools)


def random_program(rng: np.random.Generator) -> str:
    """A program of post-style lines and random words (most are refused somewhere: the messages must agree too)."""
    forms = ["G0 X1 Y2", "G1 X3", "Y-2 Z-1", "G81 X1 Y1 Z-3 R1", "G83 X2 Z-4 R2 Q1.5", "G73 X3 Z-2 R1 Q0.7 K2",
             "G82 X1 Z-1 R1 P500", "G80", "X4 Y4", "G4 P250", "G4 X0.2", "G43 Z5 H1", "G49", "G41 D1 X2", "G40 X0",
             "M8", "M9", "M7", "G28 G91 Z0", "G90", "G53 G0 Z0", "G52 X1 Y1", "G52 X0 Y0", "G64 P0.01", "G61",
             "G9 G1 X2", "M98 P1001", "M98 P1001 L2", "G95 F0.1", "G94 F300", "G5.2 X1 Y1 L3", "X2 Y0 P2", "X3 Y1",
             "G5.3", "G5 X3 Y3 I1 J0 P0 Q1", "G5 X4 Y2 P1 Q1", "G5.1 X6 Y2 I1 J1", "G98", "G99", "G2 X5 Y0 R3",
             "G6.2 P3 K0 X0 Y0 F600", "K0 X1 Y1", "K0 X2 Y0", "K1",
             "G91 G1 X1", "M0", "O1001", "M99", "M30", "%", "/G1 X9", "(c)", ""]
    words = ["G0", "G1", "G2", "G4", "G17", "G18", "G20", "G28", "G41", "G43", "G53", "G81", "G83", "G91", "G95",
             "G5.2", "M6", "M98", "T1", "T7", "H1", "D2", "F100", "P1000", "P0.5", "L2", "K2", "Q1", "R1", "X1",
             "Y-4", "Z-5", "I1", "N10"]
    lines = ["O1000"] if rng.random() < 0.4 else []
    lines.append("G21 G90 G17 F100 S1000 M3")
    if rng.random() < 0.5:
        lines.append("T1 M6")
    for _ in range(int(rng.integers(1, 15))):
        if rng.random() < 0.93:
            lines.append(forms[int(rng.integers(len(forms)))])
        else:
            lines.append(" ".join(words[int(rng.integers(len(words)))] for _ in range(int(rng.integers(1, 5)))))
    return "\n".join(lines) + "\n"


def test_c_and_python_agree_on_random_post_programs(parser_driver: Path, tmp_path: Path) -> None:
    rng = np.random.default_rng(16)
    accepted = 0
    for case in range(300):
        text = random_program(rng)
        dialect = (gp.DIALECT_FANUC, gp.DIALECT_LINUXCNC)[case % 2]
        tools = TOOLS if case % 3 else ()
        expected = dump(text, dialect, tools)
        assert run_parser_driver(parser_driver, tmp_path, text, dialect, tools) == expected, text
        accepted += not expected.startswith("error")
    assert accepted >= 30  # the comparison covers accepted programs, not only refusals


def parse(text: str, dialect: int = gp.DIALECT_FANUC, tools=(), **parameters: float) -> ip.Program:
    p = dict(ip.default_parameters())
    p.update(parameters)
    return ip.parse_program(text, p, "part.nc", dialect=dialect, tools=tools)


def ends_mm(program: ip.Program) -> list[tuple[float, ...]]:
    return [tuple(round(v * 1000.0, 9) for v in m.end) for m in program.moves]


def test_a_drilling_cycle_expands_as_a_fanuc_control_runs_it() -> None:
    program = parse("G21 F120\nG0 Z10\nG98 G81 X5 Y6 Z-3 R2\nG99 X8\nG80\n")
    assert ends_mm(program) == [(0, 0, 10), (5, 6, 10), (5, 6, 2), (5, 6, -3), (5, 6, 10),  # G98: initial level
                                (8, 6, 10), (8, 6, 2), (8, 6, -3), (8, 6, 2)]            # G99: R
    kinds = [m.kind for m in program.moves[1:5]]
    assert kinds == [gp.MOVE_RAPID, gp.MOVE_RAPID, gp.MOVE_LINE, gp.MOVE_RAPID]
    assert all(m.exact_stop for m in program.moves[1:])
    assert program.moves[3].feed == pytest.approx(0.002)


def test_peck_cycles_retract_and_return_short_of_the_last_depth() -> None:
    g83 = ends_mm(parse("G21 F120\nG0 Z5\nG83 X0 Y0 Z-5 R1 Q2.5\n"))[1:]
    assert g83 == [(0, 0, 1), (0, 0, -1.5), (0, 0, 1), (0, 0, -1.246), (0, 0, -4), (0, 0, 1), (0, 0, -3.746),
                   (0, 0, -5), (0, 0, 5)]
    g73 = ends_mm(parse("G21 F120\nG0 Z5\nG73 X0 Y0 Z-3 R1 Q2\n"))[1:]
    assert g73 == [(0, 0, 1), (0, 0, -1), (0, 0, -0.746), (0, 0, -3), (0, 0, 5)]


def test_g91_cycles_take_r_from_the_initial_level_and_z_from_r() -> None:
    program = parse("G21 F120\nG0 Z10\nG91 G81 X2 Z-5 R-8 K3\n")
    assert ends_mm(program)[-4:] == [(6, 0, 10), (6, 0, 2), (6, 0, -3), (6, 0, 10)]
    assert len(program.moves) == 1 + 3 * 4


def test_dwell_units_per_dialect() -> None:
    fanuc = parse("G4 P500\nG4 P0.5\nG4 X0.25\n")
    assert [m.dwell for m in fanuc.moves] == [0.5, 0.5, 0.25]
    assert all(m.kind == gp.MOVE_DWELL and m.start == m.end for m in fanuc.moves)
    assert [m.dwell for m in parse("G4 P2\n", gp.DIALECT_LINUXCNC).moves] == [2.0]


def test_tool_change_length_offset_and_home_return() -> None:
    program = parse("T7 M6\nG43 H7 G0 Z10\nM8\nG28 G91 Z0\n", tools=TOOLS, home_x=0.1, home_y=0.2, home_z=0.3)
    first, home = program.moves
    assert first.end[2] == pytest.approx(0.010 + 0.0625) and first.offset[2] == 0.0625
    assert (first.tool, first.coolant) == (7, gp.COOLANT_OFF)
    assert home.end == (0.0, 0.0, 0.3) and home.coolant == gp.COOLANT_FLOOD and home.kind == gp.MOVE_RAPID


def test_subprogram_calls_repeat_and_return() -> None:
    text = "O1\nG21 F100\nM98 P30002\nG1 Y1\nM30\nO2\nG91 G1 X1\nG90\nM99\n"
    program = parse(text)
    assert ends_mm(program) == [(1, 0, 0), (2, 0, 0), (3, 0, 0), (3, 1, 0)]
    assert [m.line for m in program.moves] == [7, 7, 7, 4]


def test_linuxcnc_nurbs_knots_are_linuxcncs() -> None:
    program = parse("G21 F600\nG5.2 X10 Y0\nX10 Y10\nX0 Y10\nG5.3\n", gp.DIALECT_LINUXCNC)
    (curve,) = program.curves
    assert curve.degree == 2 and curve.knots == [0, 0, 0, 1, 2, 2, 2]
    assert curve.points[0] == (0.0, 0.0, 0.0) and len(program.moves) == 1


def test_linuxcnc_splines_are_exact_bezier_curves() -> None:
    program = parse("G21 F600\nG5 X10 Y0 I3 J4 P-3 Q4\nG5 X20 Y0 P-3 Q-4\nG5.1 X25 Y5 I4 J0\n", gp.DIALECT_LINUXCNC)
    first, second, third = program.curves
    mm = [[round(v * 1000.0, 9) for v in point[:2]] for point in first.points]
    assert mm == [[0, 0], [3, 4], [7, 4], [10, 0]] and first.knots == [0, 0, 0, 0, 1, 1, 1, 1]
    assert [round(v * 1000.0, 9) for v in second.points[1][:2]] == [13, -4]   # the reflection of P-3 Q4
    assert third.degree == 2 and [round(v * 1000.0, 9) for v in third.points[1][:2]] == [24, 0]


def test_accepted_words_that_are_not_modelled_are_noted_once() -> None:
    program = parse("M0\nM0\nT1 M6\nT2 M6\nG43 H1 G0 Z1\nM19\n")
    assert [n.split(": ", 2)[2].split(":")[0] for n in program.notes] == [
        "M0", "T1", "M6", "G43 H1", "M19"]
    assert program.notes[0] == 'part.nc line 1: "M0": M0: program stop not modelled (the program runs on)'


# The corpus of post-style programs (tests/fuzz/corpus/gcode/post_*, also fuzzing seeds; provenance in each
# program's header): each runs through the whole engine (interp_run) in its dialect with a tool table, and the C
# parser and the reference read it identically.
CORPUS = sorted((repo_root() / "tests" / "fuzz" / "corpus" / "gcode").glob("post_*"))
CORPUS_DIALECT = {".nc": ("fanuc", gp.DIALECT_FANUC), ".ngc": ("linuxcnc", gp.DIALECT_LINUXCNC),
                  ".mpf": ("sinumerik", gp.DIALECT_SINUMERIK)}
TOOL_TABLE = """T1 P1 D10.000 Z+50.000 ; 10 mm end mill flutes=3
T2 P2 D6.000 Z+70.000 ; 6 mm drill
T7 P7 D5.000 Z+60.000 ; spot drill
"""


def test_the_corpus_covers_three_dialects() -> None:
    assert {path.suffix for path in CORPUS} == set(CORPUS_DIALECT), CORPUS


@pytest.mark.parametrize("path", CORPUS, ids=[p.name for p in CORPUS])
def test_corpus_programs_run_in_their_dialect(parser_driver: Path, tmp_path: Path, path: Path) -> None:
    from milling_twin.models.interpolator.tool_table import parse_tool_table
    name, dialect = CORPUS_DIALECT[path.suffix]
    table = tmp_path / "tool.tbl"
    table.write_text(TOOL_TABLE)
    result = subprocess.run([str(DRIVER), "--dialect", name, "--tool-table", str(table), "--param", "start_z=0.2",
                             str(path)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    text = path.read_text(encoding="latin-1")
    tools = parse_tool_table(TOOL_TABLE)
    expected = dump(text, dialect, tools)
    assert not expected.startswith("error"), expected
    assert run_parser_driver(parser_driver, tmp_path, text, dialect, tools) == expected

"""Cutter radius compensation (G40/G41/G42, models/interpolator/cutter_comp.py and fmus/interpolator/cutter_comp.c):
the tool-centre path of known contours (a square outline and pocket, circles, helices, inside corners), the
refusals (gouging, NURBS, other planes, entry and exit rules), an independent geometric check of every compensated
path (the tool keeps exactly its radius from the programmed contour and never comes closer) and the C stage equal
to the Python reference bit for bit (build/tools/cutter_comp_driver), on these programs and on seeded random
contours.

The programs' moves are made by a small reader here (``marked``), marked as the parser marks them, so the stage
is tested on its own (the parser calls it at the end of parsing)."""
from __future__ import annotations

import math
import os
import random
import re
import subprocess
from dataclasses import replace
from pathlib import Path

import pytest

from milling_twin.models.interpolator import cutter_comp
from milling_twin.models.interpolator.cutter_comp import compensate
from milling_twin.models.interpolator.parser import (COMP_LEFT, COMP_OFF, COMP_RIGHT, MOVE_ARC, MOVE_DWELL,
                                                     MOVE_LINE, MOVE_NURBS, MOVE_RAPID, Move, Program, ProgramError,
                                                     nurbs_block_gcode)

REPO = Path(__file__).resolve().parents[1]
DRIVER = Path(os.environ.get("MILLING_TWIN_CUTTER_COMP_DRIVER", REPO / "build" / "tools" / "cutter_comp_driver"))
HEADER = REPO / "fmus" / "interpolator" / "cutter_comp.h"
FILE = "part.nc"
R = 0.005                       # m: a 10 mm end mill

_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


def marked(text: str, radius: float = R) -> Program:
    """The moves of a test program as the parser makes them (machine coordinates in m, arcs with centre, start
    angle, sweep and radii), each marked with the compensation of its line: ``comp`` from the line of G41/G42
    until the line of G40, ``comp_radius`` the tool radius. (A small reader of the programs here, G90 mm only:
    G0-G3 with X Y Z I J K R, G4 P, G6.2 blocks, G17-G19, G40-G42, F; the stage is tested apart from the
    parser's dialects and tool table.)"""
    moves: list[Move] = []
    pos = [0.0, 0.0, 0.0]
    feed, plane, motion, comp = 0.0, 17, 0, COMP_OFF
    lines = text.split("\n")
    k = 0
    while k < len(lines):
        number = k + 1
        words = [(w, float(v)) for w, v in _WORD.findall(re.sub(r"\(.*?\)", "", lines[k]).upper())]
        k += 1
        seen = {w: v for w, v in words if w != "G"}
        for w, v in words:
            if w == "G" and v in (0.0, 1.0, 2.0, 3.0):
                motion = int(v)
            elif w == "G" and v in (17.0, 18.0, 19.0):
                plane = int(v)
            elif w == "G" and v in (40.0, 41.0, 42.0):
                comp = {40.0: COMP_OFF, 41.0: COMP_LEFT, 42.0: COMP_RIGHT}[v]
        gs = [v for w, v in words if w == "G"]
        if "F" in seen:
            feed = seen["F"] / 60000.0
        state = dict(offset=(0.0, 0.0, 0.0), feed=feed, spindle=0.0, spindle_on=False, comp=comp,
                     comp_radius=radius if comp != COMP_OFF else 0.0)
        if 4.0 in gs:
            moves.append(Move(MOVE_DWELL, number, tuple(pos), tuple(pos), dwell=seen["P"], **state))
            continue
        if 6.2 in gs:
            first = [seen.get(a, 0.0) / 1000.0 for a in "XYZ"]
            last = first
            while k < len(lines) and lines[k].upper().startswith("K"):
                point = dict(_WORD.findall(lines[k].upper()))
                if "X" in point:
                    last = [float(point.get(a, 0.0)) / 1000.0 for a in "XYZ"]
                k += 1
            moves.append(Move(MOVE_NURBS, number, tuple(pos), tuple(last), curve=0, u0=0.0, u1=1.0, **state))
            pos = list(last)
            continue
        if not any(a in seen for a in "XYZ"):
            continue
        end = [seen[a] / 1000.0 if a in seen else pos[i] for i, a in enumerate("XYZ")]
        if motion in (0, 1):
            if end != pos:
                moves.append(Move(MOVE_RAPID if motion == 0 else MOVE_LINE, number, tuple(pos), tuple(end),
                                  **dict(state, feed=0.0 if motion == 0 else feed)))
        else:
            ia, ib, inormal = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}[plane]
            sa, sb, ea, eb = pos[ia], pos[ib], end[ia], end[ib]
            if "R" in seen:
                r, da, db = seen["R"] / 1000.0, ea - sa, eb - sb
                chord = math.sqrt(da * da + db * db)
                h = math.sqrt(max(r * r - chord * chord / 4.0, 0.0))
                sign = 1.0 if (motion == 3) == (r > 0) else -1.0
                ca, cb = sa + 0.5 * da - sign * h * db / chord, sb + 0.5 * db + sign * h * da / chord
            else:
                words_ab = {17: "IJ", 18: "KI", 19: "JK"}[plane]
                ca, cb = sa + seen.get(words_ab[0], 0.0) / 1000.0, sb + seen.get(words_ab[1], 0.0) / 1000.0
            theta0 = math.atan2(sb - cb, sa - ca)
            sweep = math.atan2(eb - cb, ea - ca) - theta0
            if motion == 2 and sweep >= 0.0:
                sweep -= 2.0 * math.pi
            if motion == 3 and sweep <= 0.0:
                sweep += 2.0 * math.pi
            centre = [0.0, 0.0, 0.0]
            centre[ia], centre[ib], centre[inormal] = ca, cb, pos[inormal]
            moves.append(Move(MOVE_ARC, number, tuple(pos), tuple(end), center=tuple(centre),
                              axes=(ia, ib, inormal), theta0=theta0, sweep=sweep, r0=math.hypot(sa - ca, sb - cb),
                              r1=math.hypot(ea - ca, eb - cb), height=end[inormal] - pos[inormal], **state))
        pos = end
    return Program(FILE, moves, [], len(lines), 0, 0.0, False, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def compensated(text: str, radius: float = R) -> list[Move]:
    program = marked(text, radius)
    compensate(program, text, FILE)
    return program.moves


def refusal(text: str, radius: float = R) -> ProgramError:
    with pytest.raises(ProgramError) as caught:
        compensated(text, radius)
    return caught.value


# the moves as the driver reads and writes them (GcMove's fields; doubles exact as hex)

_FIELDS = ("kind", "line", "block", "start", "end", "offset", "feed", "spindle", "spindle_on", "center", "axes",
           "theta0", "sweep", "r0", "r1", "height", "curve", "u0", "u1", "tool", "coolant", "exact_stop", "dwell",
           "tolerance", "comp", "comp_radius")
_INTS = {"kind", "line", "block", "spindle_on", "axes", "curve", "tool", "coolant", "exact_stop", "comp"}


def _words(move: Move) -> list[str]:
    out = []
    for name in _FIELDS:
        value = getattr(move, name)
        values = value if isinstance(value, tuple) else (value,)
        out += [str(int(v)) if name in _INTS else float(v).hex() for v in values]
    return out


def _read_words(words: list[str]) -> list[str]:
    """The driver's output numbers in the form _words writes them (ints as ints, doubles as float.hex)."""
    out, i = [], 0
    for name in _FIELDS:
        count = 3 if name in ("start", "end", "offset", "center", "axes") else 1
        for w in words[i:i + count]:
            out.append(str(int(w)) if name in _INTS else float.fromhex(w).hex())
        i += count
    return out


def c_compensate(program: Program, text: str, tmp_path: Path) -> list[list[str]] | str:
    """The C stage on the (uncompensated) program: its moves as word lists, or its error message."""
    moves_file, text_file = tmp_path / "moves.txt", tmp_path / "program.nc"
    lines = [" ".join(float(v).hex() for v in program.start)] + [" ".join(_words(m)) for m in program.moves]
    moves_file.write_text("\n".join(lines) + "\n")
    text_file.write_bytes(text.encode())
    run = subprocess.run([str(DRIVER), str(moves_file), str(text_file), FILE], capture_output=True, text=True,
                         check=True)
    head, _, rest = run.stdout.partition("\n")
    if head.startswith("error "):
        return head[len("error "):]
    assert head == f"ok {len(rest.splitlines())}", run.stdout[:200]
    return [_read_words(line.split()) for line in rest.splitlines()]


def python_result(text: str, radius: float) -> tuple[Program, list[list[str]] | str]:
    program = marked(text, radius)
    original = replace(program, moves=list(program.moves))
    try:
        compensate(program, text, FILE)
    except ProgramError as error:
        return original, str(error)
    return original, [_words(m) for m in program.moves]


needs_driver = pytest.mark.skipif(not DRIVER.exists(), reason="build/tools/cutter_comp_driver not built")


# an independent geometric check of a compensated path

def _point(move: Move, lam: float) -> tuple[float, float, float]:
    if move.kind == MOVE_ARC:
        theta = move.theta0 + lam * move.sweep
        r = move.r0 + lam * (move.r1 - move.r0)
        return (move.center[0] + r * math.cos(theta), move.center[1] + r * math.sin(theta),
                move.center[2] + lam * move.height)
    return tuple(move.start[i] + lam * (move.end[i] - move.start[i]) for i in range(3))


def _arc_step(move: Move, x: float, y: float) -> float:
    """The angle swept from an arc's start to (x, y), in [0, 2 pi)."""
    step = (math.atan2(y - move.center[1], x - move.center[0]) - move.theta0) * (1.0 if move.sweep > 0 else -1.0)
    return step % (2.0 * math.pi)


def _arc_gap(move: Move, x: float, y: float, step: float) -> float:
    """|distance from the centre - the arc's radius there| (r0 -> r1 over the sweep: the parser takes an end point
    within its tolerance of the circle)."""
    radius = move.r0 + step / abs(move.sweep) * (move.r1 - move.r0)
    return abs(math.hypot(x - move.center[0], y - move.center[1]) - radius)


def _distance_to(move: Move, x: float, y: float) -> float:
    """XY distance from (x, y) to a programmed line or XY arc."""
    if move.kind == MOVE_ARC:
        step = _arc_step(move, x, y)
        if step <= abs(move.sweep):
            return _arc_gap(move, x, y, step)
        return min(math.hypot(x - move.start[0], y - move.start[1]), math.hypot(x - move.end[0], y - move.end[1]))
    ax, ay, bx, by = move.start[0], move.start[1], move.end[0], move.end[1]
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0.0 else max(0.0, min(1.0, ((x - ax) * dx + (y - ay) * dy) / length2))
    return math.hypot(x - ax - t * dx, y - ay - t * dy)


def _offset_distance(move: Move, x: float, y: float) -> float:
    """XY distance from (x, y) to the whole line (or circle) a programmed line (or XY arc) lies on."""
    if move.kind == MOVE_ARC:
        step = _arc_step(move, x, y)
        if step > abs(move.sweep):      # beyond an end: the radius there
            step = 0.0 if 2.0 * math.pi - step < step - abs(move.sweep) else abs(move.sweep)
        return _arc_gap(move, x, y, step)
    dx, dy = move.end[0] - move.start[0], move.end[1] - move.start[1]
    return abs((x - move.start[0]) * dy - (y - move.start[1]) * dx) / math.hypot(dx, dy)


def check_path(original: list[Move], result: list[Move], radius: float, samples: int = 16,
               whole_contour: bool = True) -> int:
    """Checks a compensated path against its programmed contour: the moves join exactly; every point of a
    compensated move lies at the tool radius from the line or circle of its own programmed element (corner arcs:
    from their centre, the programmed corner) and no closer than the radius to any compensated element of the
    contour (whole_contour) or to its own and the neighbouring elements (what compensation block by block
    guarantees: whether the tool's entry clears the end of a closed contour, or a narrow neck, is the program's
    matter, as on the controls). Rapids are not checked (they do not cut). Returns the number of points checked."""
    contour = [m for m in original if m.comp != COMP_OFF and m.kind in (MOVE_LINE, MOVE_ARC, MOVE_RAPID)
               and (m.kind == MOVE_ARC or m.start[:2] != m.end[:2])]
    entry = contour[0] if contour else None
    contour = contour[1:]        # the entry move starts uncompensated
    index = {m.line: i for i, m in enumerate(contour)}
    for a, b in zip(result, result[1:]):
        assert a.end == b.start, (a, b)
    checked = 0
    for m in result:
        if m.comp == COMP_OFF or m.kind in (MOVE_DWELL, MOVE_RAPID) or m.start[:2] == m.end[:2] and m.kind != MOVE_ARC:
            continue
        if entry is not None and m.line == entry.line and m.kind != MOVE_ARC:
            continue
        i = index[m.line]
        own = contour[i]
        near = contour if whole_contour else contour[max(i - 1, 0):i + 2]
        # a corner arc: about the programmed corner, the start of the element it precedes
        corner_arc = m.kind == MOVE_ARC and m.r0 == radius and own.start[:2] == m.center[:2]
        for j in range(samples + 1):
            x, y, _ = _point(m, j / samples)
            if corner_arc:
                assert math.hypot(x - m.center[0], y - m.center[1]) == pytest.approx(radius, abs=1e-12)
            else:
                assert _offset_distance(own, x, y) == pytest.approx(radius, abs=1e-11), (m, j)
            nearest = min(_distance_to(o, x, y) for o in near)
            assert nearest >= radius - 1e-11, (m, j, nearest)
            checked += 1
    return checked


# known contours

SQUARE = """G21 G90 G17 F600
G0 X-20 Y-20
G1 Z-1
{comp} G1 X0 Y0 D1
Y50
X50
Y0
X0
G40 G1 X-20 Y-20
M30"""


def test_square_outline_with_g41_is_the_rectangle_with_rounded_corners():
    text = SQUARE.format(comp="G41")
    moves = compensated(text)
    r = R * 1000.0
    got = [(m.kind, m.line, tuple(round(v * 1000.0, 9) for v in m.start[:2]), tuple(round(v * 1000.0, 9)
            for v in m.end[:2])) for m in moves]
    # entry: to (0, 0) offset left of its direction (45 deg), then the inside corner with the side x = -r
    entry_y = r * math.sqrt(2.0) - r   # where the entry's offset line (y = x + r sqrt 2) meets x = -r
    expected = [(MOVE_RAPID, 2, (0.0, 0.0), (-20.0, -20.0)),
                (MOVE_LINE, 3, (-20.0, -20.0), (-20.0, -20.0)),
                (MOVE_LINE, 4, (-20.0, -20.0), (-r, round(entry_y, 9))),
                (MOVE_LINE, 5, (-r, round(entry_y, 9)), (-r, 50.0)),
                (MOVE_ARC, 6, (-r, 50.0), (0.0, 50.0 + r)),
                (MOVE_LINE, 6, (0.0, 50.0 + r), (50.0, 50.0 + r)),
                (MOVE_ARC, 7, (50.0, 50.0 + r), (50.0 + r, 50.0)),
                (MOVE_LINE, 7, (50.0 + r, 50.0), (50.0 + r, 0.0)),
                (MOVE_ARC, 8, (50.0 + r, 0.0), (50.0, -r)),
                (MOVE_LINE, 8, (50.0, -r), (0.0, -r)),
                (MOVE_LINE, 9, (0.0, -r), (-20.0, -20.0))]
    assert got == [(k, ln, tuple(v + 0.0 for v in s), tuple(v + 0.0 for v in e)) for k, ln, s, e in expected]
    for m, corner in zip((moves[4], moves[6], moves[8]), ((0.0, 0.05), (0.05, 0.05), (0.05, 0.0))):
        assert (m.center[0], m.center[1]) == pytest.approx(corner, abs=1e-15)
        assert m.r0 == m.r1 == R and m.sweep == pytest.approx(-math.pi / 2.0, abs=1e-15) and m.height == 0.0
        assert m.center[2] == m.start[2] == m.end[2] == -0.001
    assert all(m.end[2] == -0.001 for m in moves[2:])
    assert check_path(marked(text).moves, moves, R) > 100


def test_square_pocket_with_g42_is_the_inner_square_with_sharp_corners():
    text = """G21 G90 G17 F600
G0 X25 Y25
G1 Z-2
G42 G1 Y50 D1
X50
Y0
X0
Y50
X25
G40 G1 Y25
M30"""
    moves = compensated(text)
    r = R * 1000.0
    corners = [tuple(round(v * 1000.0, 9) for v in m.end[:2]) for m in moves[2:]]
    assert corners == [(25.0 + r, 50.0 - r), (50.0 - r, 50.0 - r), (50.0 - r, r), (r, r), (r, 50.0 - r),
                       (25.0, 50.0 - r), (25.0, 25.0)]
    assert [m.kind for m in moves] == [MOVE_RAPID, MOVE_LINE] + [MOVE_LINE] * 7   # no arcs: every corner inside
    assert check_path(marked(text).moves, moves, R) > 50


def test_a_cam_style_outside_contour_with_tangent_lead_in_and_lead_out():
    # as a CAM post writes a 2D contour with compensation in the control: a linear lead-in, a lead-in arc of
    # radius 6 tangent to the edge, the 40 x 40 outline with corner fillets of radius 3 (climb, clockwise), a
    # lead-out arc and line; every join tangent, so no corner arc; the tool (radius 5) on the left
    text = """G21 G90 G17 F1000
G0 X26 Y-16 Z5
G1 Z-5
G41 G1 X26 Y-6 D1
G3 X20 Y0 I-6 J0
G1 X3
G2 X0 Y3 I0 J3
G1 Y37
G2 X3 Y40 I3 J0
G1 X37
G2 X40 Y37 I0 J-3
G1 Y3
G2 X37 Y0 I-3 J0
G1 X20
G3 X14 Y-6 I0 J-6
G40 G1 X14 Y-16
G0 Z5
M30"""
    moves = compensated(text)
    assert [m.kind for m in moves] == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_ARC] + [MOVE_LINE, MOVE_ARC] * 4 + \
        [MOVE_LINE, MOVE_ARC, MOVE_LINE, MOVE_RAPID]
    radii = [round(m.r0 * 1000.0, 12) for m in moves if m.kind == MOVE_ARC]
    assert radii == [1.0, 8.0, 8.0, 8.0, 8.0, 1.0]           # lead arcs 6 - 5 (inside), fillets 3 + 5
    edges = [m for m in moves if m.kind == MOVE_LINE and m.line in (6, 8, 10, 12, 14)]
    assert [tuple(round(v * 1000.0, 9) + 0.0 for v in m.start[:2] + m.end[:2]) for m in edges] == [
        (20.0, -5.0, 3.0, -5.0), (-5.0, 3.0, -5.0, 37.0), (3.0, 45.0, 37.0, 45.0), (45.0, 37.0, 45.0, 3.0),
        (37.0, -5.0, 20.0, -5.0)]
    assert moves[2].end[:2] == pytest.approx((0.021, -0.006), abs=1e-15)
    assert moves[-2].start[:2] == pytest.approx((0.019, -0.006), abs=1e-15)
    # (the tool crosses the lead-out arc's path on the bottom edge: leads are moves in the air, not the part's
    # edge, so the clearance is checked against the neighbouring elements)
    assert check_path(marked(text).moves, moves, R, whole_contour=False) > 150


@pytest.mark.parametrize("comp,grown", [("G41", True), ("G42", False)])
def test_circle_g2_radius_grows_or_shrinks_by_the_tool_radius(comp, grown):
    text = f"""G21 G90 G17 F900
G0 X20 Y30 Z2
G1 Z-1
{comp} G1 Y0 D3
G2 X20 Y0 I-20 J0
G2 X0 Y20 Z-3 I-20 J0
G40 G1 X0 Y40
M30"""
    moves = compensated(text)
    r = 0.02 + R if grown else 0.02 - R
    circle, helix = moves[3], moves[4]
    assert [m.kind for m in moves] == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_ARC, MOVE_ARC, MOVE_LINE]
    for arc in (circle, helix):
        assert (arc.center[0], arc.center[1]) == (0.0, 0.0)
        assert arc.r0 == pytest.approx(r, abs=1e-15) and arc.r1 == pytest.approx(r, abs=1e-15)
    assert circle.sweep == pytest.approx(-2.0 * math.pi, abs=1e-14) and circle.height == 0.0
    assert helix.sweep == pytest.approx(-1.5 * math.pi, abs=1e-14)
    assert helix.height == pytest.approx(-0.002, abs=1e-18) and helix.end[2] == pytest.approx(-0.003, abs=1e-18)
    assert moves[2].end == circle.start and circle.end == helix.start       # tangent: no corner arcs
    assert circle.start[:2] == pytest.approx((r, 0.0), abs=1e-15)
    assert helix.end[:2] == pytest.approx((0.0, r), abs=1e-15)
    assert moves[5].start == helix.end and moves[5].end[:2] == pytest.approx((0.0, 0.04), abs=1e-18)
    assert check_path(marked(text).moves, moves, R) > 30


def test_inside_corners_meet_where_the_offset_elements_intersect():
    # a line into a concave arc, the arc into a line (G41: the tool left of the travel, the arcs turn left)
    text = """G21 G90 G17 F600
G0 X-30 Y0
G41 G1 X-20 Y0 D1
X0
G3 X20 Y20 I0 J20
G1 X20 Y40
G40 G1 X40 Y40
M30"""
    moves = compensated(text)
    kinds = [m.kind for m in moves]
    assert kinds == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_ARC, MOVE_LINE, MOVE_LINE]
    line, arc, up = moves[2], moves[3], moves[4]
    # tangent junctions here: the arc keeps its centre, radius 20 - 5, the joins exact
    assert arc.r0 == pytest.approx(0.015, abs=1e-15) and arc.center[:2] == (0.0, 0.02)
    assert line.end[:2] == pytest.approx((0.0, R), abs=1e-15) and up.start[:2] == pytest.approx((0.015, 0.02),
                                                                                               abs=1e-15)
    # a true inside corner between two lines at 60 degrees, and between a line and a concave arc
    text = """G21 G90 G17 F600
G0 X0 Y-20
G41 G1 X0 Y0 D1
X40
G1 X60 Y34.64101615137754
G40 G1 X80 Y40
M30"""
    moves = compensated(text)
    by_line = {m.line: m for m in moves}          # the last move of each line
    joint = by_line[4].end
    assert by_line[5].start == joint and by_line[5].kind == MOVE_LINE
    # the joint lies on both offset lines: y = r and the 60-degree line shifted left by r
    assert joint[1] == pytest.approx(R, abs=1e-15)
    n = (-math.sin(math.pi / 3.0), math.cos(math.pi / 3.0))
    assert (joint[0] - 0.04) * n[0] + joint[1] * n[1] == pytest.approx(R, abs=1e-15)
    assert joint[0] == pytest.approx(0.04 - R * math.tan(math.pi / 6.0), abs=1e-15)
    text = """G21 G90 G17 F600
G0 X0 Y-20
G41 G1 X0 Y0 D1
X40
G3 X40 Y40 I-10 J20
G40 G1 X0 Y40
M30"""
    moves = compensated(text)
    line, arc = [m for m in moves if m.line in (4, 5)][-2:]
    assert line.end == arc.start and (line.kind, arc.kind) == (MOVE_LINE, MOVE_ARC)
    # the arc turns left by atan(1/2) at its start: inside for G41; the offset line y = r meets the circle of
    # radius sqrt(500) - 5 about (30, 20) at x = 30 + sqrt((sqrt(500) - 5)^2 - 15^2)
    rc = math.sqrt(500.0) - 5.0
    assert arc.center[:2] == (0.03, 0.02) and arc.r0 == pytest.approx(rc / 1000.0, abs=1e-15)
    assert line.end[:2] == pytest.approx(((30.0 + math.sqrt(rc * rc - 225.0)) / 1000.0, R), abs=1e-15)
    assert check_path(marked(text).moves, moves, R) > 10


def test_plunges_and_dwells_keep_the_compensated_xy_position():
    text = """G21 G90 G17 F600
G0 X-20 Y0 Z5
G41 G1 X0 Y0 D1
G1 Z-1
G4 P0.5
X30
G1 Z5
G1 X30 Y30 Z-1
G0 Z5
G40 G0 X50 Y50
M30"""
    program = marked(text)
    kinds = [m.kind for m in program.moves]
    assert MOVE_DWELL in kinds
    moves = compensated(text)
    by_line = {}
    for m in moves:
        by_line.setdefault(m.line, []).append(m)
    plunge, dwell = by_line[4][0], by_line[5][0]
    assert plunge.start[:2] == plunge.end[:2] == dwell.start[:2] == dwell.end[:2] == moves[1].end[:2]
    assert plunge.end[2] == -0.001
    # the corner between X30 (going +x) and the ramp (going +y) is inside for G41: X30 ends at the intersection,
    # and the lift between the two stays there
    lift = by_line[7][0]
    assert lift.start[:2] == lift.end[:2] == by_line[6][0].end[:2] == pytest.approx((0.03 - R, R), abs=1e-15)
    ramp, = by_line[8]
    assert ramp.kind == MOVE_LINE and ramp.start == lift.end and ramp.end[:2] == pytest.approx((0.03 - R, 0.03),
                                                                                               abs=1e-15)
    assert ramp.end[2] == -0.001
    retract = by_line[9][0]
    assert retract.start[:2] == retract.end[:2] == ramp.end[:2]
    exit_move = by_line[10][0]
    assert exit_move.start == retract.end and exit_move.end == (0.05, 0.05, 0.005)


def test_corner_arcs_take_the_line_and_machine_state_of_the_move_they_precede():
    moves = compensated(SQUARE.format(comp="G41").replace("Y50\nX50", "Y50\nX50 F1200"))
    arc, side = moves[4], moves[5]
    assert arc.kind == MOVE_ARC and arc.line == side.line == 6
    assert arc.feed == side.feed == pytest.approx(0.02) and moves[3].feed == pytest.approx(0.01)
    assert arc.comp == COMP_LEFT and arc.comp_radius == R and not arc.exact_stop


def test_small_outside_turns_between_lines_meet_without_an_arc():
    # a nearly straight chain (turns of 0.1 deg) keeps its lines; a 10-degree turn gets its arc
    text = """G21 G90 G17 F600
G0 X-20 Y0
G41 G1 X0 Y0 D1
X20 Y-0.0349
X40 Y-0.0698
X60 Y-3.5967
G40 G1 X60 Y-20
M30"""
    moves = compensated(text)
    assert [m.kind for m in moves] == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_LINE, MOVE_ARC, MOVE_LINE,
                                       MOVE_LINE]
    assert check_path(marked(text).moves, moves, R) > 20


def test_nearly_tangent_outside_joins_of_lines_and_arcs_meet_without_an_arc():
    # the arc's start tangent turns right by 1e-4 rad from the line (a CAM post's rounding of a tangent join):
    # outside for G41, the offset line and circle meet; the same arc 0.1 rad off gets its corner arc
    text = """G21 G90 G17 F600
G0 X-20 Y0
G41 G1 X0 Y0 D1
X20
G2 X39.998 Y-20 I-0.002 J-20
G40 G1 X60 Y-20
M30"""
    moves = compensated(text)
    assert [m.kind for m in moves] == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_ARC, MOVE_LINE]
    assert moves[2].end == moves[3].start and moves[3].r0 == pytest.approx(0.025, abs=1e-9)
    assert check_path(marked(text).moves, moves, R) > 10
    sharper = text.replace("G2 X39.998 Y-20 I-0.002 J-20", "G2 X37.9034 Y-21.8968 I-1.9967 J-19.9001")
    moves = compensated(sharper)
    assert [m.kind for m in moves] == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_ARC, MOVE_ARC, MOVE_LINE]
    assert moves[3].r0 == R and check_path(marked(sharper).moves, moves, R) > 10


def test_rapids_under_compensation_cross_outside_corners_straight():
    # as LinuxCNC: no rapid arc, a rapid straight to the rapid's offset start, then the rapid parallel to its
    # programmed line
    text = """G21 G90 G17 F600
G0 X-20 Y0
G41 G1 X0 Y0 D1
X30
G0 Y-30
G1 X0
G40 G1 X-20 Y-30
M30"""
    moves = compensated(text)
    assert [m.kind for m in moves] == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_RAPID, MOVE_RAPID, MOVE_ARC,
                                       MOVE_LINE, MOVE_LINE]
    chord, rapid = moves[3], moves[4]
    assert chord.line == rapid.line == 5 and chord.feed == rapid.feed == 0.0
    assert chord.start == moves[2].end and chord.start[:2] == pytest.approx((0.03, R), abs=1e-15)
    assert chord.end == rapid.start and rapid.start[:2] == pytest.approx((0.03 + R, 0.0), abs=1e-15)
    assert rapid.end[:2] == pytest.approx((0.03 + R, -0.03), abs=1e-15)


def test_negative_radius_compensates_on_the_other_side_and_zero_leaves_the_path():
    left = compensated(SQUARE.format(comp="G41"), -R)
    right = compensated(SQUARE.format(comp="G42"), R)
    assert [(m.kind, m.start, m.end) for m in left] == [(m.kind, m.start, m.end) for m in right]
    plain = marked(SQUARE.format(comp="G41"), 0.0).moves
    assert [(m.kind, m.start, m.end) for m in compensated(SQUARE.format(comp="G41"), 0.0)] == \
        [(m.kind, m.start, m.end) for m in plain]


# refusals: file, line, the line's text and what was expected

def _assert_refused(error: ProgramError, line: int, expected_part: str, text: str) -> None:
    assert error.file == FILE and error.line == line
    assert error.text == text.split("\n")[line - 1]
    assert expected_part in error.expected
    assert str(error).startswith(f'{FILE} line {line}: "{error.text}": ')


def test_an_inside_step_shorter_than_the_tool_radius_is_refused_as_gouging():
    text = """G21 G90 G17 F600
G0 X25 Y25
G42 G1 Y50 D1
X50
Y0
X30
Y2
X0
Y50
X25
G40 G1 Y25
M30"""
    _assert_refused(refusal(text), 6, "the tool (radius 5 mm) cannot follow this inside corner without gouging",
                    text)
    # a step as long as the radius plus a margin is cut
    assert compensated(text.replace("Y2\n", "Y5.5\n"))
    # an inside arc of smaller radius than the tool
    arc = """G21 G90 G17 F600
G0 X-20 Y0
G41 G1 X0 Y0 D1
X20
G3 X20 Y8 I0 J4
G1 X0
G40 G1 X-20 Y8
M30"""
    _assert_refused(refusal(arc), 5, "an arc radius greater than the tool radius (5 mm) on the compensated side",
                    arc)
    assert compensated(arc, 0.003)


def test_an_entry_move_no_longer_than_the_radius_is_refused():
    text = """G21 G90 G17 F600
G0 X-4 Y0
G41 G1 X0 Y0 D1
X30
G40 G1 X40
M30"""
    _assert_refused(refusal(text), 3, "an entry move after G41/G42 longer than the tool radius (5 mm)", text)


NURBS = "\n".join(["G21 G90 G17 F600", "G0 X-20 Y0", "G41 G1 X0 Y0 D1"]
                  + nurbs_block_gcode([(0, 0), (10, 20), (20, 0)], [1, 1, 1], [0, 0, 0, 1, 1, 1], 2)
                  + ["G40 G1 X30 Y0", "M30"])


def test_nurbs_under_compensation_is_refused():
    text = NURBS
    _assert_refused(refusal(text), 4, "cutter compensation of a NURBS block is not supported", text)
    # outside compensation the same block is left as it is
    plain = text.replace("G41 ", "").replace("G40 ", "")
    assert [m.kind for m in compensated(plain)].count(MOVE_NURBS) == 1


def test_arcs_outside_the_xy_plane_entry_and_exit_arcs_and_side_changes_are_refused():
    text = """G21 G90 G17 F600
G0 X-20 Y0
G41 G1 X0 Y0 D1
G18 G2 X10 Z0 I5 K0
G40 G1 X20
M30"""
    _assert_refused(refusal(text), 4, "XY plane (G17) only", text)
    assert "ZX plane (G18)" in refusal(text).expected
    text = """G21 G90 G17 F600
G0 X-20 Y0
G41 G2 X0 Y20 I10 J10 D1
G40 G1 X20
M30"""
    _assert_refused(refusal(text), 3, "a straight entry move (G0 or G1)", text)
    text = """G21 G90 G17 F600
G0 X-20 Y0
G41 G1 X0 Y0 D1
X20
G40 G2 X40 Y0 I10 J0
M30"""
    _assert_refused(refusal(text), 5, "a straight exit move (G0 or G1) as the first move in XY after G40, got an arc",
                    text)
    text = """G21 G90 G17 F600
G0 X-20 Y0
G41 G1 X0 Y0 D1
X20
G42 X40
G40 G1 X60
M30"""
    _assert_refused(refusal(text), 5, "G40 before changing the side or the radius", text)


# C equals Python

def test_constants_agree_with_the_header():
    header = HEADER.read_text()
    for name in ("COMP_TANGENT", "COMP_SMALL_TURN", "COMP_SLACK"):
        value = re.search(rf"#define {name} (\S+)", header).group(1)
        assert float(value) == getattr(cutter_comp, name), name


PROGRAMS = [SQUARE.format(comp="G41"), SQUARE.format(comp="G42"), NURBS, NURBS.replace("G41 ", "")]


def _all_test_programs() -> list[str]:
    """Every program text of this module (the known contours and the refusals)."""
    source = Path(__file__).read_text()
    found = re.findall(r'"""(G21 G90 G17.*?)"""', source, flags=re.DOTALL)
    return PROGRAMS + [t for t in found if "{" not in t]


def _random_contour(rng: random.Random, bulge: float = 1.0) -> str:
    """A closed contour around a random star-shaped polygon (5-10 corners, sorted angles: a simple polygon whose
    corners are inside and outside ones), some sides arcs through the side's end bulging either way (radius
    >= the chord / (2 sin(bulge / 2)): at most `bulge` rad of sweep), CAM-style coordinates (4 decimals, so joins
    that should be tangent are not exactly), a few rapid sides, plunges and dwells, a random direction and side,
    and a straight entry and exit."""
    n = rng.randint(5, 10)
    angles = sorted(rng.uniform(0.0, 2.0 * math.pi) for _ in range(n))
    radii = [rng.uniform(20.0, 40.0) for _ in range(n)]
    pts = [(r * math.cos(a), r * math.sin(a)) for r, a in zip(radii, angles)]
    if rng.random() < 0.5:
        pts.reverse()
    start = (pts[0][0] * 1.8, pts[0][1] * 1.8)
    lines = ["G21 G90 G17 F800", f"G0 X{start[0]:.4f} Y{start[1]:.4f} Z5", "G1 Z-1",
             f"{rng.choice(['G41', 'G42'])} G1 X{pts[0][0]:.4f} Y{pts[0][1]:.4f} D1"]
    for k in range(1, n + 1):
        x, y = pts[k % n]
        px, py = pts[k - 1]
        if rng.random() < 0.4:
            chord = math.hypot(x - px, y - py)
            radius = chord / (2.0 * math.sin(rng.uniform(0.05, bulge) / 2.0))
            lines.append(f"{rng.choice(['G2', 'G3'])} X{x:.4f} Y{y:.4f} R{radius:.4f}")
        else:
            lines.append(f"{'G0' if rng.random() < 0.1 else 'G1'} X{x:.4f} Y{y:.4f}")
        if rng.random() < 0.1:
            lines.append(f"G1 Z{rng.uniform(-2.0, 0.0):.4f}")
        if rng.random() < 0.05:
            lines.append("G4 P0.2")
    lines += [f"G40 G1 X{start[0]:.4f} Y{start[1]:.4f}", "G0 Z5", "M30"]
    return "\n".join(lines)


@needs_driver
def test_c_stage_equals_the_python_reference(tmp_path):
    rng = random.Random(20261125)
    cases = [(t, R) for t in _all_test_programs()] + [(t, 0.003) for t in _all_test_programs()]
    cases += [(_random_contour(rng), rng.choice([0.001, 0.003, 0.005, 0.008, -0.004])) for _ in range(300)]
    outcomes = {"ok": 0, "refused": 0}
    for text, radius in cases:
        try:
            original, expected = python_result(text, radius)
        except ProgramError:
            continue      # a random arc the parser does not take (R shorter than half the chord after rounding)
        got = c_compensate(original, text, tmp_path)
        assert got == expected, text
        outcomes["ok" if isinstance(expected, list) else "refused"] += 1
    assert outcomes["ok"] >= 100 and outcomes["refused"] >= 20, outcomes


def _tangents(move: Move) -> tuple[tuple[float, float], tuple[float, float]]:
    if move.kind == MOVE_ARC:
        sign = 1.0 if move.sweep > 0 else -1.0
        a, b = move.theta0, move.theta0 + move.sweep
        return (-sign * math.sin(a), sign * math.cos(a)), (-sign * math.sin(b), sign * math.cos(b))
    dx, dy = move.end[0] - move.start[0], move.end[1] - move.start[1]
    length = math.hypot(dx, dy)
    return (dx / length, dy / length), (dx / length, dy / length)


def _room_for_the_tool(original: list[Move], radius: float) -> bool:
    """The contour has room for the tool: no turn sharper than 150 degrees, and elements that do not meet keep
    2 radii apart (sampled), so that a gouge could only come from the compensation itself."""
    contour = [m for m in original if m.comp != COMP_OFF and (m.kind == MOVE_ARC or m.start[:2] != m.end[:2])][1:]
    for a, b in zip(contour, contour[1:] + contour[:1]):
        ta, tb = _tangents(a)[1], _tangents(b)[0]
        if ta[0] * tb[0] + ta[1] * tb[1] < math.cos(math.radians(150.0)):
            return False
    points = [[_point(m, j / 24.0)[:2] for j in range(25)] for m in contour]
    n = len(contour)
    for i in range(n):
        for k in range(i + 2, n):
            if i == 0 and k == n - 1:
                continue
            if min(_distance_to(contour[k], x, y) for x, y in points[i]) < 2.0 * radius:
                return False
    return True


_TURNS = (0.0, 1e-12, -1e-12, 1e-9, -1e-9, 1e-6, -1e-6, 0.005, -0.005, 0.5, -0.5, math.pi / 2.0, -math.pi / 2.0,
          math.pi - 1e-9, -(math.pi - 1e-9), math.pi)


def _random_moves(rng: random.Random) -> Program:
    """A random sequence of moves as the parser could make them (not from a program): lines and rapids turning by
    anything from 0 to a reversal (near-tangent turns included), tiny and Z-only lines, arcs in all planes and of
    any sweep, dwells, NURBS pieces, compensation switched on and off with radii 0, +/-1, 5, 20 mm and changes."""
    moves: list[Move] = []
    pos, heading = [0.0, 0.0, 0.0], rng.uniform(-math.pi, math.pi)
    comp, radius = COMP_OFF, 0.0
    for k in range(rng.randint(1, 30)):
        if rng.random() < 0.2:
            comp = rng.choice([COMP_OFF, COMP_LEFT, COMP_RIGHT])
            radius = rng.choice([0.0, 0.001, -0.001, 0.005, 0.02])
        state = dict(offset=(0.0, 0.0, 0.0), feed=0.01, spindle=0.0, spindle_on=False, comp=comp,
                     comp_radius=radius if comp != COMP_OFF else 0.0)
        kind = rng.random()
        heading += rng.choice(_TURNS)
        if kind < 0.45:
            length = rng.choice([1e-9, 1e-4, 0.002, 0.03])
            end = [pos[0] + length * math.cos(heading), pos[1] + length * math.sin(heading), pos[2]]
            if rng.random() < 0.1:
                end = [pos[0], pos[1], pos[2] - 0.001]
            rapid = rng.random() < 0.15
            moves.append(Move(MOVE_RAPID if rapid else MOVE_LINE, k + 1, tuple(pos), tuple(end),
                              **dict(state, feed=0.0 if rapid else 0.01)))
        elif kind < 0.85:
            ia, ib, inormal = (0, 1, 2) if rng.random() < 0.9 else (2, 0, 1)
            r = rng.choice([1e-4, 0.003, 0.006, 0.05])
            sweep = rng.choice([-1.0, 1.0]) * rng.choice([1e-6, 0.3, 2.0, math.pi, 2.0 * math.pi])
            # the centre to the side the sweep turns to: the arc starts along the heading (or off it)
            normal = heading + (math.pi / 2.0 if sweep > 0 else -math.pi / 2.0) + rng.choice([0.0, 0.0, 0.3])
            centre = list(pos)
            centre[ia], centre[ib] = pos[ia] + r * math.cos(normal), pos[ib] + r * math.sin(normal)
            theta0 = math.atan2(pos[ib] - centre[ib], pos[ia] - centre[ia])
            end = list(pos)
            end[ia] = centre[ia] + r * math.cos(theta0 + sweep)
            end[ib] = centre[ib] + r * math.sin(theta0 + sweep)
            height = rng.choice([0.0, 0.0, -0.002])
            end[inormal] = pos[inormal] + height
            moves.append(Move(MOVE_ARC, k + 1, tuple(pos), tuple(end), center=tuple(centre), axes=(ia, ib, inormal),
                              theta0=theta0, sweep=sweep, r0=math.hypot(pos[ia] - centre[ia], pos[ib] - centre[ib]),
                              r1=math.hypot(end[ia] - centre[ia], end[ib] - centre[ib]), height=height, **state))
            if ia == 0:
                heading = theta0 + sweep + (math.pi / 2.0 if sweep > 0 else -math.pi / 2.0)
        elif kind < 0.93:
            moves.append(Move(MOVE_DWELL, k + 1, tuple(pos), tuple(pos), dwell=0.5, **state))
        else:
            end = [pos[0] + 0.01, pos[1] - 0.01, pos[2]]
            moves.append(Move(MOVE_NURBS, k + 1, tuple(pos), tuple(end), curve=0, u0=0.0, u1=1.0, **state))
        pos = list(moves[-1].end)
    return Program(FILE, moves, [], len(moves), 0, 0.0, False, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


@needs_driver
def test_random_move_sequences_c_equals_python_and_nothing_breaks(tmp_path):
    rng = random.Random(16)
    outcomes = {"ok": 0, "refused": 0}
    for case in range(500):
        program = _random_moves(rng)
        text = "\n".join(f"N{k + 1} (move {k + 1})" for k in range(len(program.moves)))
        original = replace(program, moves=list(program.moves))
        try:
            compensate(program, text, FILE)
            expected = [_words(m) for m in program.moves]
            for m in program.moves:
                assert all(math.isfinite(v) for v in m.start + m.end + m.center + (m.theta0, m.sweep, m.r0, m.r1))
            for a, b in zip(program.moves, program.moves[1:]):
                assert a.end == b.start
        except ProgramError as error:
            expected = str(error)
            assert error.text == text.split("\n")[error.line - 1]
        assert c_compensate(original, text, tmp_path) == expected, case
        outcomes["ok" if isinstance(expected, list) else "refused"] += 1
    assert outcomes["ok"] >= 100 and outcomes["refused"] >= 100, outcomes


def test_random_contours_keep_the_tool_radius_from_the_contour():
    rng = random.Random(7)
    checked = compensated_programs = 0
    for _ in range(200):
        text = _random_contour(rng)
        radius = rng.choice([0.001, 0.003, 0.005])
        program = marked(text, radius)
        original = list(program.moves)
        if not _room_for_the_tool(original, radius):
            continue
        try:
            compensate(program, text, FILE)
        except ProgramError as error:
            assert error.line >= 1 and error.text == text.split("\n")[error.line - 1]
            continue
        checked += check_path(original, program.moves, abs(radius), samples=8, whole_contour=False)
        compensated_programs += 1
    assert compensated_programs >= 60 and checked > 5000, (compensated_programs, checked)


def test_the_parser_runs_the_compensation_in_c_and_python(tmp_path) -> None:
    """A G41 square through parse_program and through the C engine (interp_run): the cut runs on the offset
    square, the tool radius (5 mm) outside the programmed 20 mm square, in both."""
    from milling_twin.models.interpolator import default_parameters
    from milling_twin.models.interpolator.parser import parse_program
    from milling_twin.models.interpolator.tool_table import parse_tool_table

    table = "T1 D10 Z50\n"
    text = ("G21 G90 G17\nT1 M6\nG0 X-20 Y-20\nG1 Z-1 F300\nG41 D1 G1 X0 Y0\nY20\nX20\nY0\nX0\n"
            "G40 G1 X-20 Y-20\nM30\n")
    program = parse_program(text, default_parameters(), "square.nc", tools=parse_tool_table(table))
    cut = [m for m in program.moves if m.line == 6]  # Y20: the left side, 5 mm left of X0 (climb: G41)
    assert len(cut) == 1 and cut[0].start[0] == pytest.approx(-0.005, abs=1e-12)
    assert cut[0].end[0] == pytest.approx(-0.005, abs=1e-12) and cut[0].end[1] == pytest.approx(0.02, abs=1e-12)
    (tmp_path / "square.nc").write_text(text)
    (tmp_path / "tool.tbl").write_text(table)
    csv = tmp_path / "out.csv"
    driver = REPO / "build" / "tools" / "interp_run"
    run = subprocess.run([str(driver), "--tool-table", str(tmp_path / "tool.tbl"), "--csv", str(csv),
                          str(tmp_path / "square.nc")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    rows = [line.split(",") for line in csv.read_text().splitlines()[1:]]
    on_left_side = [float(r[2]) for r in rows if r[8] == "6"]
    assert on_left_side and max(abs(x + 0.005) for x in on_left_side) < 1e-9

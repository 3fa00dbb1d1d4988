"""Parser: part program text -> moves (lines, arcs, NURBS pieces) in machine coordinates, in metres.
Mirrors ``fmus/interpolator/gcode_parser.c`` (and ``gcode_parser.h``); ``nurbs_block_gcode`` writes G6.2 blocks
for tests, benchmarks and training.

G-code subset (one block per line; letters case-insensitive; ``N`` words and blanks ignored)
------------------------------------------------------------------------------------------------
- comments ``( ... )`` (one line, not nested) and ``;`` to the end of the line; a line holding only ``%``
  is a tape mark and ignored;
- numbers: ``[+-]digits[.digits]`` or ``[+-].digits``, at most 17 significant digits, no exponent;
- ``G0`` rapid, ``G1`` line, ``G2``/``G3`` arc clockwise/counter-clockwise (centre ``I J K`` relative to
  the start, or radius ``R``: R > 0 the arc of at most 180 degrees, R < 0 the longer one; a full circle
  needs I/J/K), helical with the third axis; ``G6.2`` NURBS block (below); ``G17``/``G18``/``G19`` plane
  XY/ZX/YZ (centre words I,J / K,I / J,K); ``G20``/``G21`` inch/mm; ``G90``/``G91`` absolute/incremental;
  ``G54``..``G59`` work offsets (values from the parameters ``g54_x`` ... ``g59_z`` or set by
  ``G10 L2 P1..6 X Y Z``: the machine position of the work zero, in the current length unit);
- ``F`` feed (mm/min or inch/min, > 0, required before the first G1/G2/G3/G6.2), ``S`` spindle speed
  (rpm), ``M3``/``M4``/``M5`` spindle clockwise/counter-clockwise/stop, ``M2``/``M30`` program end
  (only blank and comment lines may follow).
- Within a line: F and S, then M3/M4/M5, then G17-G19/G20/G21/G90/G91/G54-G59, then G10, then the
  motion, then M2/M30. Axis words without G10 need a motion mode (G0-G3 set one, it is modal).

NURBS blocks (Fanuc style; ``P`` is the order = degree + 1, 2..6, default 4: a cubic)::

    G6.2 P4 K0 X.. Y.. Z.. R1 [F..]   first control point: must be the current position (1 um)
    K0 X.. Y.. R..                    one control point per line: knot K, axes (omitted: previous
    ...                               control point's), weight R > 0 (default 1)
    K1                                then degree+1 lines with a knot only
    K1
    K1
    K1

The block ends at the first line without K. Knots must be non-decreasing and clamped (first and last
degree+1 equal), inner knots of multiplicity at most the degree (degree = a corner, handled as a
block boundary); at least degree+1 control points; degree 1..5 (P2..P6); only in G90.

Every malformed line fails initialization with ``<file> line <n>: "<text>": <what was expected>``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

from milling_twin.models.interpolator.nurbs import dot as _dot

OFFSET_NAMES = ("g54", "g55", "g56", "g57", "g58", "g59")

MAX_LINE_LENGTH = 1000
MAX_SIGNIFICANT_DIGITS = 17
MAX_COORDINATE = 1e6        # |value| in program units (mm or inch)
MAX_FEED_WORD = 1e7         # mm/min
MAX_SPEED_WORD = 1e6        # rpm
MAX_NURBS_POINTS = 100000
MAX_DEGREE = 5
START_POINT_TOLERANCE = 1e-6   # m: first NURBS control point vs current position
ARC_RADIUS_TOLERANCE = 2e-6    # m, plus ARC_RADIUS_RELATIVE * radius
ARC_RADIUS_RELATIVE = 1e-4

MOVE_RAPID, MOVE_LINE, MOVE_ARC, MOVE_NURBS, MOVE_DWELL = 0, 1, 2, 3, 4
COMP_OFF, COMP_LEFT, COMP_RIGHT = 0, 1, 2
COOLANT_OFF, COOLANT_MIST, COOLANT_FLOOD, COOLANT_BOTH = 0, 1, 2, 3
DIALECT_FANUC, DIALECT_LINUXCNC, DIALECT_SINUMERIK = 0, 1, 2
DIALECTS = {"fanuc": DIALECT_FANUC, "linuxcnc": DIALECT_LINUXCNC, "sinumerik": DIALECT_SINUMERIK}


class ProgramError(ValueError):
    """A malformed part program: ``line`` (1-based), ``text`` of the line and what was ``expected``."""

    def __init__(self, file: str, line: int, text: str, expected: str):
        self.file, self.line, self.text, self.expected = file, line, text, expected
        super().__init__(f"{file} line {line}: \"{_clip(text)}\": {expected}")


def _clip(text: str) -> str:
    return text if len(text) <= 80 else text[:77] + "..."


@dataclass
class NurbsCurve:
    degree: int
    points: list[tuple[float, float, float]]      # machine coordinates, m
    weights: list[float]
    knots: list[float]
    line: int


@dataclass
class Move:
    kind: int
    line: int
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    offset: tuple[float, float, float]
    feed: float                    # programmed F in m/s (rapids: 0)
    spindle: float                 # rad/s, signed
    spindle_on: bool
    block: int = 0                 # N word, 0 without
    # arc
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axes: tuple[int, int, int] = (0, 1, 2)
    theta0: float = 0.0
    sweep: float = 0.0
    r0: float = 0.0
    r1: float = 0.0
    height: float = 0.0
    # nurbs
    curve: int = -1
    u0: float = 0.0
    u1: float = 0.0
    # machine state while the move runs
    tool: int = 0                  # active tool number (T.. M6), 0 before the first tool change
    coolant: int = COOLANT_OFF     # COOLANT_MIST (M7), COOLANT_FLOOD (M8), COOLANT_BOTH
    exact_stop: bool = False       # the path stops at the end of this move (G61, G9, before a dwell)
    dwell: float = 0.0             # MOVE_DWELL: seconds the tool stands still at start (== end)
    tolerance: float = 0.0         # contour tolerance of G64 P / CYCLE832, m; 0: the chord_error parameter
    comp: int = COMP_OFF           # cutter radius compensation: COMP_LEFT (G41), COMP_RIGHT (G42)
    comp_radius: float = 0.0       # m: the radius the tool path is offset by


@dataclass(frozen=True)
class Tool:
    """One row of the tool table, SI units; ``number`` is the T word."""
    number: int
    diameter: float
    name: str = ""                  # Sinumerik T="name"
    corner_radius: float = 0.0
    length: float = 0.0
    stick_out: float = 0.0
    helix: float = 0.0             # rad
    flutes: int = 0


@dataclass
class Program:
    file: str
    moves: list[Move]
    curves: list[NurbsCurve]
    final_line: int
    final_block: int
    final_spindle: float
    final_spindle_on: bool
    start: tuple[float, float, float]
    start_offset: tuple[float, float, float]


_LETTERS = "GMNXYZIJKRFSPL"


def _parse_number(text: str, i: int, file: str, line: int, raw: str, letter: str) -> tuple[float, int, str]:
    """The number at text[i:] (spaces before it allowed); returns (value, next index, digits as written)."""
    n = len(text)
    while i < n and text[i] in " \t":
        i += 1
    start = i
    negative = False
    if i < n and text[i] in "+-":
        negative = text[i] == "-"
        i += 1
    mantissa, digits, scale, seen_point, any_digit = 0, 0, 0, False, False
    while i < n and (text[i].isdigit() and text[i] in "0123456789" or (text[i] == "." and not seen_point)):
        if text[i] == ".":
            seen_point = True
        else:
            any_digit = True
            d = ord(text[i]) - 48
            if mantissa == 0 and d == 0:
                if seen_point:
                    scale += 1
            else:
                digits += 1
                if digits > MAX_SIGNIFICANT_DIGITS:
                    raise ProgramError(file, line, raw, f"at most {MAX_SIGNIFICANT_DIGITS} significant digits "
                                                        f"in the number after '{letter}'")
                mantissa = mantissa * 10 + d
                if seen_point:
                    scale += 1
        i += 1
    if not any_digit:
        raise ProgramError(file, line, raw, f"a number after '{letter}'")
    # strip trailing zeros of the fraction: same value, and keeps 10^scale exact
    while scale > 0 and mantissa % 10 == 0 and mantissa != 0:
        mantissa //= 10
        scale -= 1
    if mantissa == 0:
        scale = 0
    if scale > 22:
        raise ProgramError(file, line, raw, f"at most 22 decimals in the number after '{letter}'")
    value = float(mantissa) / (10.0 ** scale) if scale else float(mantissa)
    if negative:
        value = -value
    return value, i, text[start:i]


def _tokenize(raw: str, file: str, line: int) -> list[tuple[str, float, str]]:
    """Words of one line as (letter, value, number text); comments removed."""
    words: list[tuple[str, float, str]] = []
    i, n = 0, len(raw)
    while i < n:
        c = raw[i]
        if c in " \t":
            i += 1
        elif c == "(":
            j = i + 1
            while j < n and raw[j] != ")":
                if raw[j] == "(":
                    raise ProgramError(file, line, raw, "')' before another '(' (comments do not nest)")
                j += 1
            if j >= n:
                raise ProgramError(file, line, raw, "')' to close the comment")
            i = j + 1
        elif c == ";":
            break
        elif c.isalpha() and c.isascii():
            letter = c.upper()
            if letter not in _LETTERS:
                raise ProgramError(file, line, raw, f"a word G, M, N, X, Y, Z, I, J, K, R, F, S, P or L, got '{c}'")
            value, i, text = _parse_number(raw, i + 1, file, line, raw, letter)
            words.append((letter, value, text))
        else:
            shown = f"'{c}'" if c.isprintable() and c.isascii() else f"byte 0x{ord(c):02x}" if ord(c) < 128 \
                else "a non-ASCII character"
            raise ProgramError(file, line, raw, f"a word (letter and number), a comment or the end of the line, "
                                                f"got {shown}")
    return words


def _g_code(value: float, text: str, file: str, line: int, raw: str) -> int:
    """G code as 10 * number (G6.2 -> 62); unknown codes are an error."""
    tenths = round(value * 10.0)
    if abs(value * 10.0 - tenths) > 1e-9 or value < 0:
        tenths = -1
    known = {0, 10, 20, 30, 62, 100, 170, 180, 190, 200, 210, 540, 550, 560, 570, 580, 590, 900, 910}
    if tenths not in known:
        raise ProgramError(file, line, raw, f"a supported G code (G0 G1 G2 G3 G6.2 G10 G17 G18 G19 G20 G21 "
                                            f"G54-G59 G90 G91), got G{text}")
    return tenths


def _m_code(value: float, text: str, file: str, line: int, raw: str) -> int:
    if value not in (2.0, 3.0, 4.0, 5.0, 30.0):
        raise ProgramError(file, line, raw, f"a supported M code (M2 M3 M4 M5 M30), got M{text}")
    return int(value)


class _Parser:
    def __init__(self, text: str, file: str, p: Mapping[str, float]):
        self.file = file
        self.lines = text.split("\n")
        self.p = p
        self.offsets = [[p[f"{name}_{a}"] for a in "xyz"] for name in OFFSET_NAMES]
        self.active_offset = 0
        self.position = [p["start_x"], p["start_y"], p["start_z"]]   # machine
        self.unit = 1e-3          # m per program unit (G21)
        self.inch = False
        self.absolute = True
        self.plane = 17
        self.motion = -1
        self.feed = 0.0           # m/s; 0 = not set
        self.speed = 0.0          # rpm as written
        self.spindle_dir = 0      # 1 M3, -1 M4, 0 M5
        self.moves: list[Move] = []
        self.curves: list[NurbsCurve] = []
        self.ended = 0
        self.final_line = 0
        self.final_block = 0
        self.block = 0
        self.start = tuple(self.position)
        self.start_offset = tuple(self.offsets[0])

    def fail(self, line: int, expected: str):
        raise ProgramError(self.file, line, self.lines[line - 1].rstrip("\r"), expected)

    def length(self, value: float) -> float:
        return value * 0.0254 if self.inch else value / 1000.0

    def spindle_now(self) -> tuple[float, bool]:
        speed = self.speed * (2.0 * math.pi / 60.0) * self.spindle_dir
        return speed, self.spindle_dir != 0

    def run(self) -> Program:
        n = len(self.lines)
        k = 0
        while k < n:
            k = self.line(k)
        return Program(self.file, self.moves, self.curves, self.final_line, self.final_block, *self.spindle_now(),
                       self.start, self.start_offset)

    def line(self, k: int) -> int:
        number = k + 1
        raw = self.lines[k].rstrip("\r")
        if len(raw) > MAX_LINE_LENGTH:
            raise ProgramError(self.file, number, raw, f"a line of at most {MAX_LINE_LENGTH} characters")
        if raw.strip(" \t") == "%":
            return k + 1
        words = _tokenize(raw, self.file, number)
        if not words:
            return k + 1
        if self.ended:
            self.fail(number, f"nothing after the program end (M2/M30 in line {self.ended})")
        self.final_line = number
        seen: dict[str, tuple[float, str]] = {}
        gs: dict[str, int] = {}
        ms: dict[str, int] = {}
        groups = {0: "motion", 10: "motion", 20: "motion", 30: "motion", 62: "motion", 100: "g10",
                  170: "plane", 180: "plane", 190: "plane", 200: "units", 210: "units",
                  900: "distance", 910: "distance"}
        for letter, value, text in words:
            if letter == "G":
                code = _g_code(value, text, self.file, number, raw)
                group = groups.get(code, "offset")
                if group in gs:
                    self.fail(number, f"one G code of the {group} group per line, got G{gs[group] / 10:g} "
                                      f"and G{text}")
                gs[group] = code
            elif letter == "M":
                code = _m_code(value, text, self.file, number, raw)
                group = "end" if code in (2, 30) else "spindle"
                if group in ms:
                    self.fail(number, f"one M code of the {group} group per line, got M{ms[group]} and M{text}")
                ms[group] = code
            elif letter == "N":
                if seen or gs or ms:
                    self.fail(number, "the line number N first in the line")
                if value < 0 or value != math.floor(value) or value > 2147483647:
                    self.fail(number, f"a whole line number after N, got N{text}")
                seen["N"] = (value, text)
            else:
                if letter in seen:
                    self.fail(number, f"one {letter} word per line")
                seen[letter] = (value, text)
        self.block = int(seen["N"][0]) if "N" in seen else 0
        self.final_block = self.block
        motion_g = gs.get("motion")
        if motion_g == 62:
            return self.nurbs(k, seen, gs, ms)
        # F, S
        self.feed_and_spindle(number, seen, ms)
        if "plane" in gs:
            self.plane = gs["plane"] // 10
        if "units" in gs:
            self.inch = gs["units"] == 200
        if "distance" in gs:
            self.absolute = gs["distance"] == 900
        if "offset" in gs:
            self.active_offset = (gs["offset"] - 540) // 10
        for letter in ("P", "L"):
            if letter in seen and "g10" not in gs:
                self.fail(number, f"{letter} only with G10 (or P with G6.2)")
        axes = [seen.get(a) for a in "XYZ"]
        if "g10" in gs:
            if "L" not in seen or seen["L"][0] != 2.0:
                self.fail(number, "L2 with G10 (set a work offset)")
            if "P" not in seen or seen["P"][0] not in (1.0, 2.0, 3.0, 4.0, 5.0, 6.0):
                self.fail(number, "P1 to P6 with G10 L2 (the work offset G54 to G59)")
            if motion_g is not None:
                self.fail(number, "no motion G code in a G10 line")
            for letter in "IJKR":
                if letter in seen:
                    self.fail(number, f"only X, Y, Z with G10 L2, got {letter}")
            index = int(seen["P"][0]) - 1
            for a in range(3):
                if axes[a] is not None:
                    value = axes[a][0]
                    if abs(value) > MAX_COORDINATE:
                        self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                    self.offsets[index][a] = self.length(value)
        else:
            if motion_g is not None:
                self.motion = motion_g
            has_axes = any(x is not None for x in axes)
            arc_words = [w for w in "IJKR" if w in seen]
            if self.motion in (20, 30) and (has_axes or motion_g is not None or arc_words):
                self.arc(number, seen, axes)
            elif has_axes or motion_g is not None:
                if arc_words:
                    self.fail(number, f"{arc_words[0]} only with G2/G3 (or in a NURBS block)")
                if self.motion < 0:
                    self.fail(number, "a motion mode G0, G1, G2 or G3 before coordinates")
                if has_axes:
                    self.straight(number, axes)
            elif arc_words:
                self.fail(number, f"{arc_words[0]} only with G2/G3 (or in a NURBS block)")
        if "end" in ms:
            self.ended = number
        return k + 1

    def target(self, number: int, axes) -> list[float]:
        off = self.offsets[self.active_offset]
        out = []
        for a in range(3):
            if axes[a] is None:
                out.append(self.position[a])
                continue
            value = axes[a][0]
            if abs(value) > MAX_COORDINATE:
                self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
            if self.absolute:
                out.append(self.length(value) + off[a])
            else:
                out.append(self.position[a] + self.length(value))
        return out

    def need_feed(self, number: int) -> None:
        if self.feed <= 0.0:
            self.fail(number, "F (feed) before the first feed move (G1, G2, G3, G6.2)")

    def add(self, move: Move) -> None:
        move.block = self.block
        self.moves.append(move)
        self.position = list(move.end)

    def straight(self, number: int, axes) -> None:
        end = self.target(number, axes)
        rapid = self.motion == 0
        if not rapid:
            self.need_feed(number)
        dx, dy, dz = end[0] - self.position[0], end[1] - self.position[1], end[2] - self.position[2]
        if dx * dx + dy * dy + dz * dz <= 0.0:
            return
        speed, on = self.spindle_now()
        self.add(Move(MOVE_RAPID if rapid else MOVE_LINE, number, tuple(self.position), tuple(end),
                      tuple(self.offsets[self.active_offset]), 0.0 if rapid else self.feed, speed, on))

    def arc(self, number: int, seen, axes) -> None:
        self.need_feed(number)
        plane_axes = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}[self.plane]
        centre_words = {17: ("I", "J"), 18: ("K", "I"), 19: ("J", "K")}[self.plane]
        ia, ib, inormal = plane_axes
        if not any(x is not None for x in axes) and "R" not in seen and not any(w in seen for w in "IJK"):
            self.fail(number, "an end point or a centre with G2/G3")
        end = self.target(number, axes)
        start = self.position
        for w in "IJK":
            if w in seen and w not in centre_words:
                self.fail(number, f"the centre words {centre_words[0]}, {centre_words[1]} in the G{self.plane} "
                                  f"plane, got {w}")
        has_ijk = any(w in seen for w in centre_words)
        clockwise = self.motion == 20
        sa, sb = start[ia], start[ib]
        ea, eb = end[ia], end[ib]
        if has_ijk and "R" in seen:
            self.fail(number, "either the centre (I, J, K) or the radius R, not both")
        if not has_ijk and "R" not in seen:
            self.fail(number, f"the arc centre ({centre_words[0]}, {centre_words[1]}) or the radius R with "
                              f"G{self.motion // 10}")
        if has_ijk:
            offs = []
            for w in centre_words:
                value = seen[w][0] if w in seen else 0.0
                if abs(value) > MAX_COORDINATE:
                    self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                offs.append(self.length(value))
            ca, cb = sa + offs[0], sb + offs[1]
        else:
            r = seen["R"][0]
            if abs(r) > MAX_COORDINATE:
                self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
            radius = self.length(abs(r))
            da, db = ea - sa, eb - sb
            chord = math.sqrt(da * da + db * db)
            if chord <= 0.0:
                self.fail(number, "an end point different from the start with R (a full circle needs I, J, K)")
            if radius <= 0.0:
                self.fail(number, "a radius R other than 0")
            half = 0.5 * chord
            if half > radius * (1.0 + ARC_RADIUS_RELATIVE) + ARC_RADIUS_TOLERANCE:
                self.fail(number, f"a radius R of at least half the distance to the end point "
                                  f"({half / self.unit_factor():.6g})")
            h2 = radius * radius - half * half
            h = math.sqrt(h2) if h2 > 0.0 else 0.0
            # left of the travel direction for G3 with R > 0 and for G2 with R < 0
            left = (not clockwise) == (r > 0)
            sign = 1.0 if left else -1.0
            ca = sa + 0.5 * da - sign * h * db / chord
            cb = sb + 0.5 * db + sign * h * da / chord
        r0 = math.sqrt((sa - ca) * (sa - ca) + (sb - cb) * (sb - cb))
        r1 = math.sqrt((ea - ca) * (ea - ca) + (eb - cb) * (eb - cb))
        if r0 <= 0.0:
            self.fail(number, "an arc centre away from the start point")
        if abs(r1 - r0) > ARC_RADIUS_TOLERANCE + ARC_RADIUS_RELATIVE * r0:
            self.fail(number, f"the end point on the arc: its distance from the centre is "
                              f"{r1 / self.unit_factor():.6g}, the start's {r0 / self.unit_factor():.6g}")
        theta0 = math.atan2(sb - cb, sa - ca)
        theta1 = math.atan2(eb - cb, ea - ca)
        sweep = theta1 - theta0
        if clockwise:
            if sweep >= 0.0:
                sweep -= 2.0 * math.pi
        else:
            if sweep <= 0.0:
                sweep += 2.0 * math.pi
        height = end[inormal] - start[inormal]
        centre = [0.0, 0.0, 0.0]
        centre[ia], centre[ib], centre[inormal] = ca, cb, start[inormal]
        speed, on = self.spindle_now()
        self.add(Move(MOVE_ARC, number, tuple(start), tuple(end), tuple(self.offsets[self.active_offset]),
                      self.feed, speed, on, center=tuple(centre), axes=plane_axes, theta0=theta0, sweep=sweep,
                      r0=r0, r1=r1, height=height))

    def unit_factor(self) -> float:
        return 0.0254 if self.inch else 1e-3

    def feed_and_spindle(self, number: int, seen: dict, ms: dict) -> None:
        """The F, S and M3/M4/M5 words of a line (plain or G6.2), as gcode_parser.c takes them."""
        if "F" in seen:
            f = seen["F"][0]
            if not (f > 0.0) or f > MAX_FEED_WORD:
                self.fail(number, f"a feed F > 0 and at most {MAX_FEED_WORD:g}, got F{seen['F'][1]}")
            self.feed = self.length(f) / 60.0
        if "S" in seen:
            s = seen["S"][0]
            if s < 0.0 or s > MAX_SPEED_WORD:
                self.fail(number, f"a spindle speed S of 0 to {MAX_SPEED_WORD:g} rpm, got S{seen['S'][1]}")
            self.speed = s
        if "spindle" in ms:
            self.spindle_dir = {3: 1, 4: -1, 5: 0}[ms["spindle"]]

    def nurbs(self, k: int, seen, gs, ms) -> int:
        number = k + 1
        first_line = number
        if not self.absolute:
            self.fail(number, "G90 (absolute coordinates) for a NURBS block")
        for group in ("g10",):
            if group in gs:
                self.fail(number, "no G10 in a NURBS line")
        for letter in "IJ":
            if letter in seen:
                self.fail(number, f"K, X, Y, Z, R, P, F in a G6.2 line, got {letter}")
        if "L" in seen:
            self.fail(number, "K, X, Y, Z, R, P, F in a G6.2 line, got L")
        if "K" not in seen:
            self.fail(number, "a knot K in the G6.2 line")
        if not any(a in seen for a in "XYZR"):
            self.fail(number, "the first control point (X, Y, Z, R) in the G6.2 line")
        degree = 3
        if "P" in seen:
            pv = seen["P"][0]
            if pv not in (2.0, 3.0, 4.0, 5.0, 6.0):
                self.fail(number, f"an order P (degree + 1) of 2 to {MAX_DEGREE + 1}, got P{seen['P'][1]}")
            degree = int(pv) - 1
        self.feed_and_spindle(number, seen, ms)
        for group in ("plane", "units", "distance", "offset"):
            if group in gs:
                self.fail(number, "no other G code in the G6.2 line")
        if "end" in ms:
            self.fail(number, "M2/M30 after the NURBS block, not in its first line")
        self.need_feed(number)
        self.motion = -1          # G6.2 is not modal beyond its block
        points: list[list[float]] = []
        weights: list[float] = []
        knots: list[float] = []
        trailing = 0
        off = self.offsets[self.active_offset]
        previous = list(self.position)
        line_words = seen
        k_line = k
        while True:
            ln = k_line + 1
            if ln != first_line:
                for letter in line_words:
                    if letter not in "KXYZRN":
                        self.fail(ln, f"K, X, Y, Z, R in a NURBS block (started in line {first_line}), got {letter}")
            kv = line_words["K"][0]
            if abs(kv) > MAX_COORDINATE:
                self.fail(ln, f"a knot of magnitude at most {MAX_COORDINATE:g}")
            has_point = any(a in line_words for a in "XYZR")
            if has_point:
                if trailing:
                    self.fail(ln, f"knot-only lines (K) after the last control point of the NURBS block started "
                                  f"in line {first_line}")
                if len(points) >= MAX_NURBS_POINTS:
                    self.fail(ln, f"at most {MAX_NURBS_POINTS} control points in a NURBS block")
                pt = []
                for a, letter in enumerate("XYZ"):
                    if letter in line_words:
                        value = line_words[letter][0]
                        if abs(value) > MAX_COORDINATE:
                            self.fail(ln, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                        pt.append(self.length(value) + off[a])
                    else:
                        pt.append(previous[a])
                w = line_words["R"][0] if "R" in line_words else 1.0
                if not (w > 0.0) or w > MAX_COORDINATE:
                    self.fail(ln, f"a weight R > 0 (and at most {MAX_COORDINATE:g}), got R{line_words['R'][1]}")
                if not points:
                    e = [pt[a] - self.position[a] for a in range(3)]
                    d = math.sqrt(_dot(e, e))
                    if d > START_POINT_TOLERANCE:
                        self.fail(ln, "the first control point at the current position "
                                      + "(" + ", ".join(f"{(self.position[a] - off[a]) / self.unit_factor():.6g}"
                                                        for a in range(3)) + ")")
                    pt = list(self.position)
                points.append(pt)
                weights.append(w)
                previous = pt
            else:
                trailing += 1
                if trailing > MAX_DEGREE + 1:
                    self.fail(ln, f"degree + 1 = {degree + 1} knot-only lines (K) closing the NURBS block started "
                                  f"in line {first_line}")
            if knots and kv < knots[-1]:
                self.fail(ln, f"non-decreasing knots, got K{line_words['K'][1]} after {knots[-1]:.15g}")
            knots.append(kv)
            # next line: continues the block if it has a K word
            nxt = k_line + 1
            while nxt < len(self.lines):
                raw_next = self.lines[nxt].rstrip("\r")
                if len(raw_next) > MAX_LINE_LENGTH:
                    raise ProgramError(self.file, nxt + 1, raw_next,
                                       f"a line of at most {MAX_LINE_LENGTH} characters")
                if raw_next.strip(" \t") == "%":
                    break
                words = _tokenize(raw_next, self.file, nxt + 1)
                if words:
                    break
                nxt += 1
            if nxt >= len(self.lines):
                words = []
            elif raw_next.strip(" \t") == "%":
                words = []
            if not words or not any(w[0] == "K" for w in words):
                end_line = k_line + 1
                break
            line_words = {}
            for letter, value, text in words:
                if letter in line_words:
                    self.fail(nxt + 1, f"one {letter} word per line")
                line_words[letter] = (value, text)
            k_line = nxt
        n_points = len(points)
        if n_points < degree + 1:
            self.fail(end_line, f"at least degree + 1 = {degree + 1} control points in the NURBS block started in "
                                f"line {first_line}, got {n_points}")
        if trailing != degree + 1:
            self.fail(end_line, f"degree + 1 = {degree + 1} knot-only lines (K) closing the NURBS block started in "
                                f"line {first_line}, got {trailing}")
        for j in range(1, degree + 1):
            if knots[j] != knots[0] or knots[-1 - j] != knots[-1]:
                self.fail(first_line, f"a clamped knot vector (the first and the last {degree + 1} knots equal) in "
                                      f"the NURBS block started here")
        if not knots[-1] > knots[0]:
            self.fail(first_line, "a last knot greater than the first in the NURBS block started here")
        if knots[degree + 1] == knots[degree] or knots[n_points] == knots[n_points - 1]:
            self.fail(first_line, f"exactly {degree + 1} equal knots at each end of the NURBS block started here")
        multiplicity = 1
        for j in range(degree + 2, n_points):
            multiplicity = multiplicity + 1 if knots[j] == knots[j - 1] else 1
            if multiplicity > degree:
                self.fail(first_line, f"inner knots of multiplicity at most the degree {degree} in the NURBS block "
                                      f"started here (knot {knots[j]:.15g})")
        curve = NurbsCurve(degree, [tuple(p) for p in points], weights, knots, first_line)
        index = len(self.curves)
        self.curves.append(curve)
        speed, on = self.spindle_now()
        # split at inner knots of multiplicity == degree (possible corners)
        breaks = [knots[degree]]
        j = degree + 1
        while j < n_points:
            m = 1
            while j + m < n_points and knots[j + m] == knots[j]:
                m += 1
            if m >= degree:
                breaks.append(knots[j])
            j += m
        breaks.append(knots[n_points])
        for b in range(len(breaks) - 1):
            self.moves.append(Move(MOVE_NURBS, first_line, tuple(self.position), tuple(points[-1]),
                                   tuple(off), self.feed, speed, on, block=self.block, curve=index, u0=breaks[b],
                                   u1=breaks[b + 1]))
        self.position = list(points[-1])
        self.final_line = end_line
        return end_line


def parse_program(text: str, parameters: Mapping[str, float], file: str = "program.nc") -> Program:
    return _Parser(text, file, parameters).run()


# Writing part programs (tests, benchmark, training)

def _g(x: float) -> str:
    text = f"{x:.10f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def nurbs_block_gcode(points_mm: Sequence[Sequence[float]], weights: Sequence[float], knots: Sequence[float],
                      degree: int, feed_mm_min: float | None = None) -> list[str]:
    """The lines of a G6.2 block of the given degree (written as Fanuc's order P = degree + 1) for control points
    in mm (x, y[, z])."""
    lines = []
    for i, (point, w) in enumerate(zip(points_mm, weights)):
        axes = " ".join(f"{a}{_g(float(c))}" for a, c in zip("XYZ", point))
        head = f"G6.2 P{degree + 1} " if i == 0 else ""
        tail = f" F{_g(feed_mm_min)}" if i == 0 and feed_mm_min is not None else ""
        lines.append(f"{head}K{_g(float(knots[i]))} {axes} R{_g(float(w))}{tail}")
    for k in knots[len(points_mm):]:
        lines.append(f"K{_g(float(k))}")
    return lines

"""Interpolator: the CNC's real-time interpolator as an FMU — part program in, tool positions every
interpolation period out (``fmus/interpolator/``, identifier ``Interpolator``).

This module is (1) the model definition ``INTERPOLATOR`` (variables, units, ranges, defaults) and (2) the
Python reference implementation of everything the FMU's C code computes natively (parser, geometry,
feedrate schedule, parameter update), written operation for operation like the C code so that the
generic FMU tests compare the two to 1e-12 and ``tests/test_interpolator*.py`` prove the C code right.
The C files mirror the sections below: ``gcode_parser.c`` (Parser), ``nurbs.c`` (NURBS),
``path.c`` (Path: moves, samples, velocity limits), ``feed_schedule.c`` (Schedule),
``param_update.c`` (parameter update: Taylor, RBF, corrector) and ``interpolator.c`` (Interpolator).

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

NURBS blocks (Fanuc style; ``P`` is the degree here, not Fanuc's order)::

    G6.2 P3 K0 X.. Y.. Z.. R1 [F..]   first control point: must be the current position (1 um)
    K0 X.. Y.. R..                    one control point per line: knot K, axes (omitted: previous
    ...                               control point's), weight R > 0 (default 1)
    K1                                then degree+1 lines with a knot only
    K1
    K1
    K1

The block ends at the first line without K. Knots must be non-decreasing and clamped (first and last
degree+1 equal), inner knots of multiplicity at most the degree (degree = a corner, handled as a
block boundary); at least degree+1 control points; degree 1..5; only in G90.

Every malformed line fails initialization with ``<file> line <n>: "<text>": <what was expected>``.

Feedrate schedule, parameter update: see ``Path``, ``Schedule`` and ``step_nurbs`` below, and README.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path as FilePath
from typing import Callable, Mapping, Sequence

import numpy as np

from milling_twin.models.definition import ModelDefinition, Variable

# ============================================================================================
# Model definition
# ============================================================================================

METHOD_TAYLOR1, METHOD_TAYLOR2, METHOD_RBF, METHOD_CORRECTOR = 1, 2, 3, 4
METHOD_NAMES = {1: "taylor1", 2: "taylor2", 3: "rbf", 4: "corrector"}
OFFSET_NAMES = ("g54", "g55", "g56", "g57", "g58", "g59")
RBF_HIDDEN, RBF_INPUTS = 5, 4
RESOURCE_PROGRAM = FilePath(__file__).resolve().parents[2] / "fmus" / "interpolator" / "resources" / "program.nc"

# Default RBF network: trained by milling_twin/training/rbf.py on the butterfly curve of
# scenarios/nurbs/ (F 100 mm/s, A 1000 mm/s2, J 1e5 mm/s3, 1 um, 1 ms); rewritten by
# `python -m milling_twin.training.rbf --write-defaults`.
# BEGIN RBF DEFAULTS
RBF_DEFAULTS: dict[str, float] = {
    "rbf_width": 1.5,
    "rbf_offset_1": 0.0, "rbf_offset_2": 0.0, "rbf_offset_3": 0.0, "rbf_offset_4": 0.0,
    "rbf_scale_1": 1.0, "rbf_scale_2": 1.0, "rbf_scale_3": 1.0, "rbf_scale_4": 1.0,
    **{f"rbf_center_{j}_{d}": 0.0 for j in range(1, 6) for d in range(1, 5)},
    **{f"rbf_weight_{j}": 0.0 for j in range(1, 6)},
    "rbf_bias": 0.0,
}
# END RBF DEFAULTS

JERK_UNIT = ""  # m/s3: not yet in models/units.py (display units); documented in the descriptions


def _variables() -> tuple[Variable, ...]:
    fixed = "fixed"
    v: list[Variable] = [
        Variable("program", "String", "parameter",
                 "Part program file (absolute path, or relative to the working directory); empty: "
                 "resources/program.nc of the FMU", start="", variability=fixed),
        Variable("period", "Float64", "parameter", "Interpolation period", unit="s", display_unit="ms",
                 start=1e-3, min=1e-5, max=0.1, variability=fixed),
        Variable("method", "Int32", "parameter",
                 "NURBS parameter update: 1 first-order Taylor, 2 second-order Taylor, 3 RBF network, "
                 "4 predictor-corrector (Newton on the chord length)", start=4, min=1, max=4, variability=fixed),
        Variable("corrector_predictor", "Int32", "parameter",
                 "Predictor refined by method 4: 1 first-order Taylor, 2 second-order Taylor, 3 RBF network",
                 start=2, min=1, max=3, variability=fixed),
        Variable("arc_length_feedback", "Boolean", "parameter",
                 "NURBS steps aim at the scheduled arc length from the actual position (the chords travelled in "
                 "the block), so the error of an inexact update does not accumulate; false: the scheduled step as "
                 "is (open loop, as in the NURBS-interpolation literature)", start=True, variability=fixed),
        Variable("corrector_tolerance", "Float64", "parameter",
                 "Method 4: relative tolerance of the chord length (|chord - step| / step)",
                 start=1e-6, min=1e-15, max=1e-2, variability=fixed),
        Variable("max_feed", "Float64", "parameter", "Highest feed a program may command (F is clipped)",
                 unit="m/s", display_unit="mm/min", start=1.0 / 3.0, min=1e-6, max=10.0, variability=fixed),
        Variable("rapid_feed", "Float64", "parameter", "Path speed of rapid moves (G0; no override)",
                 unit="m/s", display_unit="mm/min", start=1.0 / 6.0, min=1e-6, max=10.0, variability=fixed),
        Variable("acceleration", "Float64", "parameter", "Tangential (path) acceleration limit",
                 unit="m/s2", display_unit="mm/s2", start=1.0, min=1e-3, max=1e3, variability=fixed),
        Variable("jerk", "Float64", "parameter",
                 "Tangential jerk limit, also the curvature jerk limit v^3 kappa^2 [m/s3]",
                 unit=JERK_UNIT, start=100.0, min=1e-2, max=1e6, variability=fixed),
        Variable("centripetal_acceleration", "Float64", "parameter", "Centripetal acceleration limit v^2 kappa",
                 unit="m/s2", display_unit="mm/s2", start=1.0, min=1e-3, max=1e3, variability=fixed),
        Variable("chord_error", "Float64", "parameter", "Largest distance between the path and the chord "
                 "between two interpolation points", unit="m", display_unit="um", start=1e-6, min=1e-9,
                 max=1e-3, variability=fixed),
    ]
    for axis in "xyz":
        v.append(Variable(f"axis_acceleration_{axis}", "Float64", "parameter",
                          f"Acceleration limit of the {axis.upper()} axis", unit="m/s2", display_unit="mm/s2",
                          start=2.0, min=1e-3, max=1e4, variability=fixed))
    for axis in "xyz":
        v.append(Variable(f"axis_jerk_{axis}", "Float64", "parameter",
                          f"Jerk limit of the {axis.upper()} axis [m/s3]", unit=JERK_UNIT, start=300.0,
                          min=1e-2, max=1e7, variability=fixed))
    for axis in "xyz":
        v.append(Variable(f"start_{axis}", "Float64", "parameter",
                          f"Machine {axis.upper()} position of the tool before the program starts",
                          unit="m", display_unit="mm", start=0.0, min=-10.0, max=10.0, variability=fixed))
    for name in OFFSET_NAMES:
        for axis in "xyz":
            v.append(Variable(f"{name}_{axis}", "Float64", "parameter",
                              f"Work offset {name.upper()}: machine {axis.upper()} position of the work zero",
                              unit="m", display_unit="mm", start=0.0, min=-10.0, max=10.0, variability=fixed))
    v.append(Variable("rbf_width", "Float64", "parameter", "RBF network: width of the Gaussian units",
                      start=RBF_DEFAULTS["rbf_width"], min=1e-3, max=1e3, variability=fixed))
    for d in range(1, RBF_INPUTS + 1):
        v.append(Variable(f"rbf_offset_{d}", "Float64", "parameter",
                          f"RBF network: offset of input feature {d} (x = (feature - offset) * scale)",
                          start=RBF_DEFAULTS[f"rbf_offset_{d}"], min=-1e9, max=1e9, variability=fixed))
    for d in range(1, RBF_INPUTS + 1):
        v.append(Variable(f"rbf_scale_{d}", "Float64", "parameter", f"RBF network: scale of input feature {d}",
                          start=RBF_DEFAULTS[f"rbf_scale_{d}"], min=-1e9, max=1e9, variability=fixed))
    for j in range(1, RBF_HIDDEN + 1):
        for d in range(1, RBF_INPUTS + 1):
            v.append(Variable(f"rbf_center_{j}_{d}", "Float64", "parameter",
                              f"RBF network: coordinate {d} of the centre of unit {j}",
                              start=RBF_DEFAULTS[f"rbf_center_{j}_{d}"], min=-1e9, max=1e9, variability=fixed))
    for j in range(1, RBF_HIDDEN + 1):
        v.append(Variable(f"rbf_weight_{j}", "Float64", "parameter", f"RBF network: output weight of unit {j}",
                          start=RBF_DEFAULTS[f"rbf_weight_{j}"], min=-1e9, max=1e9, variability=fixed))
    v.append(Variable("rbf_bias", "Float64", "parameter", "RBF network: output bias",
                      start=RBF_DEFAULTS["rbf_bias"], min=-1e9, max=1e9, variability=fixed))
    v.append(Variable("feed_override", "Float64", "input", "Feed override (1 = 100 %; 0 = feed hold; not for G0)",
                      unit="1", display_unit="%", start=1.0, min=0.0, max=1.5))
    for axis in "xyz":
        v.append(Variable(axis, "Float64", "output", f"Machine {axis.upper()} position of the tool",
                          unit="m", display_unit="mm"))
    for axis in "xyz":
        v.append(Variable(f"{axis}_program", "Float64", "output",
                          f"Commanded {axis.upper()} position in work coordinates (before the work offset)",
                          unit="m", display_unit="mm"))
    for axis in "xyz":
        v.append(Variable(f"feed_velocity_{axis}", "Float64", "output", f"Feed velocity, {axis.upper()} component",
                          unit="m/s", display_unit="mm/min"))
    v += [
        Variable("feed", "Float64", "output", "Scheduled path speed", unit="m/s", display_unit="mm/min"),
        Variable("path_acceleration", "Float64", "output", "Scheduled tangential acceleration",
                 unit="m/s2", display_unit="mm/s2"),
        Variable("u", "Float64", "output", "NURBS parameter in NURBS blocks, else the fraction of the block done"),
        Variable("line_number", "Int32", "output", "Line of the part program being executed (0 before the start)"),
        Variable("block_number", "Int32", "output", "N word of the block being executed (0 without one)"),
        Variable("spindle_speed", "Float64", "output", "Commanded spindle speed (negative for M4, 0 when stopped)",
                 unit="rad/s", display_unit="rpm"),
        Variable("spindle_on", "Boolean", "output", "Spindle running (M3/M4)"),
        Variable("rapid", "Boolean", "output", "A rapid move (G0) is being executed"),
        Variable("finished", "Boolean", "output", "The program has ended: the tool is at rest on its last point"),
    ]
    return tuple(v)


INTERPOLATOR = ModelDefinition(
    identifier="Interpolator",
    description="CNC interpolator: G-code with NURBS blocks to tool positions every interpolation period, "
                "with look-ahead feedrate scheduling and Taylor/RBF/predictor-corrector parameter update",
    default_step_size=1e-3,
    default_stop_time=10.0,
    equations=None,
    variables=_variables(),
    native_outputs=tuple(n for n in (
        "x", "y", "z", "x_program", "y_program", "z_program", "feed_velocity_x", "feed_velocity_y",
        "feed_velocity_z", "feed", "path_acceleration", "u", "line_number", "block_number", "spindle_speed",
        "spindle_on",
        "rapid", "finished")),
)

OUTPUTS = tuple(v.name for v in INTERPOLATOR.of("output"))
PARAMETERS = tuple(v.name for v in INTERPOLATOR.of("parameter") if v.type != "String")


def default_parameters() -> dict[str, float]:
    return {v.name: float(v.start) for v in INTERPOLATOR.of("parameter") if v.type != "String"}


# ============================================================================================
# Parser (gcode_parser.c)
# ============================================================================================

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

MOVE_RAPID, MOVE_LINE, MOVE_ARC, MOVE_NURBS = 0, 1, 2, 3


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
            if pv not in (1.0, 2.0, 3.0, 4.0, 5.0):
                self.fail(number, f"a degree P of 1 to {MAX_DEGREE}, got P{seen['P'][1]}")
            degree = int(pv)
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


# ============================================================================================
# NURBS (nurbs.c)
# ============================================================================================

def find_span(knots: Sequence[float], n: int, p: int, u: float, lo: int, hi: int) -> int:
    """Knot span index i with knots[i] <= u < knots[i+1], restricted to [lo, hi] (u at or past the
    end of the range gives hi, before it lo)."""
    if u >= knots[hi + 1]:
        return hi
    if u <= knots[lo]:
        return lo
    low, high = lo, hi + 1
    mid = (low + high) // 2
    while u < knots[mid] or u >= knots[mid + 1]:
        if u < knots[mid]:
            high = mid
        else:
            low = mid
        mid = (low + high) // 2
    return mid


def basis_derivatives(knots: Sequence[float], i: int, u: float, p: int, nd: int) -> list[list[float]]:
    """B-spline basis functions of span i and their derivatives up to nd (Piegl & Tiller, A2.3)."""
    ndu = [[0.0] * (p + 1) for _ in range(p + 1)]
    left = [0.0] * (p + 1)
    right = [0.0] * (p + 1)
    ndu[0][0] = 1.0
    for j in range(1, p + 1):
        left[j] = u - knots[i + 1 - j]
        right[j] = knots[i + j] - u
        saved = 0.0
        for r in range(j):
            ndu[j][r] = right[r + 1] + left[j - r]
            temp = ndu[r][j - 1] / ndu[j][r]
            ndu[r][j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j][j] = saved
    ders = [[0.0] * (p + 1) for _ in range(nd + 1)]
    for j in range(p + 1):
        ders[0][j] = ndu[j][p]
    a = [[0.0] * (p + 1), [0.0] * (p + 1)]
    for r in range(p + 1):
        s1, s2 = 0, 1
        a[0][0] = 1.0
        for k in range(1, nd + 1):
            d = 0.0
            rk, pk = r - k, p - k
            if r >= k:
                a[s2][0] = a[s1][0] / ndu[pk + 1][rk]
                d = a[s2][0] * ndu[rk][pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a[s2][j] = (a[s1][j] - a[s1][j - 1]) / ndu[pk + 1][rk + j]
                d += a[s2][j] * ndu[rk + j][pk]
            if r <= pk:
                a[s2][k] = -a[s1][k - 1] / ndu[pk + 1][r]
                d += a[s2][k] * ndu[r][pk]
            ders[k][r] = d
            s1, s2 = s2, s1
    factor = float(p)
    for k in range(1, nd + 1):
        for j in range(p + 1):
            ders[k][j] *= factor
        factor *= float(p - k)
    return ders


_BINOMIAL = ((1.0,), (1.0, 1.0), (1.0, 2.0, 1.0), (1.0, 3.0, 3.0, 1.0))


class Nurbs:
    """A rational B-spline with homogeneous control points (w x, w y, w z, w)."""

    def __init__(self, curve: NurbsCurve):
        self.p = curve.degree
        self.n = len(curve.points) - 1
        self.knots = list(curve.knots)
        self.pw = [(w * x, w * y, w * z, w) for (x, y, z), w in zip(curve.points, curve.weights)]

    def evaluate(self, u: float, nd: int, lo: int, hi: int) -> list[list[float]]:
        """Point and derivatives d^k C / du^k, k = 0..nd (nd <= 3), span searched in [lo, hi]."""
        p = self.p
        i = find_span(self.knots, self.n, p, u, lo, hi)
        ders = basis_derivatives(self.knots, i, u, p, nd)
        aw = []
        for k in range(nd + 1):
            x = y = z = w = 0.0
            row = ders[k]
            for j in range(p + 1):
                c = self.pw[i - p + j]
                b = row[j]
                x += b * c[0]
                y += b * c[1]
                z += b * c[2]
                w += b * c[3]
            aw.append((x, y, z, w))
        out: list[list[float]] = []
        w0 = aw[0][3]
        for k in range(nd + 1):
            vx, vy, vz = aw[k][0], aw[k][1], aw[k][2]
            for m in range(1, k + 1):
                f = _BINOMIAL[k][m] * aw[m][3]
                prev = out[k - m]
                vx -= f * prev[0]
                vy -= f * prev[1]
                vz -= f * prev[2]
            out.append([vx / w0, vy / w0, vz / w0])
        return out

    def span_range(self, u0: float, u1: float) -> tuple[int, int]:
        """First and last span index with positive length inside [u0, u1]."""
        p, kn = self.p, self.knots
        lo = p
        while kn[lo + 1] <= u0:
            lo += 1
        hi = self.n
        while kn[hi] >= u1:
            hi -= 1
        return lo, hi


def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def arc_length_derivatives(d: list[list[float]]) -> tuple[float, list[float], list[float], list[float], float, float]:
    """From C, C', C'', C''' (u-derivatives): speed g = |C'|, unit tangent T, d2C/ds2, d3C/ds3 and
    du/ds, d2u/ds2."""
    d1, d2, d3 = d[1], d[2], d[3]
    gg = _dot(d1, d1)
    g = math.sqrt(gg)
    up = 1.0 / g
    d12 = _dot(d1, d2)
    upp = -d12 / (gg * gg)
    uppp = -(_dot(d2, d2) + _dot(d1, d3)) / (gg * gg * g) + 4.0 * d12 * d12 / (gg * gg * gg * g)
    t = [d1[0] * up, d1[1] * up, d1[2] * up]
    up2 = up * up
    k = [d2[a] * up2 + d1[a] * upp for a in range(3)]
    up3 = up2 * up
    kp = [d3[a] * up3 + 3.0 * d2[a] * up * upp + d1[a] * uppp for a in range(3)]
    return g, t, k, kp, up, upp


# Gauss-Legendre, 5 points on [-1, 1]
GL_NODES = (-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831, 0.9061798459386640)
GL_WEIGHTS = (0.2369268850561891, 0.4786286704993665, 0.5688888888888889, 0.4786286704993665,
              0.2369268850561891)


def gauss_length(curve: Nurbs, ua: float, ub: float, lo: int, hi: int) -> float:
    half = 0.5 * (ub - ua)
    mid = 0.5 * (ua + ub)
    total = 0.0
    for node, weight in zip(GL_NODES, GL_WEIGHTS):
        d = curve.evaluate(mid + half * node, 1, lo, hi)[1]
        total += weight * math.sqrt(_dot(d, d))
    return total * half


# ============================================================================================
# Path: moves, samples and velocity limits (path.c)
# ============================================================================================

COS_TURN = math.cos(0.02)            # NURBS sampling: tangent turn between neighbouring samples
CURVATURE_VARIATION = 0.02           # and relative curvature change (where the turn is significant)
SIGNIFICANT_TURN = 1e-3
MAX_SAMPLE_DEPTH = 40
MAX_SAMPLES = 2_000_000
INITIAL_SUBDIVISION = 4
CHORD_SAFETY = 0.95                   # the chord limit uses 95 % of chord_error (sampling margin)
TANGENT_TOLERANCE = 1e-12             # 1 - cos(angle) below which a junction is tangent
BIG = 1e300


@dataclass
class Limits:
    period: float
    acceleration: float
    jerk: float
    centripetal: float
    chord: float
    axis_acceleration: tuple[float, float, float]
    axis_jerk: tuple[float, float, float]
    max_feed: float


def limits_of(p: Mapping[str, float]) -> Limits:
    return Limits(p["period"], p["acceleration"], p["jerk"], p["centripetal_acceleration"], p["chord_error"],
                  tuple(p[f"axis_acceleration_{a}"] for a in "xyz"), tuple(p[f"axis_jerk_{a}"] for a in "xyz"),
                  max(p["max_feed"], p["rapid_feed"]))


def tangential_limits(lim: Limits, t: Sequence[float], curved: bool) -> tuple[float, float]:
    """Tangential acceleration and jerk limits where the unit tangent is t: the path limits, and each axis's
    share of its own limit (all of it on straight moves; on curves 1/2 of the acceleration, the rest is
    for the centripetal part, and 1/3 of the jerk, the rest for the curvature terms)."""
    at, jt = lim.acceleration, lim.jerk
    share_a = 0.5 if curved else 1.0
    share_j = (1.0 / 3.0) if curved else 1.0
    for i in range(3):
        ti = abs(t[i])
        if ti > 0.0:
            at = min(at, share_a * lim.axis_acceleration[i] / ti)
            jt = min(jt, share_j * lim.axis_jerk[i] / ti)
    return at, jt


def curvature_limit(lim: Limits, kappa: float, k: Sequence[float], kp: Sequence[float], at: float) -> float:
    """Highest path speed allowed by the chord error, the centripetal acceleration, the curvature jerk
    and the axes' shares of acceleration and jerk, where the curvature is kappa, d2C/ds2 = k and
    d3C/ds3 = kp, with tangential acceleration limit at."""
    v = BIG
    if kappa > 0.0:
        rho = 1.0 / kappa
        delta = CHORD_SAFETY * lim.chord
        if delta < rho:
            v = min(v, 2.0 * math.sqrt(delta * (2.0 * rho - delta)) / lim.period)
        else:
            v = min(v, 2.0 * rho / lim.period)
        v = min(v, math.sqrt(lim.centripetal / kappa))
        v = min(v, math.cbrt(lim.jerk / (kappa * kappa)))
    for i in range(3):
        ki, kpi = abs(k[i]), abs(kp[i])
        if ki > 0.0:
            v = min(v, math.sqrt(0.5 * lim.axis_acceleration[i] / ki))
            v = min(v, lim.axis_jerk[i] / (9.0 * at * ki))
        if kpi > 0.0:
            v = min(v, math.cbrt(lim.axis_jerk[i] / (3.0 * kpi)))
    return v


def junction_limit(lim: Limits, ta, ka, tb, kb) -> float:
    """Speed allowed where tangent ta / curvature vector ka (end of one move) meet tb / kb: a corner makes
    the velocity jump by v |tb - ta| within one period, a curvature change the acceleration by v^2 |kb - ka|."""
    v = BIG
    period = lim.period
    if _dot(ta, tb) < 1.0 - TANGENT_TOLERANCE:
        dt = [tb[i] - ta[i] for i in range(3)]
        norm = math.sqrt(_dot(dt, dt))
        v = min(v, lim.acceleration * period / norm, lim.jerk * period * period / norm)
        for i in range(3):
            di = abs(dt[i])
            if di > 0.0:
                v = min(v, 0.5 * lim.axis_acceleration[i] * period / di,
                        lim.axis_jerk[i] * period * period / (3.0 * di))
    dk = [kb[i] - ka[i] for i in range(3)]
    norm = math.sqrt(_dot(dk, dk))
    if norm > 0.0:
        v = min(v, math.sqrt(lim.jerk * period / norm))
        for i in range(3):
            di = abs(dk[i])
            if di > 0.0:
                v = min(v, math.sqrt(lim.axis_jerk[i] * period / (3.0 * di)))
    return v


@dataclass
class Geometry:
    """Tangent, curvature vector, its s-derivative and the limits at a point of a move."""

    t: list[float]
    k: list[float]
    kp: list[float]


def line_geometry(move: Move) -> tuple[list[float], float]:
    d = [move.end[i] - move.start[i] for i in range(3)]
    length = math.sqrt(_dot(d, d))
    return [d[i] / length for i in range(3)], length


class ArcShape:
    """Helical arc: centre c, plane axes (a, b, normal), angle theta0 + lam * sweep, radius r0..r1,
    normal coordinate c_n + lam * height; lam = s / length."""

    def __init__(self, move: Move):
        self.m = move
        rm = 0.5 * (move.r0 + move.r1)
        planar = rm * move.sweep
        self.length = math.sqrt(planar * planar + move.height * move.height)
        self.omega = abs(move.sweep) / self.length
        self.rm = rm

    def point(self, lam: float) -> list[float]:
        m = self.m
        if lam >= 1.0:
            return list(m.end)
        theta = m.theta0 + lam * m.sweep
        r = m.r0 + lam * (m.r1 - m.r0)
        ia, ib, inormal = m.axes
        p = [0.0, 0.0, 0.0]
        p[ia] = m.center[ia] + r * math.cos(theta)
        p[ib] = m.center[ib] + r * math.sin(theta)
        p[inormal] = m.center[inormal] + lam * m.height
        return p

    def tangent(self, lam: float) -> list[float]:
        m = self.m
        theta = m.theta0 + lam * m.sweep
        r = m.r0 + lam * (m.r1 - m.r0)
        c, s = math.cos(theta), math.sin(theta)
        ia, ib, inormal = m.axes
        d = [0.0, 0.0, 0.0]
        d[ia] = -r * s * m.sweep + (m.r1 - m.r0) * c
        d[ib] = r * c * m.sweep + (m.r1 - m.r0) * s
        d[inormal] = m.height
        norm = math.sqrt(_dot(d, d))
        return [d[i] / norm for i in range(3)]

    def geometry_bound(self) -> Geometry:
        """Per-axis magnitudes bounding |T_i|, |k_i|, |k'_i| over the whole arc (in-plane axes: the circle's
        extremes; normal axis: the helix's constant climb)."""
        m = self.m
        ia, ib, inormal = m.axes
        rw = self.rm * self.omega
        t, k, kp = [0.0] * 3, [0.0] * 3, [0.0] * 3
        for i in (ia, ib):
            t[i] = min(1.0, rw)
            k[i] = rw * self.omega
            kp[i] = rw * self.omega * self.omega
        t[inormal] = abs(m.height) / self.length
        return Geometry(t, k, kp)

    def end_geometry(self, lam: float) -> Geometry:
        """Tangent and curvature vector at lam (for junctions; helix: k = -r w^2 (cos, sin) in the plane)."""
        m = self.m
        theta = m.theta0 + lam * m.sweep
        ia, ib, inormal = m.axes
        t = self.tangent(lam)
        w2 = self.omega * self.omega
        r = m.r0 + lam * (m.r1 - m.r0)
        k = [0.0, 0.0, 0.0]
        k[ia] = -r * w2 * math.cos(theta)
        k[ib] = -r * w2 * math.sin(theta)
        return Geometry(t, k, [0.0, 0.0, 0.0])


@dataclass
class Path:
    """The program as the schedule sees it: moves with their start s and length, and nodes along s.

    Node k: position s, hard speed cap vh (geometry and dynamics), the moves left and right of it (-1 at
    the ends; equal inside a move), station flag. Interval k (node k to k+1): its move, tangential limits
    and the hard cap of its interior (a peak between the two nodes)."""

    program: Program
    lim: Limits
    move_s: list[float]
    move_length: list[float]
    move_cap: list[float]           # constant hard cap of lines/arcs (BIG for lines)
    move_span: list[tuple[int, int]]
    curves: list[Nurbs]
    arcs: dict[int, ArcShape]
    node_s: list[float] = field(default_factory=list)
    node_vh: list[float] = field(default_factory=list)
    node_left: list[int] = field(default_factory=list)
    node_right: list[int] = field(default_factory=list)
    station: list[int] = field(default_factory=list)
    int_move: list[int] = field(default_factory=list)
    int_at: list[float] = field(default_factory=list)
    int_jt: list[float] = field(default_factory=list)
    int_cap: list[float] = field(default_factory=list)
    total: float = 0.0


class PathError(ValueError):
    pass


def _nurbs_samples(curve: Nurbs, lim: Limits, u0: float, u1: float, lo: int, hi: int, line: int, file: str):
    """Adaptive samples of one NURBS move: lists (u, s, vlc, at, jt, geometry at the ends)."""
    us: list[float] = []
    ss: list[float] = []
    vl: list[float] = []
    ats: list[float] = []
    jts: list[float] = []
    first_geometry = last_geometry = None

    def point(u: float):
        d = curve.evaluate(u, 3, lo, hi)
        g, t, k, kp, _, _ = arc_length_derivatives(d)
        if not (g > 0.0) or not math.isfinite(g):
            raise PathError(f"{file} line {line}: the NURBS block has a zero tangent near u = {u:.9g} "
                            "(repeated control points?)")
        kappa = math.sqrt(_dot(k, k))
        at, jt = tangential_limits(lim, t, True)
        v = curvature_limit(lim, kappa, k, kp, at)
        return t, kappa, v, at, jt, d[0]

    def push(u: float, s: float, info) -> None:
        if len(us) >= MAX_SAMPLES:
            raise PathError(f"{file} line {line}: the NURBS block needs more than {MAX_SAMPLES} samples")
        us.append(u)
        ss.append(s)
        vl.append(info[2])
        ats.append(info[3])
        jts.append(info[4])

    def refine(ua: float, ia, ub: float, ib, s_a: float, depth: int) -> float:
        """Samples in (ua, ub] (ua already pushed with s_a); returns s at ub."""
        um = 0.5 * (ua + ub)
        im = point(um)
        e = [ib[5][0] - ia[5][0], ib[5][1] - ia[5][1], ib[5][2] - ia[5][2]]
        chord = math.sqrt(_dot(e, e))
        kmax = max(ia[1], im[1], ib[1])
        kmin = min(ia[1], im[1], ib[1])
        split = (_dot(ia[0], im[0]) < COS_TURN or _dot(im[0], ib[0]) < COS_TURN
                 or (kmax * chord > SIGNIFICANT_TURN and kmax - kmin > CURVATURE_VARIATION * kmax))
        if split and depth < MAX_SAMPLE_DEPTH and um > ua and um < ub:
            s_m = refine(ua, ia, um, im, s_a, depth + 1)
            return refine(um, im, ub, ib, s_m, depth + 1)
        s_b = s_a + gauss_length(curve, ua, ub, lo, hi)
        push(ub, s_b, ib)
        return s_b

    kn = curve.knots
    info0 = point(u0)
    push(u0, 0.0, info0)
    s = 0.0
    for span in range(lo, hi + 1):
        a, b = max(kn[span], u0), min(kn[span + 1], u1)
        if not b > a:
            continue
        ua, ia = a, (info0 if a == u0 else point(a))
        for j in range(1, INITIAL_SUBDIVISION + 1):
            ub = a + (b - a) * j / INITIAL_SUBDIVISION if j < INITIAL_SUBDIVISION else b
            ib = point(ub)
            s = refine(ua, ia, ub, ib, s, 0)
            ua, ia = ub, ib
    # geometry at both ends for the junctions (left-sided derivatives at u1: span hi)
    d0 = curve.evaluate(u0, 3, lo, lo)
    _, t0, k0, kp0, _, _ = arc_length_derivatives(d0)
    d1 = curve.evaluate(u1, 3, hi, hi)
    _, t1, k1, kp1, _, _ = arc_length_derivatives(d1)
    first_geometry = Geometry(t0, k0, kp0)
    last_geometry = Geometry(t1, k1, kp1)
    return us, ss, vl, ats, jts, first_geometry, last_geometry


def conservative_limits(ss: Sequence[float], vl: Sequence[float], lim: Limits) -> list[float]:
    """Each sample's limit lowered to the lowest of its neighbours and of every sample within the step the tool
    can take there (min(limit, max feed) * period): a step spans all of them, and its chord error and
    accelerations follow the sharpest point it spans."""
    n = len(vl)
    vc = []
    for i in range(n):
        v = min(vl[max(0, i - 1)], vl[i], vl[min(n - 1, i + 1)])
        window = min(vl[i], lim.max_feed) * lim.period
        j = i - 2
        while j >= 0 and ss[i] - ss[j] <= window:
            v = min(v, vl[j])
            j -= 1
        j = i + 2
        while j < n and ss[j] - ss[i] <= window:
            v = min(v, vl[j])
            j += 1
        vc.append(v)
    return vc


def build_path(program: Program, p: Mapping[str, float]) -> Path:
    lim = limits_of(p)
    curves = [Nurbs(c) for c in program.curves]
    path = Path(program, lim, [], [], [], [], curves, {})
    ends: list[tuple[Geometry, Geometry]] = []
    s = 0.0
    samples = []  # per move: list of (local s, vlc) for NURBS; None else
    for index, move in enumerate(program.moves):
        path.move_s.append(s)
        if move.kind in (MOVE_RAPID, MOVE_LINE):
            t, length = line_geometry(move)
            at, jt = tangential_limits(lim, t, False)
            zero = [0.0, 0.0, 0.0]
            geometry = Geometry(t, zero, zero)
            ends.append((geometry, geometry))
            path.move_cap.append(BIG)
            path.move_span.append((0, 0))
            samples.append(([0.0, length], [BIG, BIG], [at, at], [jt, jt]))
        elif move.kind == MOVE_ARC:
            arc = ArcShape(move)
            path.arcs[index] = arc
            length = arc.length
            bound = arc.geometry_bound()
            at, jt = tangential_limits(lim, bound.t, True)
            kappa = arc.rm * arc.omega * arc.omega
            v = curvature_limit(lim, kappa, bound.k, bound.kp, at)
            ends.append((arc.end_geometry(0.0), arc.end_geometry(1.0)))
            path.move_cap.append(v)
            path.move_span.append((0, 0))
            samples.append(([0.0, length], [v, v], [at, at], [jt, jt]))
        else:
            curve = curves[move.curve]
            lo, hi = curve.span_range(move.u0, move.u1)
            path.move_span.append((lo, hi))
            us, ss, vl, ats, jts, g0, g1 = _nurbs_samples(curve, lim, move.u0, move.u1, lo, hi, move.line,
                                                          program.file)
            length = ss[-1]
            vc = conservative_limits(ss, vl, lim)
            ends.append((g0, g1))
            path.move_cap.append(BIG)
            samples.append((ss, vc, ats, jts))
        path.move_length.append(length)
        s += length
    path.total = s
    # nodes
    n_moves = len(program.moves)
    for index in range(n_moves):
        ss, vc, ats, jts = samples[index]
        base = path.move_s[index]
        count = len(ss)
        for j in range(count):
            if j == 0:
                if index == 0:
                    path.node_s.append(base)
                    path.node_vh.append(0.0)
                    path.node_left.append(-1)
                    path.node_right.append(index)
                    path.station.append(1)
                else:
                    ga = ends[index - 1][1]
                    gb = ends[index][0]
                    v = junction_limit(lim, ga.t, ga.k, gb.t, gb.k)
                    prev_cap = samples[index - 1][1][-1]
                    v = min(v, prev_cap, vc[0])
                    path.node_s.append(base)
                    path.node_vh.append(v)
                    path.node_left.append(index - 1)
                    path.node_right.append(index)
                    path.station.append(0)
            elif j == count - 1:
                if index == n_moves - 1:
                    path.node_s.append(base + ss[j])
                    path.node_vh.append(0.0)
                    path.node_left.append(index)
                    path.node_right.append(-1)
                    path.station.append(1)
                # else: the next move's first node is this junction
            else:
                path.node_s.append(base + ss[j])
                path.node_vh.append(vc[j])
                path.node_left.append(index)
                path.node_right.append(index)
                path.station.append(0)
            if j < count - 1:
                path.int_move.append(index)
                path.int_at.append(min(ats[j], ats[j + 1]))
                path.int_jt.append(min(jts[j], jts[j + 1]))
                if program.moves[index].kind == MOVE_NURBS:
                    path.int_cap.append(max(vc[j], vc[j + 1]))
                else:
                    path.int_cap.append(path.move_cap[index])
    if n_moves and path.node_s[-1] != path.total:
        path.node_s[-1] = path.total
    return path


# ============================================================================================
# Schedule (feed_schedule.c): look-ahead over the whole program, jerk-limited S-curves
# ============================================================================================

BISECTIONS = 60
VIOLATION_TOLERANCE = 1e-9


def s_curve_time(dv: float, a: float, j: float) -> float:
    """Duration of a jerk-limited velocity change dv >= 0 with zero acceleration at both ends."""
    if dv >= a * a / j:
        return dv / a + a / j
    return 2.0 * math.sqrt(dv / j)


def s_curve_distance(v0: float, v1: float, a: float, j: float) -> float:
    return 0.5 * (v0 + v1) * s_curve_time(abs(v1 - v0), a, j)


def reach_up(v0: float, length: float, a: float, j: float) -> float:
    """Highest velocity reachable from v0 (zero acceleration) over length (zero acceleration at the end)."""
    if length <= 0.0:
        return v0
    p = 2.0 * v0
    q = length * math.sqrt(j)
    if p == 0.0:
        y = math.cbrt(q)
    else:
        y = 2.0 * math.sqrt(p / 3.0) * math.sinh(math.asinh(1.5 * q / p * math.sqrt(3.0 / p)) / 3.0)
    x = y * y
    if x >= a * a / j:
        qa = 0.5 / a
        qb = v0 / a + 0.5 * a / j
        qc = v0 * a / j - length
        x = -2.0 * qc / (qb + math.sqrt(qb * qb - 4.0 * qa * qc))
    return v0 + x


def _bisect_fitting(fits: Callable[[float], bool], good: float, bad: float) -> float:
    """Narrow [good, bad] (fits(good) holds, fits(bad) does not, fits changes once between them) by
    BISECTIONS halvings and return the end that fits."""
    for _ in range(BISECTIONS):
        mid = 0.5 * (good + bad)
        if fits(mid):
            good = mid
        else:
            bad = mid
    return good


def lowest_feasible(v_high: float, v_low: float, length: float, a: float, j: float) -> float:
    """The lowest velocity in [v_low, v_high] to which one can slow down from v_high over length."""
    if s_curve_distance(v_low, v_high, a, j) <= length:
        return v_low
    return _bisect_fitting(lambda v: s_curve_distance(v, v_high, a, j) <= length, v_high, v_low)


def segment_peak(va: float, vb: float, length: float, cap: float, a: float, j: float) -> float:
    """Cruise velocity of a segment va -> vp -> vb of the given length: the highest up to cap when cap is
    above both ends, else the lowest from cap up (the segment starts or ends above its cap)."""

    def fits(peak: float) -> bool:
        return s_curve_distance(va, peak, a, j) + s_curve_distance(peak, vb, a, j) <= length

    top = max(va, vb)
    if cap >= top:
        return cap if fits(cap) else _bisect_fitting(fits, top, cap)
    floor = max(cap, 0.0)
    return floor if fits(floor) else _bisect_fitting(fits, top, floor)


def s_curve_position(v0: float, v1: float, a: float, j: float, w: float) -> float:
    """Distance from the start of the S-curve v0 -> v1 at which the velocity is w (between v0 and v1)."""
    dv = abs(v1 - v0)
    if dv <= 0.0:
        return 0.0
    if dv >= a * a / j:
        t1 = a / j
        t2 = dv / a - a / j
    else:
        t1 = math.sqrt(dv / j)
        t2 = 0.0
    total = 2.0 * t1 + t2
    delta = abs(w - v0)
    d1 = 0.5 * j * t1 * t1
    if delta <= d1:
        t = math.sqrt(2.0 * delta / j)
        dx = j * t * t * t / 6.0
    elif delta <= d1 + j * t1 * t2:
        tau = (delta - d1) / (j * t1)
        t = t1 + tau
        dx = j * t1 * t1 * t1 / 6.0 + d1 * tau + 0.5 * j * t1 * tau * tau
    else:
        r = math.sqrt(2.0 * max(dv - delta, 0.0) / j)
        t = total - r
        dx = 0.5 * dv * total - (dv * r - j * r * r * r / 6.0)
    return v0 * t + dx if v1 >= v0 else v0 * t - dx


@dataclass
class Segment:
    s0: float
    length: float
    va: float
    vp: float
    vb: float
    a: float
    j: float
    cap: float
    soft_cap: float
    first: int      # first interval
    last: int       # last interval (inclusive)


@dataclass
class Piece:
    t: float
    s: float
    v: float
    a: float
    j: float


class Schedule:
    """Stations (nodes with zero acceleration), their velocities and the S-curve pieces in between."""

    def __init__(self, path: Path, max_feed: float, rapid_feed: float):
        self.path = path
        self.max_feed = max_feed
        self.rapid_feed = rapid_feed
        self.override = 1.0
        self.pieces: list[Piece] = []
        self.end_time = 0.0
        self.hold = False

    def soft(self, move: int) -> float:
        if move < 0:
            return BIG
        m = self.path.program.moves[move]
        if m.kind == MOVE_RAPID:
            return self.rapid_feed
        return min(m.feed * self.override, self.max_feed)

    def node_cap(self, k: int) -> float:
        path = self.path
        return min(path.node_vh[k], self.soft(path.node_left[k]), self.soft(path.node_right[k]))

    def interval_at(self, s: float) -> int:
        """Interval containing s (the last one whose start node is <= s)."""
        ns = self.path.node_s
        lo, hi = 0, len(ns) - 2
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if ns[mid] <= s:
                lo = mid
            else:
                hi = mid - 1
        return lo

    def segments(self, s_start: float, first_interval: int) -> list[Segment]:
        path = self.path
        out: list[Segment] = []
        n_int = len(path.int_move)
        i = first_interval
        s0 = s_start
        while i < n_int:
            a = j = BIG
            cap = 0.0
            soft = BIG
            first = i
            while True:
                m = path.int_move[i]
                a = min(a, path.int_at[i])
                j = min(j, path.int_jt[i])
                sm = self.soft(m)
                soft = min(soft, sm)
                cap = max(cap, min(sm, path.int_cap[i]))
                i += 1
                if i >= n_int or path.station[i]:
                    break
            end = path.node_s[i] if i <= n_int else path.total
            out.append(Segment(s0, end - s0, 0.0, 0.0, 0.0, a, j, cap, soft, first, i - 1))
            s0 = end
        return out

    def velocities(self, segs: list[Segment], v_start: float) -> None:
        """Station velocities: backward envelope over every cap, then forward from v_start, raised
        where the start is above new (soft) caps and cannot slow down in time."""
        path = self.path
        n = len(segs)
        caps = [0.0] * (n + 1)
        for k in range(1, n):
            caps[k] = self.node_cap(segs[k].first)
        caps[n] = 0.0
        b = [0.0] * (n + 1)
        for k in range(n - 1, 0, -1):
            b[k] = min(caps[k], reach_up(b[k + 1], segs[k].length, segs[k].a, segs[k].j))
        b[0] = BIG
        v = [0.0] * (n + 1)
        v[0] = v_start
        for k in range(1, n + 1):
            sg = segs[k - 1]
            vk = min(b[k], reach_up(v[k - 1], sg.length, sg.a, sg.j))
            if vk < v[k - 1] and s_curve_distance(vk, v[k - 1], sg.a, sg.j) > sg.length:
                vk = lowest_feasible(v[k - 1], vk, sg.length, sg.a, sg.j)
            v[k] = vk
        for k in range(n):
            segs[k].va = v[k]
            segs[k].vb = v[k + 1]
            segs[k].vp = segment_peak(v[k], v[k + 1], segs[k].length, segs[k].cap, segs[k].a, segs[k].j)
        del path

    def violations(self, segs: list[Segment]) -> list[int]:
        """Nodes to make stations: per segment the violated node with the lowest cap, or the two ends of the
        interval holding a peak above that interval's cap."""
        path = self.path
        add: list[int] = []
        for sg in segs:
            hard_only = sg.va > sg.soft_cap * (1.0 + VIOLATION_TOLERANCE) or sg.vb > sg.soft_cap * (
                1.0 + VIOLATION_TOLERANCE)
            da = s_curve_distance(sg.va, sg.vp, sg.a, sg.j)
            db = s_curve_distance(sg.vp, sg.vb, sg.a, sg.j)
            cruise = sg.length - da - db
            worst, worst_cap = -1, BIG
            for k in range(sg.first + 1, sg.last + 1):
                allowed = path.node_vh[k] if hard_only else self.node_cap(k)
                w = allowed * (1.0 + VIOLATION_TOLERANCE)
                x = path.node_s[k] - sg.s0
                if x <= da:
                    if sg.vp >= sg.va:
                        bad = w < sg.va or (w < sg.vp and x > s_curve_position(sg.va, sg.vp, sg.a, sg.j, w))
                    else:
                        bad = w < sg.vp or (w < sg.va and x < s_curve_position(sg.va, sg.vp, sg.a, sg.j, w))
                elif x <= da + cruise:
                    bad = w < sg.vp
                else:
                    y = x - da - cruise
                    if sg.vb >= sg.vp:
                        bad = w < sg.vp or (w < sg.vb and y > s_curve_position(sg.vp, sg.vb, sg.a, sg.j, w))
                    else:
                        bad = w < sg.vb or (w < sg.vp and y < s_curve_position(sg.vp, sg.vb, sg.a, sg.j, w))
                if bad and allowed < worst_cap:
                    worst, worst_cap = k, allowed
            if worst >= 0:
                add.append(worst)
                continue
            if sg.vp > sg.va and sg.vp > sg.vb and sg.last > sg.first:
                # the peak region [da, da + cruise]: if no node lies in it, its interval's cap must hold
                lo_s, hi_s = sg.s0 + da, sg.s0 + da + cruise
                i = sg.first
                while i < sg.last and path.node_s[i + 1] <= lo_s:
                    i += 1
                if path.node_s[i + 1] >= hi_s or i == sg.last:
                    m = path.int_move[i]
                    cap = path.int_cap[i] if hard_only else min(self.soft(m), path.int_cap[i])
                    if sg.vp > cap * (1.0 + VIOLATION_TOLERANCE):
                        for node in (i, i + 1):
                            if not path.station[node]:
                                add.append(node)
        return add

    def plan(self, s_start: float, v_start: float, t_start: float, override: float) -> None:
        """Schedule from (s_start, v_start, zero acceleration) at t_start to the end of the program."""
        path = self.path
        self.override = override
        self.hold = False
        if not path.int_move:
            self.pieces = [Piece(t_start, s_start, 0.0, 0.0, 0.0)]
            self.end_time = t_start
            return
        first = self.interval_at(s_start)
        while True:
            segs = self.segments(s_start, first)
            self.velocities(segs, v_start)
            add = self.violations(segs)
            if not add:
                break
            for node in add:
                path.station[node] = 1
        self.pieces = self.make_pieces(segs, t_start)

    def make_pieces(self, segs: list[Segment], t: float) -> list[Piece]:
        pieces: list[Piece] = []
        for sg in segs:
            s = sg.s0
            if sg.length <= 0.0:
                continue
            da = s_curve_distance(sg.va, sg.vp, sg.a, sg.j)
            db = s_curve_distance(sg.vp, sg.vb, sg.a, sg.j)
            cruise = max(sg.length - da - db, 0.0)
            t, s = _s_curve_pieces(pieces, t, s, sg.va, sg.vp, sg.a, sg.j)
            if cruise > 0.0:
                if sg.vp <= 0.0:
                    pieces.append(Piece(t, s, 0.0, 0.0, 0.0))
                    self.hold = True
                    self.end_time = math.inf
                    return pieces
                pieces.append(Piece(t, s, sg.vp, 0.0, 0.0))
                t += cruise / sg.vp
                s += cruise
            t, s = _s_curve_pieces(pieces, t, s, sg.vp, sg.vb, sg.a, sg.j)
        pieces.append(Piece(t, self.path.total, 0.0, 0.0, 0.0))
        self.end_time = t
        return pieces


def _s_curve_pieces(pieces: list[Piece], t: float, s: float, v0: float, v1: float, a: float,
                    j: float) -> tuple[float, float]:
    dv = v1 - v0
    if dv == 0.0:
        return t, s
    sign = 1.0 if dv > 0.0 else -1.0
    dv = abs(dv)
    if dv >= a * a / j:
        t1 = a / j
        t2 = dv / a - a / j
    else:
        t1 = math.sqrt(dv / j)
        t2 = 0.0
    jerk = sign * j
    am = jerk * t1
    v = v0
    # phase 1
    pieces.append(Piece(t, s, v, 0.0, jerk))
    s += v * t1 + jerk * t1 * t1 * t1 / 6.0
    v += 0.5 * jerk * t1 * t1
    t += t1
    if t2 > 0.0:
        pieces.append(Piece(t, s, v, am, 0.0))
        s += v * t2 + 0.5 * am * t2 * t2
        v += am * t2
        t += t2
    pieces.append(Piece(t, s, v, am, -jerk))
    s += v * t1 + 0.5 * am * t1 * t1 - jerk * t1 * t1 * t1 / 6.0
    t += t1
    return t, s


# ============================================================================================
# Parameter update (param_update.c)
# ============================================================================================

@dataclass
class Rbf:
    width: float
    offset: tuple[float, float, float, float]
    scale: tuple[float, float, float, float]
    centers: tuple[tuple[float, float, float, float], ...]
    weights: tuple[float, ...]
    bias: float


def rbf_of(p: Mapping[str, float]) -> Rbf:
    return Rbf(p["rbf_width"], tuple(p[f"rbf_offset_{d}"] for d in range(1, 5)),
               tuple(p[f"rbf_scale_{d}"] for d in range(1, 5)),
               tuple(tuple(p[f"rbf_center_{j}_{d}"] for d in range(1, 5)) for j in range(1, 6)),
               tuple(p[f"rbf_weight_{j}"] for j in range(1, 6)), p["rbf_bias"])


def rbf_features(u2: float, u1: float, u0: float, length: float, ua: float, ub: float) -> tuple[float, ...]:
    """The network's raw inputs from u(i-2), u(i-1), u(i) and the step: the two parameter steps behind,
    the position in the block and the step length."""
    return (u0 - u2, u0 - u1, (u0 - ua) / (ub - ua), length)


def rbf_output(net: Rbf, raw: Sequence[float]) -> float:
    x = [(raw[d] - net.offset[d]) * net.scale[d] for d in range(4)]
    inv = 0.5 / (net.width * net.width)
    y = net.bias
    for c, w in zip(net.centers, net.weights):
        e0, e1, e2, e3 = x[0] - c[0], x[1] - c[1], x[2] - c[2], x[3] - c[3]
        y += w * math.exp(-(e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3) * inv)
    return y


@dataclass
class NurbsState:
    """Per NURBS move: parameter history, the point and derivatives at u, the previous step's u''."""

    move: int = -1
    u: float = 0.0
    u1: float = 0.0
    u2: float = 0.0
    count: int = 0
    s_done: float = 0.0
    s_actual: float = 0.0
    point: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    d1: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    d2: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    upp_prev: float = 0.0
    chord_prev: float = 0.0


def taylor_step(st: NurbsState, length: float, order: int) -> tuple[float, float, float]:
    """(du, u', u'') of the Taylor expansion of u(s) at the current point."""
    d1, d2 = st.d1, st.d2
    gg = _dot(d1, d1)
    g = math.sqrt(gg)
    up = 1.0 / g
    upp = -_dot(d1, d2) / (gg * gg)
    if order == 1:
        return length * up, up, upp
    return length * up + 0.5 * upp * length * length, up, upp


def predict(st: NurbsState, length: float, predictor: int, net: Rbf, ua: float, ub: float) -> float:
    if predictor == METHOD_TAYLOR1:
        return taylor_step(st, length, 1)[0]
    du, up, upp = taylor_step(st, length, 2)
    if predictor == METHOD_TAYLOR2 or st.count < 3:
        return du
    # history-augmented Taylor: u''' from the change of u'' over the previous chord, then the network
    uppp = (upp - st.upp_prev) / st.chord_prev if st.chord_prev > 0.0 else 0.0
    base = du + uppp * length * length * length / 6.0
    y = rbf_output(net, rbf_features(st.u2, st.u1, st.u, length, ua, ub))
    return base * (1.0 + y)


# ============================================================================================
# Interpolator (interpolator.c)
# ============================================================================================

MAX_NEWTON = 8


class Interpolator:
    """The FMU's behaviour, tick by tick (one tick = one interpolation period)."""

    def __init__(self, text: str, parameters: Mapping[str, float], file: str = "program.nc"):
        p = {**default_parameters(), **parameters}
        self.p = p
        self.program = parse_program(text, p, file)
        self.path = build_path(self.program, p)
        self.schedule = Schedule(self.path, p["max_feed"], p["rapid_feed"])
        self.period = p["period"]
        self.method = int(p["method"])
        self.predictor = int(p["corrector_predictor"]) if self.method == METHOD_CORRECTOR else self.method
        self.tolerance = p["corrector_tolerance"]
        self.feedback = bool(p["arc_length_feedback"])
        self.net = rbf_of(p)
        self.tick_count = 0
        self.piece = 0
        self.move = 0
        self.s = 0.0
        self.v = 0.0
        self.a = 0.0
        self.nurbs = NurbsState()
        self.override = None
        start = self.program.start
        self.out = self.initial_outputs(p)
        self.position = list(start)
        self.finished = False

    @staticmethod
    def initial_outputs(p: Mapping[str, float]) -> dict[str, float]:
        x, y, z = p["start_x"], p["start_y"], p["start_z"]
        return {"x": x, "y": y, "z": z, "x_program": x - p["g54_x"], "y_program": y - p["g54_y"],
                "z_program": z - p["g54_z"], "feed_velocity_x": 0.0, "feed_velocity_y": 0.0,
                "feed_velocity_z": 0.0, "feed": 0.0, "path_acceleration": 0.0, "u": 0.0, "line_number": 0.0,
                "block_number": 0.0, "spindle_speed": 0.0, "spindle_on": 0.0, "rapid": 0.0, "finished": 0.0}

    # -- schedule --
    def replan_point(self, t_now: float) -> tuple[float, float, float, int]:
        """(t, s, v, piece index) of the first moment at or after t_now with zero acceleration."""
        pieces = self.schedule.pieces
        k = self.piece
        pc = pieces[k]
        if pc.a == 0.0 and pc.j == 0.0:
            tau = t_now - pc.t
            return t_now, pc.s + pc.v * tau, pc.v, k
        k += 1
        while k < len(pieces) and not (pieces[k].a == 0.0):
            k += 1
        pc = pieces[k]
        return pc.t, pc.s, pc.v, k

    def set_override(self, override: float, t_now: float) -> None:
        if self.override is not None and override == self.override:
            return
        if self.override is None:
            self.override = override
            self.schedule.plan(0.0, 0.0, 0.0, override)
            self.piece = 0
            return
        self.override = override
        if self.finished:
            return
        t_r, s_r, v_r, k = self.replan_point(t_now)
        kept = self.schedule.pieces[self.piece:k]
        self.schedule.plan(s_r, v_r, t_r, override)
        self.schedule.pieces = kept + self.schedule.pieces
        self.piece = 0

    # -- one tick --
    def tick(self) -> None:
        self.tick_count += 1
        t = self.tick_count * self.period
        sch = self.schedule
        pieces = sch.pieces
        while self.piece + 1 < len(pieces) and pieces[self.piece + 1].t <= t:
            self.piece += 1
        pc = pieces[self.piece]
        tau = t - pc.t
        s = pc.s + tau * (pc.v + tau * (0.5 * pc.a + tau * pc.j / 6.0))
        v = pc.v + tau * (pc.a + 0.5 * tau * pc.j)
        a = pc.a + tau * pc.j
        total = self.path.total
        done = (not sch.hold) and t >= sch.end_time
        if done or s >= total:
            s = total
        if done:
            v = a = 0.0
        if s < self.s:
            s = self.s
        if v < 0.0:
            v = 0.0
        self.s, self.v, self.a = s, v, a
        self.finished = done
        self.update_outputs()

    def update_outputs(self) -> None:
        prog = self.program
        out = self.out
        if not prog.moves:
            self.finished = True
            self.set_final(out)
            return
        moves = prog.moves
        s = self.s
        while self.move + 1 < len(moves) and s > self.path.move_s[self.move] + self.path.move_length[self.move]:
            self.move += 1
        if self.finished:
            self.set_final(out)
            return
        m = moves[self.move]
        local = s - self.path.move_s[self.move]
        length = self.path.move_length[self.move]
        lam = local / length
        if lam > 1.0:
            lam = 1.0
        if lam < 0.0:
            lam = 0.0
        if m.kind in (MOVE_RAPID, MOVE_LINE):
            if lam >= 1.0:
                pos = list(m.end)
            else:
                pos = [m.start[i] + lam * (m.end[i] - m.start[i]) for i in range(3)]
            d = [m.end[i] - m.start[i] for i in range(3)]
            norm = math.sqrt(_dot(d, d))
            tangent = [d[i] / norm for i in range(3)]
            u = lam
        elif m.kind == MOVE_ARC:
            arc = self.path.arcs[self.move]
            pos = arc.point(lam)
            tangent = arc.tangent(lam)
            u = lam
        else:
            pos, tangent, u = self.step_nurbs(local, length)
        self.position = pos
        for i, axis in enumerate("xyz"):
            out[axis] = pos[i]
            out[f"{axis}_program"] = pos[i] - m.offset[i]
            out[f"feed_velocity_{axis}"] = self.v * tangent[i]
        out["feed"] = self.v
        out["path_acceleration"] = self.a
        out["u"] = u
        out["line_number"] = float(m.line)
        out["block_number"] = float(m.block)
        out["spindle_speed"] = m.spindle
        out["spindle_on"] = 1.0 if m.spindle_on else 0.0
        out["rapid"] = 1.0 if m.kind == MOVE_RAPID else 0.0
        out["finished"] = 0.0

    def set_final(self, out: dict) -> None:
        prog = self.program
        if prog.moves:
            last = prog.moves[-1]
            pos, offset = list(last.end), last.offset
        else:
            pos, offset = list(prog.start), prog.start_offset
        for i, axis in enumerate("xyz"):
            out[axis] = pos[i]
            out[f"{axis}_program"] = pos[i] - offset[i]
            out[f"feed_velocity_{axis}"] = 0.0
        out["feed"] = 0.0
        out["path_acceleration"] = 0.0
        out["u"] = 1.0 if prog.moves else 0.0
        out["line_number"] = float(prog.final_line)
        out["block_number"] = float(prog.final_block)
        out["spindle_speed"] = prog.final_spindle
        out["spindle_on"] = 1.0 if prog.final_spindle_on else 0.0
        out["rapid"] = 0.0
        out["finished"] = 1.0

    def step_nurbs(self, local: float, length: float) -> tuple[list[float], list[float], float]:
        m = self.program.moves[self.move]
        curve = self.path.curves[m.curve]
        lo, hi = self.path.move_span[self.move]
        st = self.nurbs
        if st.move != self.move:
            st.move = self.move
            st.u = st.u1 = st.u2 = m.u0
            st.count = 0
            st.s_done = 0.0
            st.s_actual = 0.0
            d = curve.evaluate(m.u0, 2, lo, hi)
            st.point, st.d1, st.d2 = d[0], d[1], d[2]
            st.upp_prev = 0.0
            st.chord_prev = 0.0
        if local >= length:
            if st.u < m.u1:
                self.nurbs_accept(st, curve, m.u1, lo, hi, 0.0, 0.0)
            st.s_done = local
        else:
            step = local - (st.s_actual if self.feedback else st.s_done)
            if step > 0.0 and st.u < m.u1:
                self.nurbs_advance(st, curve, m, step, lo, hi)
            st.s_done = local
        g = math.sqrt(_dot(st.d1, st.d1))
        tangent = [st.d1[i] / g for i in range(3)]
        return list(st.point), tangent, st.u

    def nurbs_accept(self, st: NurbsState, curve: Nurbs, u: float, lo: int, hi: int, upp_prev: float,
                     chord: float, d=None) -> None:
        if d is None:
            d = curve.evaluate(u, 2, lo, hi)
        st.u2, st.u1, st.u = st.u1, st.u, u
        st.upp_prev = upp_prev
        st.chord_prev = chord
        st.point, st.d1, st.d2 = d[0], d[1], d[2]
        st.s_actual += chord
        st.count += 1

    def nurbs_advance(self, st: NurbsState, curve: Nurbs, m: Move, step: float, lo: int, hi: int) -> None:
        u_end = m.u1
        du = predict(st, step, self.predictor, self.net, m.u0, m.u1)
        upp_now = -_dot(st.d1, st.d2) / (_dot(st.d1, st.d1) * _dot(st.d1, st.d1))
        u = st.u + du
        if not (u > st.u):
            u = st.u + step / math.sqrt(_dot(st.d1, st.d1))
        if not (u < u_end):
            u = u_end
        p0 = st.point
        if self.method != METHOD_CORRECTOR:
            d = curve.evaluate(u, 2, lo, hi)
            c = d[0]
            e = [c[0] - p0[0], c[1] - p0[1], c[2] - p0[2]]
            chord = math.sqrt(_dot(e, e))
            self.nurbs_accept(st, curve, u, lo, hi, upp_now, chord, d)
            return
        lo_u, hi_u = st.u, u_end
        target = step * step
        d = None
        chord = 0.0
        u_eval = u
        for _ in range(MAX_NEWTON):
            d = curve.evaluate(u, 2, lo, hi)
            u_eval = u
            c = d[0]
            e = [c[0] - p0[0], c[1] - p0[1], c[2] - p0[2]]
            cc = _dot(e, e)
            chord = math.sqrt(cc)
            if abs(chord - step) <= self.tolerance * step:
                break
            f = cc - target
            if f < 0.0:
                if u >= u_end:
                    break
                lo_u = u
            else:
                hi_u = u
            fp = 2.0 * _dot(e, d[1])
            nxt = u - f / fp if fp > 0.0 else -1.0
            if not (nxt > lo_u and nxt < hi_u):
                nxt = 0.5 * (lo_u + hi_u)
            if nxt == u:
                break
            u = nxt
        self.nurbs_accept(st, curve, u_eval, lo, hi, upp_now, chord, d)


# ============================================================================================
# Reference for the generic FMU tests (tests/fmu_helpers.py, NATIVE_REFERENCES)
# ============================================================================================

def default_program_text() -> str:
    return RESOURCE_PROGRAM.read_text()


def default_program_header(text: str | None = None) -> str:
    """fmus/interpolator/default_program.h: the default program as a C string (the FMU's copy for importers
    that give no resource location). Regenerate: python -c "from milling_twin.models.interpolator import *;
    open('fmus/interpolator/default_program.h', 'w').write(default_program_header())" """
    text = default_program_text() if text is None else text
    out = ["/* The default part program, identical to resources/program.nc (generated by",
           " * models.interpolator.default_program_header; tests/test_interpolator.py checks it): used when the",
           " * program parameter is empty and the importer gave no resource location. */",
           "#ifndef DEFAULT_PROGRAM_H", "#define DEFAULT_PROGRAM_H", "", "static const char DEFAULT_PROGRAM[] ="]
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    for line in lines:
        escaped = line.replace("\\", "\\\\").replace('"', '\\"')
        out.append(f'    "{escaped}\\n"')
    out[-1] += ";"
    out += ["", "#endif", ""]
    return "\n".join(out)


def ticks_in(time_now: float, step_size: float, period: float, done: int) -> int:
    """Periods completed by the end of a step (zero-order hold between ticks): as the C code counts."""
    target = math.floor((time_now + step_size) / period + 1e-6)
    return max(int(target) - done, 0)


def initial_outputs(values: Mapping[str, float | np.ndarray]) -> np.ndarray:
    """Outputs in initialization mode: the tool at its start position, everything else 0."""
    count = max([np.size(v) for v in values.values()] + [1])
    rows = []
    for i in range(count):
        p = {**default_parameters(), **{k: float(np.ravel(v)[i] if np.size(v) > 1 else np.ravel(v)[0])
                                        for k, v in values.items()}}
        out = Interpolator.initial_outputs(p)
        rows.append([out[n] for n in OUTPUTS])
    return np.array(rows)


def reference_trajectory(points: Sequence[Mapping[str, float]], step_size: float) -> np.ndarray:
    """Initialize with points[0] (fixed parameters from it), then per point: set the override, step."""
    first = {**default_parameters(), **points[0]}
    interp = Interpolator(default_program_text(), first)
    rows = []
    time_now = 0.0
    for point in points:
        override = float(point.get("feed_override", first.get("feed_override", 1.0)))
        n = ticks_in(time_now, step_size, interp.period, interp.tick_count)
        interp.set_override(override, interp.tick_count * interp.period)
        for _ in range(n):
            interp.tick()
        time_now += step_size
        rows.append([interp.out[name] for name in OUTPUTS])
    return np.array(rows)


def random_arguments(count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Valid operating points: the default program with random (fixed) limits, method, offsets and start
    point, and a feed override that is piecewise constant (changes every 20 to 60 points, sometimes a feed
    hold) — changing it every point would re-plan every period."""
    p = default_parameters()
    p["method"] = float(rng.integers(1, 5))
    p["corrector_predictor"] = float(rng.integers(1, 4))
    p["acceleration"] = float(rng.uniform(0.5, 3.0))
    p["jerk"] = float(rng.uniform(20.0, 400.0))
    p["centripetal_acceleration"] = float(rng.uniform(0.5, 3.0))
    p["chord_error"] = float(rng.uniform(0.5e-6, 5e-6))
    for axis in "xyz":
        p[f"start_{axis}"] = float(rng.uniform(-1e-3, 1e-3))
        p[f"g54_{axis}"] = float(rng.uniform(-0.01, 0.01))
    values = {name: np.full(count, value) for name, value in p.items()}
    override = np.empty(count)
    i = 0
    while i < count:
        n = int(rng.integers(20, 61))
        override[i:i + n] = 0.0 if rng.random() < 0.1 else float(rng.uniform(0.3, 1.5))
        i += n
    values["feed_override"] = override
    return values


# ============================================================================================
# Helpers for tests, benchmark and training
# ============================================================================================

def _g(x: float) -> str:
    text = f"{x:.10f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def nurbs_block_gcode(points_mm: Sequence[Sequence[float]], weights: Sequence[float], knots: Sequence[float],
                      degree: int, feed_mm_min: float | None = None) -> list[str]:
    """The lines of a G6.2 block (P = degree) for control points in mm (x, y[, z])."""
    lines = []
    for i, (point, w) in enumerate(zip(points_mm, weights)):
        axes = " ".join(f"{a}{_g(float(c))}" for a, c in zip("XYZ", point))
        head = f"G6.2 P{degree} " if i == 0 else ""
        tail = f" F{_g(feed_mm_min)}" if i == 0 and feed_mm_min is not None else ""
        lines.append(f"{head}K{_g(float(knots[i]))} {axes} R{_g(float(w))}{tail}")
    for k in knots[len(points_mm):]:
        lines.append(f"K{_g(float(k))}")
    return lines

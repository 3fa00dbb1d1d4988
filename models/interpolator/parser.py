"""Parser: part program text -> moves (lines, arcs, NURBS pieces) in machine coordinates, in metres.
Mirrors ``fmus/interpolator/gcode_parser.c`` (and ``gcode_parser.h``); ``nurbs_block_gcode`` writes G6.2 blocks
for tests, benchmarks and training.

G-code subset (one block per line; letters case-insensitive; blanks ignored)
------------------------------------------------------------------------------------------------
Dialects (parameter ``dialect``: ``fanuc``, the default, ``linuxcnc``, ``sinumerik``) share this syntax; their
differences are listed last.

Program structure
- comments ``( ... )`` (one line, not nested) and ``;`` to the end of the line; a line holding only ``%``
  is a tape mark and ignored; ``N`` words first in a line (the block number, an output);
- block skip: a line whose first character (after blanks) is ``/`` (also ``/1`` .. ``/9``) is skipped: block
  delete is on, as an operator running a program unattended sets it;
- program numbers ``O1001`` or ``:1001``, alone in their line (a comment may follow), start a program of the
  file; a file with program numbers runs its main program, the first program without ``M99`` (or the first
  program); the others are subprograms, before or after the main program, called by ``M98 P<n> [L<count>]``
  (Fanuc also ``M98 P<count><4-digit number>``: ``P31000`` is O1000 three times) and returning at ``M99``;
  calls nest at most 8 deep, a program running cannot be called again (no recursion), at most 1,000,000 lines
  run in calls and 1,000,000 moves in a program; moves and messages keep the file's line numbers; ``M99`` in the
  main program ends it (noted: a control would start it again); a subprogram reaching the next program or the end
  of the file without ``M99`` is refused at its call;
- numbers: ``[+-]digits[.digits]`` or ``[+-].digits``, at most 17 significant digits, no exponent; no
  parameters or expressions (``#``, ``[``), no rotary or parallel axes (A B C U V W).

Motion
- ``G0`` rapid, ``G1`` line, ``G2``/``G3`` arc clockwise/counter-clockwise (centre ``I J K`` relative to
  the start, or radius ``R``: R > 0 the arc of at most 180 degrees, R < 0 the longer one; a full circle
  needs I/J/K), helical with the third axis; NURBS blocks (below); ``G17``/``G18``/``G19`` plane
  XY/ZX/YZ (centre words I,J / K,I / J,K); ``G20``/``G21`` inch/mm; ``G90``/``G91`` absolute/incremental;
- ``G54``..``G59`` work offsets (values from the parameters ``g54_x`` ... ``g59_z`` or set by
  ``G10 L2 P1..6 X Y Z``: the machine position of the work zero, in the current length unit); ``G52 X Y Z``
  a local offset on top of the work offset (absolute values; ``G52 X0 Y0 Z0`` cancels); ``G53`` with G0/G1:
  the axis words are machine coordinates for that line (G90 only); ``G28 X Y Z``: rapid through the
  intermediate point (the axis words, in G90 or G91) to the home position of the named axes (machine
  coordinates from the parameters ``home_x/y/z``, 0 without them); ``G28 G91 Z0.`` goes straight up to the home Z;
  in G91 a changed offset (G54-G59, G52, G43/G49) takes effect at the next absolute coordinate of the axis;
- ``G4`` dwell (a dwell move: the tool stands still, the move before it ends at rest); ``G9`` exact stop at the
  end of the moves of its line, ``G61`` (also ``G61.1``) exact stop modal, ``G64`` continuous, ``G64 P<tol>``
  contour tolerance (program units; the moves' ``tolerance``, 0: the ``chord_error`` parameter);
- ``G94`` feed per minute, ``G95`` feed per revolution (F in mm/rev or inch/rev times the commanded S; a feed
  move in G95 needs a turning spindle; switching the mode needs a new F);
- canned cycles ``G81`` drill, ``G82`` drill with a dwell ``P`` at the bottom, ``G83`` peck (retract to R after
  each peck ``Q``, rapid back to 0.254 mm (0.010 in) above the last depth), ``G73`` high-speed peck (retract
  0.254 mm after each peck), ``G80`` cancels (and leaves no motion mode: the next coordinates need G0/G1), as do
  G0-G3; ``R`` the retract plane, ``Z`` the hole bottom (below R), ``F``; modal: every following line with X, Y, Z
  or R drills again; ``G98`` returns to the initial level (the Z before the cycle started), ``G99`` to R; in G91
  R is the distance from the initial level and Z from R, X/Y move from hole to hole; repeats ``K`` (fanuc) or
  ``L`` (linuxcnc, sinumerik); every cycle move ends at rest (exact stop); XY plane only (G17), without cutter
  compensation;
- restatements of features that are not modelled and are off: ``G15 G50 G50.1 G69`` accepted.

Tools and machine functions
- ``T<n>`` selects a tool, ``M6`` changes to it (``T1 M6``, ``M6 T1`` or ``T1`` then ``M6`` later): the moves
  after it carry ``tool = n``; the tool change takes no time and no motion (noted); with a tool table every T, H
  and D must name one of its tools; without a tool table T and H are accepted (noted: the tool geometry stays the
  model parameters, the tool length 0) and D is refused (the cutter radius is unknown);
- ``G43 H<n>``/``G44 H<n>`` tool length offset from the tool table (the controlled point is the tool tip:
  machine Z = programmed Z + length for G43, - length for G44; ``H0`` or ``G49`` cancel; without H the active
  tool); the offset takes effect with the next Z word (no motion of its own);
- ``G41``/``G42 D<n>`` cutter radius compensation left/right with the radius of tool n (diameter / 2; without D
  the active tool's), ``G40`` off: the moves carry ``comp`` and ``comp_radius`` (the cutter compensation stage
  offsets them); XY plane only;
- ``F`` feed (mm/min or inch/min, > 0, required before the first feed move; an F in a G20 line is in inch),
  ``S`` spindle speed (rpm), ``M3``/``M4``/``M5`` spindle clockwise/counter-clockwise/stop, ``M7``/``M8`` mist/
  flood coolant on, ``M9`` off (the moves carry it), ``M2``/``M30`` program end (only blank and comment lines,
  and other programs of the file, may follow);
- accepted, not modelled, noted once per word (``Program.notes``; the FMU logs them): ``M0``/``M1`` program
  stop/optional stop (the program runs on), ``M19`` spindle orientation, ``M6`` (no time), T and H without a
  tool table.
- Within a line: G20/G21, G94/G95, F and S, M3/M4/M5, T, M6, M7-M9, then plane, distance, offsets, G61/G64,
  G98/G99, G40-G42, G43/G44/G49, then G4/G10/G52/G28 or the motion (G53 with it), then M0/M1, M2/M30,
  M98/M99. Axis words need a motion mode (G0-G3 and the cycles set one, it is modal).

NURBS blocks, Fanuc (``G6.2``; ``P`` is the order = degree + 1, 2..6, default 4: a cubic)::

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

NURBS blocks, LinuxCNC (``G5.2``/``G5.3``, as LinuxCNC's G-code reference and its knot vector
``nurbs_G5_knot_vector_creator``)::

    G5.2 [P<w0>] [L<order>]           without axes: the weight of the first control point, the current position
    G5.2 X.. Y.. [Z..] [P..] [L..]    or with axes: the current position is the first control point, this the second
    X.. Y.. [Z..] [P<weight>] [K<interval>]   one control point per line (omitted axes: the previous point's)
    G5.3                              ends the block (first in its line; the rest of the line runs after the block)

Order L 2..6 (default 3: quadratic); weights P > 0 (default 1); the knots are LinuxCNC's clamped uniform vector
(0 x order, 1, 2, .., n - order + 2 x order), with ``K`` (an extension: the Sinumerik translator's PL) the
interval between consecutive distinct knots (default 1; the K of the last order - 2 points are not used); at least
L control points; only in G90. (LinuxCNC itself takes L only above 3 and the XY plane only; here L is taken as
written and Z may be given.)

Splines, LinuxCNC (XY plane, G17; modal motion codes; exact Bezier NURBS, knots 0..1)::

    G5 X.. Y.. [I.. J..] P.. Q..      cubic: I J from the start to the first control point, P Q from the end point
                                      to the second; without I J right after another G5: the reflection of its P Q
    G5.1 X.. Y.. I.. J..              quadratic: I J from the start to the control point

Dialects
- ``fanuc`` (Fanuc, Haas and the Fanuc-style posts of Fusion and Mastercam): ``G6.2`` NURBS; G4 ``P`` without a
  decimal point in milliseconds (``P500`` = 0.5 s), with a decimal point and ``X`` in seconds; cycle repeats ``K``;
  Fanuc's canned cycle initial level (the Z when the cycle mode started) and no preliminary move; ``M98 P31000``;
  ``G28`` needs axis words; ``G5.2`` refused ("set dialect = linuxcnc");
- ``linuxcnc``: ``G5.2 ... G5.3`` NURBS, ``G6.2`` refused ("set dialect = fanuc"); G4 ``P`` in seconds; cycle
  repeats ``L``; the cycle's clear level is the higher of the Z before the block and R, and a hole below R starts
  with a rapid up to R; ``G28`` without axes goes home on all axes; O-word subroutines (``o100 sub``) refused;
- ``sinumerik``: every line is first translated by the Sinumerik translator (``sinumerik.py``) into one line of
  this syntax (``G5.2`` blocks for BSPLINE, ``G500``: no settable work offset, ``G4 P`` in seconds, subprograms
  as O numbers); messages quote the file's lines.

Every malformed or unsupported line fails initialization with
``<file> line <n>: "<text>": <what was expected>``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

from milling_twin.models.interpolator import cutter_comp
from milling_twin.models.interpolator.nurbs import dot as _dot
from milling_twin.models.interpolator.numbers import NumberError, read_number

OFFSET_NAMES = ("g54", "g55", "g56", "g57", "g58", "g59")

MAX_LINE_LENGTH = 1000
MAX_COORDINATE = 1e6        # |value| in program units (mm or inch)
MAX_FEED_WORD = 1e7         # mm/min
MAX_SPEED_WORD = 1e6        # rpm
MAX_NURBS_POINTS = 100000
MAX_DEGREE = 5
START_POINT_TOLERANCE = 1e-6   # m: first NURBS control point vs current position
ARC_RADIUS_TOLERANCE = 2e-6    # m, plus ARC_RADIUS_RELATIVE * radius
ARC_RADIUS_RELATIVE = 1e-4
MAX_MOVES = 1000000            # moves of a program, subprogram repeats and canned cycles included
MAX_CALLED_LINES = 1000000     # lines executed in subprogram calls
MAX_CALL_DEPTH = 8             # nested M98 calls
MAX_REPEATS = 9999             # L of M98, K/L of a canned cycle
MAX_PROGRAM_NUMBER = 99999999  # O, P of M98, T, H, D
MAX_NOTES = 32                 # notes of accepted but not modelled words (one per word)
NOTE_LENGTH = 200              # characters of a note in the C program record (with its terminating NUL)
PECK_CLEARANCE = 0.254e-3      # m: G83 stops this short of the previous depth, G73 retracts this far (0.010 in)

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
    notes: list[str] = field(default_factory=list)   # accepted but not modelled words, one note per word


def _parse_number(text: str, i: int, file: str, line: int, raw: str, letter: str) -> tuple[float, int, str]:
    """The number at text[i:] (spaces before it allowed); returns (value, next index, digits as written)."""
    n = len(text)
    while i < n and text[i] in " \t":
        i += 1
    try:
        value, end = read_number(text, i, f"'{letter}'")
    except NumberError as error:
        raise ProgramError(file, line, raw, error.expected) from None
    return value, end, text[i:end]



_LETTERS = "GMNXYZIJKRFSPLOTHDQ"
_LETTER_LIST = "G, M, N, O, T, X, Y, Z, I, J, K, R, F, S, P, L, H, D or Q"

# G codes as 10 * number (G6.2 -> 62); the group of each (a line holds at most one code per group)
_G_GROUPS = {0: "motion", 10: "motion", 20: "motion", 30: "motion", 50: "motion", 51: "motion", 52: "motion",
             53: "nurbs end",
             62: "motion", 730: "motion", 810: "motion", 820: "motion", 830: "motion",
             800: "cycle", 40: "non-modal", 100: "non-modal", 280: "non-modal", 520: "non-modal",
             530: "non-modal", 90: "g9", 170: "plane", 180: "plane", 190: "plane", 200: "units", 210: "units",
             400: "compensation", 410: "compensation", 420: "compensation", 430: "length", 440: "length",
             490: "length", 540: "offset", 550: "offset", 560: "offset", 570: "offset", 580: "offset",
             590: "offset", 5000: "offset", 610: "path", 611: "path", 640: "path", 900: "distance",
             910: "distance", 940: "feed", 950: "feed", 980: "retract",
             990: "retract", 150: "cancel", 500: "cancel", 501: "cancel", 690: "cancel"}
_G_LIST = ("G0 G1 G2 G3 G4 G5 G5.1 G5.2 G5.3 G6.2 G9 G10 G15 G17 G18 G19 G20 G21 G28 G40 G41 G42 G43 G44 G49 G50 "
           "G50.1 G52 G53 G54-G59 G61 G61.1 G64 G69 G73 G80 G81 G82 G83 G90 G91 G94 G95 G98 G99")
# M codes and their groups
_M_GROUPS = {0: "stop", 1: "stop", 2: "end", 30: "end", 3: "spindle", 4: "spindle", 5: "spindle", 19: "spindle",
             6: "tool change", 7: "coolant", 8: "coolant", 9: "coolant", 98: "subprogram", 99: "subprogram"}
_M_LIST = "M0 M1 M2 M3 M4 M5 M6 M7 M8 M9 M19 M30 M98 M99"
_CYCLES = (730, 810, 820, 830)


def _shown(text: str) -> str:
    """A line as the messages show it (as gcode_parser.c: bytes, non-printable as '?', at most 80)."""
    data = text.encode("utf-8", "surrogateescape")
    shown = "".join(chr(b) if 32 <= b < 127 else "?" for b in data[:80])
    return shown[:77] + "..." if len(data) > 80 else shown


def line_error(text: str, file: str, line: int, expected: str) -> str:
    """The parser's message format for a later stage that refuses a line of the program (as gc_line_error):
    ``<file> line <n>: "<text of that line, at most 80 characters, non-printable shown as ?>": <expected>``."""
    lines = text.split("\n")
    shown = lines[line - 1].rstrip("\r") if 1 <= line <= len(lines) else ""
    return f"{file} line {line}: \"{_shown(shown)}\": {expected}"


def _is_skipped(raw: str) -> bool:
    """Block skip: a line whose first character (after blanks) is '/' (block delete on)."""
    return raw.lstrip(" \t").startswith("/")


def _tokenize(raw: str, file: str, line: int, spans: list[tuple[int, int]] | None = None
              ) -> list[tuple[str, float, str]]:
    """Words of one line as (letter, value, number text); comments removed; ':' first in a line is 'O'.
    ``spans``, when given, receives each word's (start, end) in ``raw`` (letter to the number's last character)."""
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
        elif (c.isalpha() and c.isascii()) or (c == ":" and not words):
            letter = "O" if c == ":" else c.upper()
            if letter not in _LETTERS:
                extra = " (only the axes X, Y, Z are modelled)" if letter in "ABCUVW" else ""
                raise ProgramError(file, line, raw, f"a word {_LETTER_LIST}, got '{c}'{extra}")
            start = i
            value, i, text = _parse_number(raw, i + 1, file, line, raw, letter)
            words.append((letter, value, text))
            if spans is not None:
                spans.append((start, i))
        else:
            shown = f"'{c}'" if c.isprintable() and c.isascii() else f"byte 0x{ord(c):02x}" if ord(c) < 128 \
                else "a non-ASCII character"
            extra = " (parameters and expressions are not supported)" if c in "#[" else ""
            raise ProgramError(file, line, raw, f"a word (letter and number), a comment or the end of the line, "
                                                f"got {shown}{extra}")
    return words


def word_spans(raw: str, file: str = "program.nc", line: int = 0) -> list[tuple[str, float, str, int, int]]:
    """The words of one line of the core syntax (Fanuc, LinuxCNC) as the parser reads them: (letter, value, number
    as written, start, end) with ``raw[start:end]`` the word; a ProgramError for a line the parser refuses. For
    tools that rewrite a program word by word (the feed optimizer's F words)."""
    spans: list[tuple[int, int]] = []
    words = _tokenize(raw, file, line, spans)
    return [(letter, value, text, a, b) for (letter, value, text), (a, b) in zip(words, spans)]


def _g_code(value: float, text: str, file: str, line: int, raw: str) -> int:
    """G code as 10 * number (G6.2 -> 62, G500 -> 5000); unknown codes are an error."""
    tenths = round(value * 10.0) if 0 <= value < 1e5 else -1
    if abs(value * 10.0 - tenths) > 1e-9:
        tenths = -1
    if tenths not in _G_GROUPS:
        raise ProgramError(file, line, raw, f"a supported G code ({_G_LIST}), got G{text}")
    return tenths


def _m_code(value: float, text: str, file: str, line: int, raw: str) -> int:
    if value != math.floor(value) or value not in _M_GROUPS:
        raise ProgramError(file, line, raw, f"a supported M code ({_M_LIST}), got M{text}")
    return int(value)


@dataclass
class _Section:
    number: int          # O number, -1 for the text before the first O line
    o_line: int          # index of the O line (-1 for the text before it)
    end: int             # index of the next O line (or the line count)
    subprogram: bool     # holds an M99


@dataclass
class _Call:
    section: int
    return_to: int       # line index after the M98 line
    remaining: int       # executions left, this one included
    line: int            # the M98 line (1-based)


class _Parser:
    def __init__(self, text: str, file: str, p: Mapping[str, float], dialect: int, tools: Sequence[Tool]):
        self.file = file
        self.raw = text.split("\n")      # the file's lines (messages quote them)
        self.lines = self.raw             # the lines parsed (the translation in the sinumerik dialect)
        self.p = p
        self.dialect = dialect
        self.tools = {}
        for tool in tools:
            self.tools.setdefault(tool.number, tool)
        self.home = [p.get("home_x", 0.0), p.get("home_y", 0.0), p.get("home_z", 0.0)]
        self.offsets = [[p[f"{name}_{a}"] for a in "xyz"] for name in OFFSET_NAMES]
        self.active_offset = 0
        self.local = [0.0, 0.0, 0.0]        # G52, m
        self.length_offset = 0.0            # G43/G44, m (+ tool length for G43)
        self.position = [p["start_x"], p["start_y"], p["start_z"]]   # machine
        self.unit = 1e-3          # m per program unit (G21)
        self.inch = False
        self.absolute = True
        self.plane = 17
        self.motion = -1
        self.feed = 0.0           # m/s; 0 = not set (G94)
        self.per_rev = False      # G95
        self.feed_rev = 0.0       # m per revolution; 0 = not set (G95)
        self.speed = 0.0          # rpm as written
        self.spindle_dir = 0      # 1 M3, -1 M4, 0 M5
        self.tool = 0
        self.pending_tool = -1
        self.coolant = COOLANT_OFF
        self.exact_mode = False
        self.g9 = False
        self.tolerance = 0.0
        self.comp = COMP_OFF
        self.comp_radius = 0.0
        self.retract_r = False    # G99
        self.cycle_r: float | None = None
        self.cycle_z: float | None = None
        self.cycle_q = 0.0
        self.cycle_p = 0.0
        self.cycle_initial = 0.0
        self.moves: list[Move] = []
        self.curves: list[NurbsCurve] = []
        self.notes: list[str] = []
        self.noted: set[str] = set()
        self.ended = 0
        self.final_line = 0
        self.final_block = 0
        self.block = 0
        self.start = tuple(self.position)
        self.start_offset = tuple(self.offsets[0])
        self.sections: list[_Section] = []
        self.section_at: dict[int, int] = {}
        self.stack: list[_Call] = []
        self.called_lines = 0
        self.closing_line = 0
        self.last_pq: tuple[int, float, float] | None = None   # after a G5: the move count and its P, Q
        self.main = -1
        if dialect == DIALECT_SINUMERIK:
            self.translate(text, tools)

    def fail(self, line: int, expected: str):
        raise ProgramError(self.file, line, self.raw[line - 1].rstrip("\r"), expected)

    def tokenize(self, k: int) -> list[tuple[str, float, str]]:
        """The words of line index k (its translation in the sinumerik dialect); messages quote the file's text."""
        try:
            return _tokenize(self.lines[k].rstrip("\r"), self.file, k + 1)
        except ProgramError as error:
            raise ProgramError(self.file, k + 1, self.raw[k].rstrip("\r"), error.expected) from None

    def add_note(self, line: int, what: str) -> None:
        if len(self.notes) < MAX_NOTES:
            text = f"{self.file} line {line}: \"{_shown(self.raw[line - 1].rstrip(chr(13)))}\": {what}"
            self.notes.append(text[:NOTE_LENGTH - 1])

    def translate(self, text: str, tools: Sequence[Tool]) -> None:
        """Sinumerik: every line translated into the core syntax (one line each), in file order, before parsing."""
        from milling_twin.models.interpolator.sinumerik import SinumerikError, SinumerikTranslator
        translator = SinumerikTranslator(tools)
        translator.prescan(text)
        out = []
        for k, raw in enumerate(self.raw):
            try:
                out.append(translator.translate(raw))
            except SinumerikError as error:
                self.fail(k + 1, error.expected)
            if translator.note:
                self.add_note(k + 1, translator.note)
        try:
            translator.finish()
        except SinumerikError as error:
            self.fail(len(self.raw), error.expected)
        self.lines = out

    def note(self, line: int, key: str, what: str) -> None:
        """Accepted but not modelled: reported once per word."""
        if key in self.noted or len(self.notes) >= MAX_NOTES:
            return
        self.noted.add(key)
        self.add_note(line, what)

    def length(self, value: float) -> float:
        return value * 0.0254 if self.inch else value / 1000.0

    def spindle_now(self) -> tuple[float, bool]:
        speed = self.speed * (2.0 * math.pi / 60.0) * self.spindle_dir
        return speed, self.spindle_dir != 0

    def total_offset(self) -> list[float]:
        """Machine position of the programmed zero: work offset + G52 + tool length (Z)."""
        off = self.offsets[self.active_offset] if self.active_offset >= 0 else [0.0, 0.0, 0.0]
        out = [off[a] + self.local[a] if self.local[a] != 0.0 else off[a] for a in range(3)]
        if self.length_offset != 0.0:
            out[2] = out[2] + self.length_offset
        return out

    # ---- program structure: O sections and subprograms ----

    def scan_sections(self) -> None:
        """Splits a file with program numbers (O or ':' lines) into sections; the main program is the first
        section without M99 (or the first section)."""
        n = len(self.lines)
        if not any(raw.lstrip(" \t")[:1] in ("O", "o", ":") for raw in self.lines):
            self.sections = [_Section(-1, -1, n, False)]
            self.main = 0
            return
        current = _Section(-1, -1, n, False)
        has_words = False
        sections = []
        for k in range(n):
            raw = self.lines[k].rstrip("\r")
            if len(raw) > MAX_LINE_LENGTH:
                self.fail(k + 1, f"a line of at most {MAX_LINE_LENGTH} characters")
            if raw.strip(" \t") == "%" or _is_skipped(raw):
                continue
            words = self.tokenize(k)
            if not words:
                continue
            if words[0][0] == "O":
                number = self.program_number(k + 1, words)
                if current.o_line >= 0 or has_words:
                    current.end = k
                    sections.append(current)
                current = _Section(number, k, n, False)
                has_words = True
                continue
            has_words = True
            for letter, value, _ in words:
                if letter == "M" and value == 99.0:
                    current.subprogram = True
        if current.o_line >= 0 or has_words:
            sections.append(current)
        seen: dict[int, int] = {}
        for index, section in enumerate(sections):
            if section.o_line >= 0:
                if section.number in seen:
                    self.fail(section.o_line + 1, f"one program O{section.number} in the file (also in line "
                                                  f"{sections[seen[section.number]].o_line + 1})")
                seen[section.number] = index
                self.section_at[section.o_line] = index
        self.sections = sections
        self.main = next((i for i, s in enumerate(sections) if not s.subprogram), 0)

    def program_number(self, number: int, words) -> int:
        if self.dialect == DIALECT_LINUXCNC:
            self.fail(number, "G-code words (LinuxCNC's O-word subroutines and control flow are not supported)")
        if len(words) > 1:
            self.fail(number, "a program number O alone in its line (a comment may follow)")
        value, text = words[0][1], words[0][2]
        if value < 0 or value != math.floor(value) or value > MAX_PROGRAM_NUMBER:
            self.fail(number, f"a whole program number of 0 to {MAX_PROGRAM_NUMBER} after O, got O{text}")
        return int(value)

    def run(self) -> Program:
        self.scan_sections()
        n = len(self.lines)
        k = 0
        if self.sections and self.sections[self.main].o_line >= 0:
            k = self.sections[self.main].o_line
        while True:
            if self.stack:
                call = self.stack[-1]
                if k >= self.sections[call.section].end:
                    self.fail(call.line, f"M99 at the end of the subprogram O{self.sections[call.section].number}")
                self.called_lines += 1
                if self.called_lines > MAX_CALLED_LINES:
                    self.fail(k + 1, f"at most {MAX_CALLED_LINES} lines executed in subprogram calls")
            if k >= n:
                break
            k = self.line(k)
        speed, on = self.spindle_now()
        program = Program(self.file, self.moves, self.curves, self.final_line, self.final_block, speed, on,
                          self.start, self.start_offset)
        program.notes = self.notes
        return program

    def o_line(self, k: int) -> int:
        """The flow reaches a program number: the main program goes on, another program is skipped."""
        index = self.section_at[k]
        if index == self.main and not self.stack:
            return k + 1
        return self.sections[index].end

    # ---- one line ----

    def line(self, k: int) -> int:
        number = k + 1
        raw = self.lines[k].rstrip("\r")
        if len(raw) > MAX_LINE_LENGTH:
            self.fail(number, f"a line of at most {MAX_LINE_LENGTH} characters")
        if raw.strip(" \t") == "%" or _is_skipped(raw):
            return k + 1
        words = self.tokenize(k)
        if not words:
            return k + 1
        if words[0][0] == "O":
            self.program_number(number, words)
            if k in self.section_at:
                return self.o_line(k)
            return k + 1
        if self.ended:
            self.fail(number, f"nothing after the program end (M2/M30 in line {self.ended})")
        self.final_line = number
        seen: dict[str, tuple[float, str]] = {}
        gs: dict[str, int] = {}
        ms: dict[str, int] = {}
        for letter, value, text in words:
            if letter == "G":
                code = _g_code(value, text, self.file, number, self.raw[k].rstrip("\r"))
                group = _G_GROUPS[code]
                if group in gs and group != "cancel":
                    self.fail(number, f"one G code of the {group} group per line, got G{gs[group] / 10:g} "
                                      f"and G{text}")
                gs[group] = code
            elif letter == "M":
                code = _m_code(value, text, self.file, number, self.raw[k].rstrip("\r"))
                group = _M_GROUPS[code]
                if group in ms:
                    self.fail(number, f"one M code of the {group} group per line, got M{ms[group]} and M{text}")
                ms[group] = code
            elif letter == "N":
                if seen or ms or (gs and list(gs) != ["nurbs end"]):   # G5.3 N..: the translator's form
                    self.fail(number, "the line number N first in the line")
                if value < 0 or value != math.floor(value) or value > 2147483647:
                    self.fail(number, f"a whole line number after N, got N{text}")
                seen["N"] = (value, text)
            elif letter == "O":
                self.fail(number, "a program number O alone in its line (a comment may follow)")
            else:
                if letter in seen:
                    self.fail(number, f"one {letter} word per line")
                seen[letter] = (value, text)
        self.block = int(seen["N"][0]) if "N" in seen else 0
        self.final_block = self.block
        self.g9 = "g9" in gs
        motion_g = gs.get("motion")
        if motion_g == 62 or motion_g == 52:
            if motion_g == 62 and self.dialect != DIALECT_FANUC:
                self.fail(number, "G6.2 is Fanuc's NURBS: set dialect = fanuc (or write the curve as G5.2 ... G5.3)")
            if motion_g == 52 and self.dialect == DIALECT_FANUC:
                self.fail(number, "G5.2 is LinuxCNC's NURBS: set dialect = linuxcnc (Fanuc's NURBS is G6.2)")
            for group in ("non-modal", "cycle", "compensation", "length", "path", "feed", "retract"):
                if group in gs:
                    self.fail(number, f"no other G code in the G{motion_g / 10:g} line, got G{gs[group] / 10:g}")
            for group in ("tool change", "subprogram", "stop"):
                if group in ms:
                    self.fail(number, f"no M{ms[group]} in the G{motion_g / 10:g} line")
            for letter in "THDQO":
                if letter in seen:
                    self.fail(number, f"no {letter} word in the G{motion_g / 10:g} line")
            if motion_g == 62:
                return self.nurbs(k, seen, gs, ms)
            return self.g52_nurbs(k, seen, gs, ms)
        if "nurbs end" in gs and number != self.closing_line:
            self.fail(number, "G5.3 after a G5.2 block (it ends the block started by G5.2)")
        # units before F (an F in a G20 line is in inch/min); feed mode before F
        if "units" in gs:
            self.inch = gs["units"] == 200
        if "feed" in gs:
            per_rev = gs["feed"] == 950
            if per_rev != self.per_rev:
                self.per_rev = per_rev
                self.feed, self.feed_rev = 0.0, 0.0
        self.feed_and_spindle(number, seen, ms)
        # tool select, tool change
        if "T" in seen:
            t = self.tool_number(number, "T", seen["T"])
            if t != 0 and t not in self.tools:
                if self.tools:
                    self.fail(number, f"a tool of the tool table for T{seen['T'][1]} (the table has no tool {t})")
                self.note(number, "T", f"T{seen['T'][1]}: no tool table: the tool geometry stays the model's "
                                       f"parameters")
            self.pending_tool = t
        if "tool change" in ms:
            if self.pending_tool < 0:
                self.fail(number, "a tool T before M6 (no tool selected)")
            self.tool = self.pending_tool
            self.note(number, "M6", "M6: the tool change takes no time and no motion here")
        if "coolant" in ms:
            c = ms["coolant"]
            if c == 9:
                self.coolant = COOLANT_OFF
            else:
                bit = COOLANT_MIST if c == 7 else COOLANT_FLOOD
                self.coolant = self.coolant | bit
        if ms.get("spindle") == 19:
            self.note(number, "M19", "M19: spindle orientation not modelled")
        if "plane" in gs:
            self.plane = gs["plane"] // 10
        if "distance" in gs:
            self.absolute = gs["distance"] == 900
        if "offset" in gs:
            code = gs["offset"]
            if code == 5000:
                if self.dialect != DIALECT_SINUMERIK:
                    self.fail(number, "G500 is Sinumerik's: set dialect = sinumerik (or use G54-G59)")
                self.active_offset = -1
            else:
                self.active_offset = (code - 540) // 10
        if "path" in gs:
            code = gs["path"]
            if code == 640:
                self.exact_mode = False
                tol = 0.0
                if "P" in seen:
                    tol = seen["P"][0]
                    if tol < 0.0 or tol > MAX_COORDINATE:
                        self.fail(number, f"a contour tolerance P of 0 to {MAX_COORDINATE:g}, got P{seen['P'][1]}")
                    tol = self.length(tol)
                self.tolerance = tol
            else:
                self.exact_mode = True
        if "retract" in gs:
            self.retract_r = gs["retract"] == 990
        if "compensation" in gs:
            self.compensation(number, gs["compensation"], seen)
        elif "D" in seen:
            self.fail(number, "D only with G41/G42 (the cutter radius of a tool)")
        if "length" in gs:
            code = gs["length"]
            if code == 490:
                if "H" in seen:
                    self.fail(number, "no H with G49 (it cancels the tool length offset)")
                self.length_offset = 0.0
            else:
                h = self.tool_number(number, "H", seen["H"]) if "H" in seen else self.tool
                length = 0.0
                if h != 0:
                    if h in self.tools:
                        length = self.tools[h].length
                    elif self.tools:
                        self.fail(number, f"a tool of the tool table for H{seen['H'][1] if 'H' in seen else h} "
                                          f"(the table has no tool {h})")
                    else:
                        self.note(number, "H", f"G{code / 10:g} H{h}: no tool table: the tool length is 0")
                self.length_offset = length if code == 430 else -length
        elif "H" in seen:
            self.fail(number, "H only with G43/G44 (a tool length offset)")
        axes = [seen.get(a) for a in "XYZ"]
        non_modal = gs.get("non-modal")
        if "cycle" in gs:          # G80 (with G0/G1 in the line as posts write it: "G0 G17 G40 G49 G80 G90")
            if motion_g in _CYCLES:
                self.fail(number, f"either G80 or a canned cycle, got G80 and G{motion_g / 10:g}")
            self.motion = -1
            self.cycle_r = self.cycle_z = None
        for letter in ("P", "L", "Q", "K"):
            if letter in seen and not self.word_used(letter, gs, ms, motion_g, non_modal):
                self.fail(number, {"P": "P only with G4, G5, G10, G64, G82, M98 (or with G6.2 or G5.2)",
                                   "L": "L only with G10, M98 or a canned cycle (repeats) (or with G5.2)",
                                   "Q": "Q only with G73/G83 (the peck depth) or G5",
                                   "K": "K only with G2/G3 (or in a NURBS block)"}[letter])
        if non_modal == 40:
            self.dwell_line(number, seen, motion_g, axes)
        elif non_modal == 100:
            self.g10(number, seen, motion_g, axes)
        elif non_modal == 520:
            if motion_g is not None:
                self.fail(number, "no motion G code in a G52 line")
            for a in range(3):
                if axes[a] is not None:
                    value = axes[a][0]
                    if abs(value) > MAX_COORDINATE:
                        self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                    self.local[a] = self.length(value)
        elif non_modal == 280:
            self.home_return(number, seen, motion_g, axes)
        else:
            previous = self.motion
            if motion_g is not None:
                self.motion = motion_g
                if previous in _CYCLES and motion_g not in _CYCLES:
                    self.cycle_r = self.cycle_z = None
            has_axes = any(x is not None for x in axes)
            if self.motion in _CYCLES:
                if motion_g is not None or has_axes or "R" in seen:
                    if non_modal == 530:
                        self.fail(number, "no G53 in a canned cycle")
                    self.cycle(number, seen, axes, motion_g is not None and previous not in _CYCLES)
            elif self.motion in (50, 51) and (has_axes or motion_g is not None):
                if non_modal == 530:
                    self.fail(number, "G53 only with G0 or G1")
                self.spline(number, seen, axes)
            else:
                arc_words = [w for w in "IJKR" if w in seen]
                if non_modal == 530 and self.motion not in (0, 10):
                    self.fail(number, "G53 only with G0 or G1")
                if self.motion in (20, 30) and (has_axes or motion_g is not None or arc_words):
                    self.arc(number, seen, axes)
                elif has_axes or motion_g is not None:
                    if arc_words:
                        self.fail(number, f"{arc_words[0]} only with G2/G3 (or in a NURBS block)")
                    if self.motion < 0:
                        self.fail(number, "a motion mode G0, G1, G2 or G3 before coordinates")
                    if has_axes:
                        self.straight(number, axes, machine=non_modal == 530)
                elif arc_words:
                    self.fail(number, f"{arc_words[0]} only with G2/G3 (or in a NURBS block)")
                elif non_modal == 530:
                    self.fail(number, "X, Y or Z (machine coordinates) with G53")
        if "stop" in ms:
            self.note(number, f"M{ms['stop']}", f"M{ms['stop']}: program stop not modelled (the program runs on)")
        if "end" in ms:
            self.ended = number
        if "subprogram" in ms:
            return self.subprogram(k, ms["subprogram"], seen)
        return k + 1

    def word_used(self, letter: str, gs, ms, motion_g, non_modal) -> bool:
        """P, L, Q, K: used by a code of the line or the motion mode (after this line's motion code)."""
        motion = motion_g if motion_g is not None else -1 if "cycle" in gs else self.motion
        cycle = motion in _CYCLES and non_modal not in (40, 100, 280, 520)
        spline = motion == 50 and non_modal not in (40, 100, 280, 520)
        if letter == "P":
            return non_modal in (40, 100) or gs.get("path") == 640 or ms.get("subprogram") == 98 or \
                (cycle and motion == 820) or spline
        if letter == "L":
            return non_modal == 100 or ms.get("subprogram") == 98 or cycle
        if letter == "Q":
            return (cycle and motion in (730, 830)) or spline
        return cycle or (non_modal not in (40, 100, 280, 520) and motion in (20, 30))

    def tool_number(self, number: int, letter: str, word) -> int:
        value, text = word
        if value < 0 or value != math.floor(value) or value > MAX_PROGRAM_NUMBER:
            self.fail(number, f"a whole tool number after {letter}, got {letter}{text}")
        return int(value)

    def compensation(self, number: int, code: int, seen) -> None:
        if code == 400:
            if "D" in seen:
                self.fail(number, "no D with G40 (it cancels the cutter radius compensation)")
            self.comp, self.comp_radius = COMP_OFF, 0.0
            return
        if self.plane != 17:
            self.fail(number, f"G17 (the XY plane) for cutter radius compensation G{code // 10}, got G{self.plane}")
        d = self.tool_number(number, "D", seen["D"]) if "D" in seen else self.tool
        radius = 0.0
        if d != 0:
            if d not in self.tools:
                shown = f"D{seen['D'][1]}" if "D" in seen else f"G{code // 10} (the active tool {d})"
                if self.tools:
                    self.fail(number, f"a tool of the tool table for {shown} (the table has no tool {d})")
                self.fail(number, f"a tool of the tool table for {shown} (the tool table is empty: the cutter "
                                  f"radius is unknown)")
            radius = 0.5 * self.tools[d].diameter
        elif "D" not in seen:
            self.fail(number, f"D (a tool of the tool table: its radius) with G{code // 10}")
        self.comp = COMP_LEFT if code == 410 else COMP_RIGHT
        self.comp_radius = radius

    def g10(self, number: int, seen, motion_g, axes) -> None:
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

    def dwell_seconds(self, number: int, letter: str, word) -> float:
        """G4/G82 dwell: seconds; Fanuc's P without a decimal point is in milliseconds."""
        value, text = word
        if value < 0.0 or value > MAX_COORDINATE:
            self.fail(number, f"a dwell {letter} of 0 to {MAX_COORDINATE:g}, got {letter}{text}")
        if letter == "P" and self.dialect == DIALECT_FANUC and "." not in text:
            return value / 1000.0
        return value

    def dwell_line(self, number: int, seen, motion_g, axes) -> None:
        if motion_g is not None:
            self.fail(number, f"no motion G code in a G4 line, got G{motion_g / 10:g}")
        if self.dialect == DIALECT_FANUC and axes[0] is not None:
            if "P" in seen:
                self.fail(number, "either P or X with G4 (the dwell), not both")
            word, letter = axes[0], "X"
        elif "P" in seen:
            word, letter = seen["P"], "P"
        else:
            self.fail(number, "P (the dwell time) with G4" + (" (or X, seconds)" if self.dialect == DIALECT_FANUC
                                                              else ""))
        for a, name in ((1, "Y"), (2, "Z")) + (((0, "X"),) if letter == "P" else ()):
            if axes[a] is not None:
                self.fail(number, f"no axis word in a G4 line, got {name}")
        self.dwell(number, self.dwell_seconds(number, letter, word))

    def dwell(self, number: int, seconds: float) -> None:
        if seconds <= 0.0:
            return
        if self.moves:
            self.moves[-1].exact_stop = True
        speed, on = self.spindle_now()
        self.add(Move(MOVE_DWELL, number, tuple(self.position), tuple(self.position), tuple(self.total_offset()),
                      0.0, speed, on, dwell=seconds))
        self.moves[-1].exact_stop = True

    def home_return(self, number: int, seen, motion_g, axes) -> None:
        """G28: rapid through the intermediate point (the axis words) to the home position of those axes."""
        if motion_g is not None:
            self.fail(number, f"no motion G code in a G28 line, got G{motion_g / 10:g}")
        for letter in "IJKR":
            if letter in seen:
                self.fail(number, f"only X, Y, Z with G28, got {letter}")
        named = [a for a in range(3) if axes[a] is not None]
        if not named:
            if self.dialect == DIALECT_FANUC:
                self.fail(number, "the axes to return (X, Y, Z: the intermediate point) with G28")
            end = list(self.home)
        else:
            middle = self.target(number, axes)
            self.rapid(number, middle)
            end = list(self.position)
            for a in named:
                end[a] = self.home[a]
        self.rapid(number, end)

    def rapid(self, number: int, end, exact: bool = False) -> None:
        dx, dy, dz = end[0] - self.position[0], end[1] - self.position[1], end[2] - self.position[2]
        if dx * dx + dy * dy + dz * dz <= 0.0:
            return
        speed, on = self.spindle_now()
        self.add(Move(MOVE_RAPID, number, tuple(self.position), tuple(end), tuple(self.total_offset()), 0.0,
                      speed, on))
        if exact:
            self.moves[-1].exact_stop = True

    def feed_to(self, number: int, end) -> None:
        dx, dy, dz = end[0] - self.position[0], end[1] - self.position[1], end[2] - self.position[2]
        if dx * dx + dy * dy + dz * dz <= 0.0:
            return
        speed, on = self.spindle_now()
        self.add(Move(MOVE_LINE, number, tuple(self.position), tuple(end), tuple(self.total_offset()),
                      self.current_feed(), speed, on))
        self.moves[-1].exact_stop = True

    def cycle(self, number: int, seen, axes, new: bool) -> None:
        """G73/G81/G82/G83 expanded to moves as a Fanuc control runs them (G17 only)."""
        code = self.motion
        if self.plane != 17:
            self.fail(number, f"G17 (the XY plane) for the canned cycle G{code // 10}, got G{self.plane}")
        if self.comp != COMP_OFF:
            self.fail(number, f"G40 (no cutter radius compensation) before the canned cycle G{code // 10}")
        for letter in "IJ":
            if letter in seen:
                self.fail(number, f"no {letter} in a canned cycle")
        for letter, name in (("R", "cycle_r"), ("Z", "cycle_z")):
            if letter in seen:
                value = seen[letter][0]
                if abs(value) > MAX_COORDINATE:
                    self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                setattr(self, name, value)
        if "Q" in seen:
            q = seen["Q"][0]
            if not q > 0.0 or q > MAX_COORDINATE:
                self.fail(number, f"a peck depth Q > 0 (and at most {MAX_COORDINATE:g}), got Q{seen['Q'][1]}")
            self.cycle_q = self.length(q)
        if "P" in seen:
            self.cycle_p = self.dwell_seconds(number, "P", seen["P"])
        if self.cycle_r is None:
            self.fail(number, f"R (the retract plane) with G{code // 10}")
        if self.cycle_z is None:
            self.fail(number, f"Z (the hole bottom) with G{code // 10}")
        if code in (730, 830) and not self.cycle_q > 0.0:
            self.fail(number, f"Q (the peck depth) with G{code // 10}")
        self.need_feed(number)
        repeat_letter = "K" if self.dialect == DIALECT_FANUC else "L"
        other = "L" if repeat_letter == "K" else "K"
        if other in seen:
            self.fail(number, f"{repeat_letter} (the repeat count) in a canned cycle of this dialect, got {other}")
        repeats = 1
        if repeat_letter in seen:
            value, text = seen[repeat_letter]
            if value < 0 or value != math.floor(value) or value > MAX_REPEATS:
                self.fail(number, f"a whole repeat count {repeat_letter} of 0 to {MAX_REPEATS}, got "
                                  f"{repeat_letter}{text}")
            repeats = int(value)
        off = self.total_offset()
        old_z = self.position[2]
        if new or self.dialect != DIALECT_FANUC:
            self.cycle_initial = old_z
        initial = self.cycle_initial
        if self.absolute:
            r = self.length(self.cycle_r) + off[2]
            bottom = self.length(self.cycle_z) + off[2]
        else:
            r = initial + self.length(self.cycle_r)
            bottom = r + self.length(self.cycle_z)
        if bottom > r:
            self.fail(number, f"the hole bottom Z below the retract plane R in G{code // 10}")
        if self.retract_r:
            clear = r
        else:
            clear = initial if self.dialect == DIALECT_FANUC or initial > r else r
        for rep in range(repeats):
            if rep == 0 and self.dialect != DIALECT_FANUC and self.position[2] < r:
                self.rapid(number, [self.position[0], self.position[1], r], True)
            hole = list(self.position)
            for a in range(2):
                if axes[a] is not None:
                    value = self.length(axes[a][0])
                    hole[a] = value + off[a] if self.absolute else self.position[a] + value
            self.rapid(number, hole, True)
            self.rapid(number, [hole[0], hole[1], r], True)
            if code in (810, 820):
                self.feed_to(number, [hole[0], hole[1], bottom])
                if code == 820:
                    self.dwell(number, self.cycle_p)
            else:
                depth = r
                while depth > bottom:
                    start = depth
                    if depth < r:
                        start = depth + PECK_CLEARANCE if code == 830 else depth
                        if code == 830:
                            self.rapid(number, [hole[0], hole[1], start], True)
                    nxt = depth - self.cycle_q
                    if nxt < bottom:
                        nxt = bottom
                    self.feed_to(number, [hole[0], hole[1], nxt])
                    depth = nxt
                    if depth > bottom:
                        if code == 830:
                            self.rapid(number, [hole[0], hole[1], r], True)
                        else:
                            self.rapid(number, [hole[0], hole[1], depth + PECK_CLEARANCE], True)
            self.rapid(number, [hole[0], hole[1], clear], True)

    def subprogram(self, k: int, code: int, seen) -> int:
        number = k + 1
        if code == 99:
            if not self.stack:
                self.note(number, "M99", "M99 in the main program: the program ends here (a control would "
                                         "start it again)")
                self.ended = number
                return k + 1
            call = self.stack[-1]
            call.remaining -= 1
            if call.remaining > 0:
                return self.sections[call.section].o_line + 1
            self.stack.pop()
            return call.return_to
        if "P" not in seen:
            self.fail(number, "P (the program number) with M98")
        value, text = seen["P"]
        if value < 0 or value != math.floor(value) or value > MAX_PROGRAM_NUMBER:
            self.fail(number, f"a whole program number after P, got P{text}")
        target, count = int(value), 1
        if "L" in seen:
            lv, lt = seen["L"]
            if lv < 0 or lv != math.floor(lv) or lv > MAX_REPEATS:
                self.fail(number, f"a whole repeat count L of 0 to {MAX_REPEATS}, got L{lt}")
            count = int(lv)
        elif self.dialect == DIALECT_FANUC and target > 9999:
            count, target = target // 10000, target % 10000
        index = next((i for i, s in enumerate(self.sections) if s.o_line >= 0 and s.number == target), -1)
        if index < 0:
            self.fail(number, f"a program O{target} in this file for M98 (subprograms are read from the same file)")
        if any(call.section == index for call in self.stack) or index == self.main:
            self.fail(number, f"no recursive call: O{target} is already running")
        if len(self.stack) >= MAX_CALL_DEPTH:
            self.fail(number, f"subprogram calls nested at most {MAX_CALL_DEPTH} deep")
        if count == 0:
            return k + 1
        self.stack.append(_Call(index, k + 1, count, number))
        return self.sections[index].o_line + 1

    def target(self, number: int, axes) -> list[float]:
        off = self.total_offset()
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

    def current_feed(self) -> float:
        if not self.per_rev:
            return self.feed
        return self.feed_rev * self.speed / 60.0

    def control_point(self, ln: int, line_words: dict, off, previous) -> list[float]:
        """A NURBS control point from the line's X, Y, Z (absolute, program units, plus the offset ``off``); an
        axis not written keeps the previous control point's coordinate (gcode_parser.c control_point)."""
        pt = []
        for a, letter in enumerate("XYZ"):
            if letter in line_words:
                value = line_words[letter][0]
                if abs(value) > MAX_COORDINATE:
                    self.fail(ln, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                pt.append(self.length(value) + off[a])
            else:
                pt.append(previous[a])
        return pt

    def need_feed(self, number: int) -> None:
        if (self.feed_rev if self.per_rev else self.feed) <= 0.0:
            self.fail(number, "F (feed) before the first feed move (G1, G2, G3, G6.2)")
        if self.per_rev and (self.spindle_dir == 0 or self.speed <= 0.0):
            self.fail(number, "a turning spindle (S > 0 and M3/M4) for a feed move in G95 (feed per revolution)")

    def add(self, move: Move) -> None:
        if len(self.moves) >= MAX_MOVES:
            self.fail(move.line, f"at most {MAX_MOVES} moves in a program (subprogram repeats and canned cycles "
                                 f"included)")
        move.block = self.block
        move.tool = self.tool
        move.coolant = self.coolant
        move.exact_stop = self.exact_mode or self.g9
        move.tolerance = self.tolerance
        move.comp = self.comp
        move.comp_radius = self.comp_radius
        self.moves.append(move)
        self.position = list(move.end)

    def straight(self, number: int, axes, machine: bool = False) -> None:
        if machine:
            if not self.absolute:
                self.fail(number, "G90 with G53 (machine coordinates are absolute)")
            end = list(self.position)
            for a in range(3):
                if axes[a] is not None:
                    value = axes[a][0]
                    if abs(value) > MAX_COORDINATE:
                        self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                    end[a] = self.length(value)
        else:
            end = self.target(number, axes)
        rapid = self.motion == 0
        if not rapid:
            self.need_feed(number)
        dx, dy, dz = end[0] - self.position[0], end[1] - self.position[1], end[2] - self.position[2]
        if dx * dx + dy * dy + dz * dz <= 0.0:
            return
        speed, on = self.spindle_now()
        self.add(Move(MOVE_RAPID if rapid else MOVE_LINE, number, tuple(self.position), tuple(end),
                      tuple(self.total_offset()), 0.0 if rapid else self.current_feed(), speed, on))

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
        self.add(Move(MOVE_ARC, number, tuple(start), tuple(end), tuple(self.total_offset()),
                      self.current_feed(), speed, on, center=tuple(centre), axes=plane_axes, theta0=theta0, sweep=sweep,
                      r0=r0, r1=r1, height=height))


    def unit_factor(self) -> float:
        return 0.0254 if self.inch else 1e-3

    def feed_and_spindle(self, number: int, seen: dict, ms: dict) -> None:
        """The F, S and M3/M4/M5 words of a line (plain or G6.2), as gcode_parser.c takes them."""
        if "F" in seen:
            f = seen["F"][0]
            if not (f > 0.0) or f > MAX_FEED_WORD:
                self.fail(number, f"a feed F > 0 and at most {MAX_FEED_WORD:g}, got F{seen['F'][1]}")
            if self.per_rev:
                self.feed_rev = self.length(f)
            else:
                self.feed = self.length(f) / 60.0
        if "S" in seen:
            s = seen["S"][0]
            if s < 0.0 or s > MAX_SPEED_WORD:
                self.fail(number, f"a spindle speed S of 0 to {MAX_SPEED_WORD:g} rpm, got S{seen['S'][1]}")
            self.speed = s
        if ms.get("spindle") in (3, 4, 5):
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
        off = self.total_offset()
        previous = list(self.position)
        line_words = seen
        k_line = k
        while True:
            ln = k_line + 1
            if ln != first_line:
                for letter in sorted(line_words):
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
                pt = self.control_point(ln, line_words, off, previous)
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
                    self.fail(nxt + 1, f"a line of at most {MAX_LINE_LENGTH} characters")
                if raw_next.strip(" \t") == "%":
                    break
                words = [] if _is_skipped(raw_next) else self.tokenize(nxt)
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
        self.emit_curve(NurbsCurve(degree, [tuple(p) for p in points], weights, knots, first_line), first_line,
                        end_line)
        return end_line

    def spline(self, number: int, seen, axes) -> None:
        """LinuxCNC G5 (cubic: I J from the start to the first control point, P Q from the end to the second; without
        I J right after a G5 the reflection of its P Q) and G5.1 (quadratic: I J from the start), as exact
        Bezier NURBS in the XY plane."""
        code = self.motion
        name = "G5" if code == 50 else "G5.1"
        if self.dialect != DIALECT_LINUXCNC:
            self.fail(number, f"{name} is LinuxCNC's {'cubic' if code == 50 else 'quadratic'} spline: set dialect = "
                              f"linuxcnc")
        if self.plane != 17:
            self.fail(number, f"G17 (the XY plane) for {name}, got G{self.plane}")
        for letter in ("Z", "K", "R") + (("P", "Q") if code == 51 else ()):
            if letter in seen:
                self.fail(number, f"no {letter} with {name}")
        self.need_feed(number)
        end = self.target(number, axes)
        start = list(self.position)
        words = {}
        for letter in "IJPQ":
            if letter in seen:
                value = seen[letter][0]
                if abs(value) > MAX_COORDINATE:
                    self.fail(number, f"a coordinate of magnitude at most {MAX_COORDINATE:g}")
                words[letter] = self.length(value)
        if code == 50:
            if "I" in words or "J" in words:
                c1 = [start[0] + words.get("I", 0.0), start[1] + words.get("J", 0.0), start[2]]
            elif self.last_pq is not None and self.last_pq[0] == len(self.moves):
                c1 = [start[0] - self.last_pq[1], start[1] - self.last_pq[2], start[2]]
            else:
                self.fail(number, "I, J (the first control point, from the start) with G5 (or a G5 just before)")
            if "P" not in words or "Q" not in words:
                self.fail(number, "P and Q (the second control point, from the end point) with G5")
            c2 = [end[0] + words["P"], end[1] + words["Q"], start[2]]
            points = [start, c1, c2, end]
        else:
            if "I" not in words and "J" not in words:
                self.fail(number, "I, J (the control point, from the start) with G5.1")
            points = [start, [start[0] + words.get("I", 0.0), start[1] + words.get("J", 0.0), start[2]], end]
        if all(p == start for p in points):
            self.fail(number, f"an end point or control points away from the start with {name}")
        degree = len(points) - 1
        knots = [0.0] * (degree + 1) + [1.0] * (degree + 1)
        self.emit_curve(NurbsCurve(degree, [tuple(p) for p in points], [1.0] * len(points), knots, number), number,
                        number)
        self.last_pq = (len(self.moves), words["P"], words["Q"]) if code == 50 else None

    def emit_curve(self, curve: NurbsCurve, first_line: int, end_line: int) -> None:
        """Stores a NURBS curve and its moves (split at inner knots of multiplicity >= the degree)."""
        knots, degree, n_points = curve.knots, curve.degree, len(curve.points)
        index = len(self.curves)
        self.curves.append(curve)
        speed, on = self.spindle_now()
        off = self.total_offset()
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
        start = tuple(self.position)
        for b in range(len(breaks) - 1):
            self.add(Move(MOVE_NURBS, first_line, start, tuple(curve.points[-1]), tuple(off), self.current_feed(),
                          speed, on, curve=index, u0=breaks[b], u1=breaks[b + 1]))
        self.final_line = end_line

    def g52_nurbs(self, k: int, seen, gs, ms) -> int:
        """G5.2 [X Y Z] [P weight] [L order] [K interval], control point lines X Y Z [P] [K], G5.3 (LinuxCNC; with
        Z and K also the form the Sinumerik translator writes for BSPLINE)."""
        number = k + 1
        first_line = number
        if not self.absolute:
            self.fail(number, "G90 (absolute coordinates) for a NURBS block")
        for letter in "IJRQ":
            if letter in seen:
                self.fail(number, f"X, Y, Z, P, L, K, F in a G5.2 line, got {letter}")
        order = 3
        if "L" in seen:
            lv = seen["L"][0]
            if lv not in (2.0, 3.0, 4.0, 5.0, 6.0):
                self.fail(number, f"an order L (degree + 1) of 2 to {MAX_DEGREE + 1}, got L{seen['L'][1]}")
            order = int(lv)
        self.feed_and_spindle(number, seen, ms)
        for group in ("plane", "units", "distance", "offset"):
            if group in gs:
                self.fail(number, "no other G code in the G5.2 line")
        if "end" in ms:
            self.fail(number, "M2/M30 after the NURBS block, not in its first line")
        self.need_feed(number)
        self.motion = -1
        off = self.total_offset()
        points = [list(self.position)]
        weights = [1.0]
        intervals: list[float] = []
        line_words = seen
        ln = number
        while True:
            if ln != first_line:
                for letter in sorted(line_words):
                    if letter not in "XYZPKN":
                        self.fail(ln, f"X, Y, Z, P, K in a G5.2 block (started in line {first_line}), or G5.3 to "
                                      f"end it, got {letter}")
            has_point = any(a in line_words for a in "XYZ")
            if "P" in line_words:
                w = line_words["P"][0]
                if not (w > 0.0) or w > MAX_COORDINATE:
                    self.fail(ln, f"a weight P > 0 (and at most {MAX_COORDINATE:g}), got P{line_words['P'][1]}")
            else:
                w = 1.0
            if has_point:
                if len(points) >= MAX_NURBS_POINTS:
                    self.fail(ln, f"at most {MAX_NURBS_POINTS} control points in a NURBS block")
                pt = self.control_point(ln, line_words, off, points[-1])
                interval = 1.0
                if "K" in line_words:
                    interval = line_words["K"][0]
                    if not (interval > 0.0) or interval > MAX_COORDINATE:
                        self.fail(ln, f"a knot interval K > 0 (and at most {MAX_COORDINATE:g}), got "
                                      f"K{line_words['K'][1]}")
                points.append(pt)
                weights.append(w)
                intervals.append(interval)
            elif ln == first_line and "K" not in line_words:
                weights[0] = w
            else:
                self.fail(ln, f"X, Y or Z (a control point) in the G5.2 block started in line {first_line}")
            # the next line: control points until G5.3
            nxt = ln
            words = []
            while nxt < len(self.lines):
                raw_next = self.lines[nxt].rstrip("\r")
                if len(raw_next) > MAX_LINE_LENGTH:
                    self.fail(nxt + 1, f"a line of at most {MAX_LINE_LENGTH} characters")
                if raw_next.strip(" \t") == "%":
                    break
                if not _is_skipped(raw_next):
                    words = self.tokenize(nxt)
                    if words:
                        break
                nxt += 1
            if not words:
                self.fail(first_line, "G5.3 to end the NURBS block started here")
            ln = nxt + 1
            if any(w[0] == "G" for w in words):
                first = words[1] if words[0][0] == "N" and len(words) > 1 else words[0]
                if first[0] != "G" or first[1] * 10.0 != 53.0:
                    self.fail(ln, f"G5.3 first to end the G5.2 block started in line {first_line} (a control point "
                                  f"line holds X, Y, Z, P, K)")
                break
            line_words = {}
            for letter, value, text in words:
                if letter in line_words:
                    self.fail(ln, f"one {letter} word per line")
                line_words[letter] = (value, text)
        n_points = len(points)
        degree = order - 1
        if n_points < order:
            self.fail(ln, f"at least L = {order} control points (the current position and {order - 1} more) in the "
                          f"G5.2 block started in line {first_line}, got {n_points}")
        # clamped knots: as LinuxCNC's knot vector (0 x order, 1, 2, ..., n - order + 2 x order) with the
        # intervals K (default 1) between the distinct knots
        knots = [0.0] * order
        t = 0.0
        for i in range(n_points - order + 1):
            t = t + intervals[i]
            knots.append(t)
        knots += [t] * (order - 1)
        self.emit_curve(NurbsCurve(degree, [tuple(p) for p in points], weights, knots, first_line), first_line, ln)
        self.final_block = self.block
        self.closing_line = ln        # the G5.3 line runs next: the words after G5.3 (G1 X.., M30) are executed
        return ln - 1


def parse_program(text: str, parameters: Mapping[str, float], file: str = "program.nc", *,
                  dialect: int = DIALECT_FANUC, tools: Sequence[Tool] = ()) -> Program:
    """The moves of a part program; ``dialect`` DIALECT_FANUC/LINUXCNC/SINUMERIK, ``tools`` the tool table;
    the home position of G28 from the parameters ``home_x/y/z`` (machine coordinates, m; 0 without them)."""
    program = _Parser(text, file, parameters, dialect, tools).run()
    # G41/G42: the moves carry side and radius; the compensation stage offsets them (or refuses a line)
    cutter_comp.compensate(program, text, file)
    return program


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

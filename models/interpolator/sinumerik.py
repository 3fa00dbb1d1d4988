"""Sinumerik 840D part programs, translated line by line into the core G-code syntax of ``parser.py``.
Mirrors ``fmus/interpolator/sinumerik.c`` (and ``sinumerik.h``): the same output bytes and the same messages.

The parser calls the translator for every line of a program read with ``dialect = "sinumerik"``: one output line
per input line, so line numbers and the quoted line text of every message stay the file's. ``translate`` returns the
line in the core syntax (possibly empty) or raises ``SinumerikError(expected)``; the caller formats
``<file> line <n>: "<original text>": <expected>``. ``prescan(text)`` first collects the subprogram names of the
whole file, so a call may come before the subprogram's section. ``note`` holds, after each line, what the line
used for the first time that is accepted but not modelled ("" if nothing); ``finish()`` names a B spline still open
at the end of the text.

Translated (Sinumerik -> core)
------------------------------
- ``; comment`` (to the end of the line; ``;$PATH=...`` lines too), ``MSG("...")`` (nothing), block numbers
  ``N10`` (kept) and ``:10`` (main blocks, as ``N10``), block skip ``/`` (the block is skipped, as the core skips
  it), a ``%`` line (nothing);
- archive section headers: ``%_N_<NAME>_MPF`` (the main program: nothing), ``%_N_<NAME>_SPF`` (a subprogram:
  ``O<n>``, names numbered 9001, 9002, ... in order of appearance in the file), ``PROC <NAME>`` (nothing right after
  its own section header, else ``O<n>`` alone; no parameters);
- subprogram calls ``L10``, ``L10 P3``, ``<NAME>``, ``<NAME> P3``, ``CALL "<NAME>"`` -> ``M98 P<n> [L<count>]``;
  ``M17`` and ``RET`` -> ``M99``; ``M2``, ``M30``;
- ``G0 G1 G2 G3 G9 G17 G18 G19 G40 G53 G54..G57 G90 G91 G94 G95 G500`` as they are; ``G153`` and ``SUPA`` -> ``G53``;
  ``G70``/``G700`` -> ``G20``, ``G71``/``G710`` -> ``G21``; ``G60`` -> ``G61``; ``G64`` -> ``G64``; ``G641`` ..
  ``G645`` -> ``G64 P<ADIS>`` (``G64`` without ADIS); ``ADIS=`` while G641.. is active -> ``G64 P<ADIS>``;
  ``CYCLE832(<tol>, <type>, ...)`` -> ``G64 P<tol>`` (tolerance 0 or omitted, or type _OFF / 0: ``G64``);
  ``G4 F<s>`` (dwell in seconds) -> ``G4 P<s>`` (P in seconds in the sinumerik dialect); ``CR=<r>`` (arc
  radius) -> ``R<r>``;
- frames: ``TRANS X Y Z`` (replaces the programmable frame; ``TRANS`` alone clears it), ``ATRANS X Y Z`` (adds)
  -> ``G52 X Y Z`` with the frame's totals (ATRANS only after the frame was set in the same program section
  without a subprogram call between: the translation runs in file order, the program per call);
  ``ROT``/``SCALE``/``MIRROR`` with no rotation, unit scale, no mirrored axis clear the frame (``G52 X0 Y0 Z0``);
  ``AROT``/``ASCALE``/``AMIRROR`` that change nothing: nothing;
- tools: ``T1``, ``T=1``, ``T="END10"`` (the tool of that name in the tool table) -> ``T<n>``; ``M6``; ``D1``
  (activates the tool's length compensation) -> ``G43 H<tool>``, ``D0`` -> ``G49``; an ``M6`` while D1 is active
  also gives ``G43 H<new tool>`` (the offset follows the tool); ``G41``/``G42`` -> ``G41 D<tool>``/``G42
  D<tool>`` (D1 and G41/G42 only after the tool change and D1 of the same program section without a subprogram
  call between; a call in BSPLINE mode is refused);
- ``S``, ``F``, ``M0 M1 M3 M4 M5 M7 M8 M9 M19``;
- R parameters ``R0``..``R99``: ``R1=5``, ``R2=R1*2+3``, several per line, evaluated left to right, once, in
  the order of the file (so a value is used only in the program section that set it: a subprogram runs per call,
  the translation once; reading an R set in another section, e.g. by the main program before a call, is
  refused); any address with ``=``: ``X=R1+10``, ``X=-R2``, ``Y=(R1+R2)/2``, ``F=R5``; operators ``+ - * /``,
  parentheses, unary minus, functions ``SIN COS TAN`` (degrees) ``SQRT ABS POT`` (square) ``TRUNC``; blanks only inside
  parentheses. A computed value is written with at most 10 decimals (at most 17 significant digits, no exponent:
  as the core reads numbers), a value written as a number is passed on as written;
- ``BSPLINE`` with ``SD=<degree>`` (2 or 3, default 3; modal), ``PW=<weight>`` and ``PL=<knot interval>`` (of the
  line's point): the first line with axes in BSPLINE mode opens ``G5.2 L<SD+1> X Y Z [P<PW>] [K<PL>]``, each
  following line with axes adds ``X Y Z [P] [K]``; the block ends (``G5.3`` at the start of the line) at the next
  line that selects G0/G1/G2/G3 or ends the program or subprogram (M2, M30, M17, RET). The B spline starts at the
  current position, the end point of the block before BSPLINE (P1 of the manual's B spline figure), so the first
  BSPLINE line's point is the second control point, as in the core's G5.2 block.
- accepted, not modelled (reported once per word in ``note``): ``G601 G602 G603`` (exact-stop windows), ``G450
  G451`` (corners of the radius compensation), ``SOFT BRISK`` (acceleration profile), ``FFWON FFWOF``, ``COMPOF
  COMPCAD COMPCURV COMPSURF`` (compressors), ``UPATH SPATH FNORM CFC CFTCP CFIN DIAMOF TRAFOOF STOPRE``,
  ``ADISPOS=``, ``MSG``.

Refused, naming the word: everything else, e.g. ``CYCLE81`` and other cycles, ``MCALL``, ``GOTO``/``IF``/``WHILE``
(control structures), ``DEF`` and ``$`` variables, ``ROT``/``SCALE``/``MIRROR`` that rotate, scale or mirror
("frame rotation is not modelled"), ``CIP``, ``CT``, ``ASPLINE``/``CSPLINE``, polar ``AP=``/``RP=``, ``AC()``/``IC()``,
``G58``/``G59`` (axial offsets), ``G505``.., ``D2``.. (one cutting edge per tool), ``G4 S`` (dwell in
revolutions); also a division by zero, an R parameter used before it is set, a function not in the list.

References (Siemens SINUMERIK 840D sl / 828D Programming Manual, Fundamentals / Job planning, editions 2009-2019,
as stored by easymanua.ls and manualslib.com): 3.7 "Special motion commands", B spline: BSPLINE modal in the group
of motion commands, PW point weight 0..3, SD=2 for a second-degree polygon (third degree standard), PL parameter
interval length, the curve does not run through the points but starts at P1 (the position before the spline);
2.12 "Coordinate transformations (frames)": TRANS/ATRANS, ROT/AROT, SCALE/ASCALE, MIRROR/AMIRROR, frame statements
in a separate block; K2 function manual: G53/G153/SUPA suppress frames; 3.25 "Programming cycles externally",
CYCLE832: parameter 1 the contour tolerance, parameter 2 the machining type (units digit 0 = deselection, _OFF).
"""
from __future__ import annotations

import math
from typing import Sequence

from milling_twin.models.interpolator.numbers import MAX_SIGNIFICANT_DIGITS, NumberError, read_number

R_COUNT = 100
MAX_SUBPROGRAMS = 64
NAME_LENGTH = 31             # characters of a subprogram or tool name
MAX_OUTPUT = 2000            # characters of one translated line
MAX_NESTING = 32             # parentheses in an expression
MAX_WORD = 64                # characters of a keyword or name
MAX_TOKENS = 256             # words of one line
FIRST_SUBPROGRAM = 9001
VALUE_LIMIT = 1e9            # |computed value|
DEGREE = math.pi / 180.0

_POW10 = [1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17,
          1e18, 1e19, 1e20, 1e21, 1e22]

# accepted, not modelled: word -> what it does (the note says it once per program)
NOTED = (
    ("G601", "exact-stop window fine"), ("G602", "exact-stop window coarse"),
    ("G603", "exact stop at the interpolation end"),
    ("G450", "corners of the radius compensation as arcs"), ("G451", "corners of the radius compensation at the "
                                                                     "intersection"),
    ("SOFT", "jerk-limited acceleration"), ("BRISK", "acceleration without jerk limit"),
    ("FFWON", "feedforward control"), ("FFWOF", "feedforward control off"),
    ("COMPOF", "compressor off"), ("COMPCAD", "compressor"), ("COMPCURV", "compressor"), ("COMPSURF", "compressor"),
    ("UPATH", "path parameter of following axes"), ("SPATH", "path parameter of following axes"),
    ("FNORM", "feed normal"), ("CFC", "feed at the contour"), ("CFTCP", "feed at the tool centre"),
    ("CFIN", "feed at inner arcs"), ("DIAMOF", "diameter programming off"), ("TRAFOOF", "transformation off"),
    ("STOPRE", "preprocessing stop"), ("ADISPOS", "rounding of rapid moves"), ("MSG", "operator message"),
    ("WORKPIECE", "blank for the control's simulation"), ("CUT2D", "2D radius compensation in the plane"),
    ("CUT2DF", "2D radius compensation in the frame's plane"),
)
_NOTED_CALLS = ("MSG", "WORKPIECE")
_NOTED = {word: (index, what) for index, (word, what) in enumerate(NOTED)}

# refused keywords: word -> what a program using it would need
REFUSED = (
    ("MCALL", "modal subprogram calls"), ("GOTO", "program jumps"), ("GOTOF", "program jumps"),
    ("GOTOB", "program jumps"), ("GOTOC", "program jumps"), ("IF", "control structures"),
    ("ELSE", "control structures"), ("ENDIF", "control structures"), ("WHILE", "control structures"),
    ("ENDWHILE", "control structures"), ("FOR", "control structures"), ("ENDFOR", "control structures"),
    ("REPEAT", "control structures"), ("UNTIL", "control structures"), ("LOOP", "control structures"),
    ("ENDLOOP", "control structures"), ("CASE", "control structures"), ("DEF", "variable definitions: use R0 to R99"),
    ("CIP", "circles through an intermediate point"), ("CT", "tangential circles"),
    ("ASPLINE", "Akima splines: only BSPLINE"), ("CSPLINE", "cubic splines: only BSPLINE"),
    ("ROTS", "frame rotation is not modelled"), ("AROTS", "frame rotation is not modelled"),
    ("CROTS", "frame rotation is not modelled"), ("TOFRAME", "frame rotation is not modelled"),
    ("TRAORI", "5-axis transformations"), ("TRANSMIT", "kinematic transformations"),
    ("TRACYL", "kinematic transformations"), ("AC", "absolute dimensions per word: program G90"),
    ("IC", "incremental dimensions per word: program G91"), ("PROC", "a PROC line of its own, without parameters"),
)
_REFUSED = dict(REFUSED)

_FUNCTIONS = ("SIN", "COS", "TAN", "SQRT", "ABS", "POT", "TRUNC")
_FRAME_WORDS = ("TRANS", "ATRANS", "ROT", "AROT", "SCALE", "ASCALE", "MIRROR", "AMIRROR")
_PROC_ATTRIBUTES = ("SAVE", "DISPLOF", "DISPLON", "SBLOF", "SBLON")
_KEYWORDS = ("BSPLINE", "RET", "SUPA") + _FRAME_WORDS + _PROC_ATTRIBUTES
_NAMED = ("SD", "PW", "PL", "ADIS", "ADISPOS", "CR", "RPL")
_NUMBER_LETTERS = "NGMXYZIJKFSTDP"
_CYCLE832_TYPES = {"_OFF": 0, "_FINISH": 1, "_SEMIFIN": 2, "_ROUGH": 3, "_ORI_FINISH": 1, "_ORI_SEMIFIN": 2,
                   "_ORI_ROUGH": 3}


def _word_end(s: str, i: int) -> int:
    """The end of the name starting at s[i] (letters, digits, _), refused beyond MAX_WORD characters."""
    j = i
    while j < len(s) and _is_name_char(s[j]):
        j += 1
    if j - i > MAX_WORD:
        raise SinumerikError(f"a word of at most {MAX_WORD} characters")
    return j


class SinumerikError(ValueError):
    """A line the translator refuses; ``expected`` is what was expected (the caller adds file, line and text)."""

    def __init__(self, expected: str):
        self.expected = expected
        super().__init__(expected)


class _Tokens(list):
    """The words of one line, at most MAX_TOKENS."""

    def append(self, token: tuple) -> None:
        if len(self) >= MAX_TOKENS:
            raise SinumerikError(f"at most {MAX_TOKENS} words in a line")
        super().append(token)


_UPPER = {code: code - 32 for code in range(ord("a"), ord("z") + 1)}


def _upper(text: str) -> str:
    """ASCII letters in upper case, every other character as it is (as C's byte-wise upper case)."""
    return text.translate(_UPPER)


def _control_free(text: str) -> bool:
    return all(ord(c) >= 32 and ord(c) != 127 for c in text)


def _is_letter(c: str) -> bool:
    return ("A" <= c <= "Z") or ("a" <= c <= "z")


def _is_digit(c: str) -> bool:
    return "0" <= c <= "9"


def _is_name_char(c: str) -> bool:
    return _is_letter(c) or _is_digit(c) or c == "_"


def _shown(c: str) -> str:
    if " " < c < "\x7f":
        return f"'{c}'"
    if ord(c) < 128:
        return f"byte 0x{ord(c):02x}"
    return "a non-ASCII character"


def format_value(x: float) -> str:
    """A computed value as the core reads it: plain decimal, at most 10 decimals and 17 significant digits."""
    if not abs(x) < VALUE_LIMIT:
        raise SinumerikError("a computed value of magnitude below 1000000000")
    a = abs(x)
    int_digits = 0
    for k in range(9):
        if a >= _POW10[k]:
            int_digits += 1
    decimals = min(10, MAX_SIGNIFICANT_DIGITS - int_digits)
    text = f"{x:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "", "-") else text


def _name_key(name: str) -> str:
    return _upper(name)


class SinumerikTranslator:
    """State of one program's translation: R parameters, the frame, subprogram names, B spline, tool, D."""

    def __init__(self, tools: Sequence = ()):
        self.tool_names: dict[str, int] = {}
        for tool in tools:
            name = getattr(tool, "name", "")
            if name and name not in self.tool_names:
                self.tool_names[name] = int(tool.number)
        self.r: list[float | None] = [None] * R_COUNT
        self.r_section = [0] * R_COUNT  # the program section of each R parameter's last assignment
        self.section = 0                # 0: the main program, 1 + index: a subprogram
        self.frame = [0.0, 0.0, 0.0]
        self.subprograms: list[str] = []
        self.spline = False          # BSPLINE is the motion mode
        self.spline_open = False     # a G5.2 block is open
        self.degree = 3
        self.tool = 0                # the last T (selected)
        self.active = 0              # the tool of the last M6
        self.edge = 0                # the active D (0: none)
        # the program section where the frame, the active tool and D were last set (-1 after a subprogram call:
        # the state then depends on the call, which the translation in file order cannot follow)
        self.frame_section = 0
        self.active_section = 0
        self.edge_section = 0
        self.adis = 0.0
        self.blend = False           # G641..G645 active
        self.after_header = ""       # the subprogram whose %_N_..._SPF header was the last line with content
        self.noted: set[int] = set()
        self.note = ""

    # subprograms ----------------------------------------------------------------------------------------------
    def _register(self, name: str) -> int:
        key = _name_key(name)
        if key in self.subprograms:
            return self.subprograms.index(key)
        if len(self.subprograms) >= MAX_SUBPROGRAMS:
            return -1
        self.subprograms.append(key)
        return len(self.subprograms) - 1

    def prescan(self, text: str) -> None:
        """Numbers the subprograms of the whole text (section headers, PROC lines) in order of appearance."""
        for raw in text.split("\n"):
            line = raw.split(";", 1)[0].strip(" \t\r")
            name = ""
            if _upper(line[:4]) == "%_N_" and _upper(line[-4:]) == "_SPF":
                name = line[4:-4]
            elif _upper(line[:5]) == "PROC " or _upper(line[:5]) == "PROC\t":
                rest = line[5:].lstrip(" \t")
                j = 0
                while j < len(rest) and _is_name_char(rest[j]):
                    j += 1
                name = rest[:j]
            if name and len(name) <= NAME_LENGTH and all(_is_name_char(c) for c in name) and _is_letter(name[0]):
                self._register(name)

    def _call_number(self, name: str) -> int:
        key = _name_key(name)
        if key not in self.subprograms:
            raise SinumerikError(f"subprogram {key} in this file (a %_N_{key}_SPF section)")
        return FIRST_SUBPROGRAM + self.subprograms.index(key)

    def finish(self) -> None:
        """At the end of the text: refuses a B spline still open (no G0-G3, M2, M30, M17 or RET after it)."""
        if self.spline_open:
            raise SinumerikError("the end of the B spline (a line with G0, G1, G2, G3, M2, M30, M17 or RET) before "
                                 "the end of the program")

    # lexing ---------------------------------------------------------------------------------------------------
    def _number(self, s: str, i: int, what: str) -> tuple[float, int, str]:
        """A plain number at s[i:] ([+-]digits[.digits]); (value, next index, text as written)."""
        try:
            value, end = read_number(s, i, what)
        except NumberError as error:
            raise SinumerikError(error.expected) from None
        return value, end, s[i:end]

    def _expression(self, s: str, i: int, depth: int, what: str) -> tuple[float, int]:
        value, i = self._term(s, i, depth, what)
        while True:
            j = self._skip(s, i, depth)
            if j < len(s) and s[j] in "+-":
                op = s[j]
                right, i = self._term(s, j + 1, depth, what)
                value = value + right if op == "+" else value - right
            else:
                return value, i

    def _term(self, s: str, i: int, depth: int, what: str) -> tuple[float, int]:
        value, i = self._unary(s, i, depth, what)
        while True:
            j = self._skip(s, i, depth)
            if j < len(s) and s[j] in "*/":
                op = s[j]
                right, i = self._unary(s, j + 1, depth, what)
                if op == "*":
                    value = value * right
                else:
                    if right == 0.0:
                        raise SinumerikError(f"no division by zero in the expression after {what}")
                    value = value / right
            else:
                return value, i

    @staticmethod
    def _skip(s: str, i: int, depth: int) -> int:
        if depth > 0:
            while i < len(s) and s[i] in " \t":
                i += 1
        return i

    def _unary(self, s: str, i: int, depth: int, what: str) -> tuple[float, int]:
        negative = False
        i = self._skip(s, i, depth)
        while i < len(s) and s[i] in "+-":
            if s[i] == "-":
                negative = not negative
            i = self._skip(s, i + 1, depth)
        value, i = self._primary(s, i, depth, what)
        return (-value if negative else value), i

    def _primary(self, s: str, i: int, depth: int, what: str) -> tuple[float, int]:
        n = len(s)
        if i < n and (_is_digit(s[i]) or s[i] == "."):
            value, i, _ = self._number(s, i, what)
            return value, i
        if i < n and s[i] == "(":
            if depth >= MAX_NESTING:
                raise SinumerikError(f"at most {MAX_NESTING} nested parentheses in the expression after {what}")
            value, i = self._expression(s, i + 1, depth + 1, what)
            i = self._skip(s, i, depth + 1)
            if i >= n or s[i] != ")":
                raise SinumerikError(f"')' to close the parenthesis in the expression after {what}")
            return value, i + 1
        if i < n and s[i] == "$":
            j = _word_end(s, i + 1)
            raise SinumerikError(f"{_upper(s[i:j])} is not supported (system variables: use R0 to R99)")
        if i < n and (_is_letter(s[i]) or s[i] == "_"):
            j = _word_end(s, i)
            name = _upper(s[i:j])
            if name[0] == "R" and len(name) > 1 and all(_is_digit(c) for c in name[1:]):
                index = int(name[1:]) if len(name) <= 4 else R_COUNT
                if index >= R_COUNT:
                    raise SinumerikError(f"an R parameter R0 to R{R_COUNT - 1}, got {name}")
                value = self.r[index]
                if value is None:
                    raise SinumerikError(f"R{index} set before it is used (R{index}=...)")
                if self.r_section[index] != self.section:
                    raise SinumerikError(f"R{index} set in this program section before it is used (R parameters "
                                         f"are evaluated once, in the order of the file, not per subprogram call)")
                return value, j
            k = self._skip(s, j, depth + 1)
            if k < n and s[k] == "(":
                if name not in _FUNCTIONS:
                    if name in ("AC", "IC"):
                        raise SinumerikError(f"{name} is not supported ({_REFUSED[name]})")
                    raise SinumerikError(f"the function {name} is not supported (SIN, COS, TAN, SQRT, ABS, POT, "
                                         f"TRUNC)")
                if depth >= MAX_NESTING:
                    raise SinumerikError(f"at most {MAX_NESTING} nested parentheses in the expression after {what}")
                arg, k = self._expression(s, k + 1, depth + 1, what)
                k = self._skip(s, k, depth + 1)
                if k >= n or s[k] != ")":
                    raise SinumerikError(f"')' to close {name}( in the expression after {what}")
                return self._function(name, arg), k + 1
            raise SinumerikError(f"a number, an R parameter, '(' or a function in the expression after {what}, "
                                 f"got {name}")
        got = _shown(s[i]) if i < n else "the end of the line"
        raise SinumerikError(f"a number, an R parameter, '(' or a function in the expression after {what}, "
                             f"got {got}")

    @staticmethod
    def _function(name: str, x: float) -> float:
        if name in ("SIN", "COS", "TAN"):
            a = x * DEGREE
            if math.isinf(a):
                return math.nan          # as C's sin(inf): refused as not finite at the end of the expression
            return math.sin(a) if name == "SIN" else math.cos(a) if name == "COS" else math.tan(a)
        if name == "SQRT":
            if x < 0.0:
                raise SinumerikError("SQRT of a number >= 0")
            return math.sqrt(x)
        if name == "ABS":
            return abs(x)
        if name == "POT":
            return x * x
        return float(math.trunc(x)) if math.isfinite(x) else x

    def _value(self, s: str, i: int, what: str) -> tuple[float, int]:
        """The expression after '=' (blanks after '=' allowed); checks that the value is finite."""
        while i < len(s) and s[i] in " \t":
            i += 1
        value, i = self._expression(s, i, 0, what)
        if i < len(s) and s[i] not in " \t;":
            raise SinumerikError(f"an operator, a blank or the end of the line after the value of {what}=, got "
                                 f"{_shown(s[i])}")
        if not math.isfinite(value):
            raise SinumerikError(f"a finite value of the expression after {what}")
        return value, i

    def _skip_parenthesis(self, s: str, i: int, name: str) -> int:
        """s[i] == '(': the index after the matching ')' (quoted strings skipped)."""
        depth, quoted = 0, False
        while i < len(s):
            c = s[i]
            if quoted:
                if c == '"':
                    quoted = False
            elif c == '"':
                quoted = True
            elif c == "(":
                depth += 1
            elif c == ")":
                depth -= 1
                if depth == 0:
                    return i + 1
            i += 1
        raise SinumerikError(f"')' to close {name}(")

    def _lex(self, s: str) -> list[tuple]:
        """Tokens of the line; R assignments are carried out here, left to right."""
        tokens: list[tuple] = _Tokens()
        n = len(s)
        i = 0
        while i < n:
            c = s[i]
            if c in " \t":
                i += 1
                continue
            if c == ";":
                break
            if c == ":" and i + 1 < n and _is_digit(s[i + 1]):
                value, i, text = self._number(s, i + 1, "':'")
                tokens.append(("N", text))
                continue
            if c == "$":
                j = _word_end(s, i + 1)
                raise SinumerikError(f"{_upper(s[i:j])} is not supported (system variables: use R0 to R99)")
            if not (_is_letter(c) or c == "_"):
                raise SinumerikError(f"a word (address and value), a keyword, a comment (;) or the end of the line, "
                                     f"got {_shown(c)}")
            letter = _upper(c)
            if i + 1 < n and (_is_digit(s[i + 1]) or s[i + 1] == "."):
                # address letter and number: X10, G641, R1=..., L10
                j = i + 1
                while j < n and _is_digit(s[j]):
                    j += 1
                k = j
                while k < n and s[k] in " \t":
                    k += 1
                if j > i + 1 and k < n and s[k] == "=":
                    if j - i > MAX_WORD:
                        raise SinumerikError(f"a word of at most {MAX_WORD} characters")
                    word = _upper(s[i:j])
                    if letter != "R":
                        raise SinumerikError(f"{word}= is not supported (addresses with an extension)")
                    index = int(s[i + 1:j]) if j - i - 1 <= 3 else R_COUNT
                    if index >= R_COUNT:
                        raise SinumerikError(f"an R parameter R0 to R{R_COUNT - 1}, got {word}")
                    value, i = self._value(s, k + 1, word)
                    self.r[index] = value
                    self.r_section[index] = self.section
                    continue
                if letter == "L" and j > i + 1:
                    if j < n and _is_name_char(s[j]):
                        if j + 1 - i > MAX_WORD:
                            raise SinumerikError(f"a word of at most {MAX_WORD} characters")
                        raise SinumerikError(f"{_upper(s[i:j + 1])}... is not supported (a subprogram L<digits>)")
                    if j - i > NAME_LENGTH:
                        raise SinumerikError(f"a subprogram name of at most {NAME_LENGTH} characters")
                    tokens.append(("CALL", "L" + s[i + 1:j]))
                    i = j
                    continue
                if letter not in _NUMBER_LETTERS:
                    raise SinumerikError(self._letter_refusal(letter))
                value, i, text = self._number(s, i + 1, letter)
                tokens.append(("W", letter, value, text))
                continue
            j = _word_end(s, i)
            word = _upper(s[i:j])
            k = j
            while k < n and s[k] in " \t":
                k += 1
            if len(word) == 1 and k < n and s[k] in "+-" and word in _NUMBER_LETTERS and k == j:
                value, i, text = self._number(s, j, word)
                tokens.append(("W", word, value, text))
                continue
            if k < n and s[k] == "=":
                i = self._named(s, word, k + 1, tokens)
                continue
            if k < n and s[k] == "(":
                if word in _NOTED_CALLS:
                    tokens.append(("NOTE", word))
                    i = self._skip_parenthesis(s, k, word)
                    continue
                if word == "CYCLE832":
                    i = self._cycle832(s, k, tokens)
                    continue
                if word in _REFUSED:
                    raise SinumerikError(f"{word} is not supported ({_REFUSED[word]})")
                raise SinumerikError(f"{word} is not supported (cycles and procedures with arguments: let the CAM "
                                     f"post write their moves)")
            if j < n and s[j] == ":" and _is_letter(word[0]):
                i = j + 1            # a jump label (no GOTO is accepted: it has no effect)
                continue
            if word == "CALL":
                if k < n and s[k] == '"':
                    e = s.find('"', k + 1)
                    if e < 0:
                        raise SinumerikError('a closing \'"\' after CALL "')
                    if e - k - 1 > NAME_LENGTH:
                        raise SinumerikError(f"a subprogram name of at most {NAME_LENGTH} characters")
                    if not _control_free(s[k + 1:e]):
                        raise SinumerikError("a subprogram name without control characters")
                    tokens.append(("CALL", s[k + 1:e]))
                    i = e + 1
                    continue
                raise SinumerikError('CALL "<subprogram name>"')
            if word == "PROC":
                i = self._proc(s, k, tokens)
                continue
            if len(word) == 1:
                if word in _NUMBER_LETTERS:
                    raise SinumerikError(f"a number after {word}")
                raise SinumerikError(self._letter_refusal(word))
            if word in _KEYWORDS or word in _NOTED:
                tokens.append(("K", word))
            elif self._subprogram_index(word) >= 0:
                tokens.append(("CALL", word))
            elif word in _REFUSED:
                raise SinumerikError(f"{word} is not supported ({_REFUSED[word]})")
            else:
                raise SinumerikError(f"{word} is not supported (a subprogram of this name in this file, a "
                                     f"%_N_{word}_SPF section, or a word the translator knows)")
            i = j
        return tokens

    @staticmethod
    def _letter_refusal(letter: str) -> str:
        if letter in "ABCUVWE":
            return f"{letter} is not supported (rotary and additional axes: X, Y, Z only)"
        if letter == "H":
            return "H is not supported (auxiliary functions)"
        if letter == "R":
            return "R<n>=<value> (R parameters are assigned with =)"
        return f"{letter} is not supported (a word N, G, M, X, Y, Z, I, J, K, F, S, T, D, L, P or R<n>=)"

    def _named(self, s: str, word: str, i: int, tokens: list) -> int:
        """<word>=<value> at s[i:] (after '='): T="name", X=expr, SD=..., returns the next index."""
        if word == "T":
            j = i
            while j < len(s) and s[j] in " \t":
                j += 1
            if j < len(s) and s[j] == '"':
                e = s.find('"', j + 1)
                if e < 0:
                    raise SinumerikError('a closing \'"\' after T="')
                name = s[j + 1:e]
                if len(name) > NAME_LENGTH:
                    raise SinumerikError(f"a tool name of at most {NAME_LENGTH} characters")
                if not _control_free(name):
                    raise SinumerikError("a tool name without control characters")
                if name not in self.tool_names:
                    raise SinumerikError(f'a tool named "{name}" in the tool table (none has this name)')
                tokens.append(("W", "T", float(self.tool_names[name]), str(self.tool_names[name])))
                return e + 1
        if len(word) == 1 and word in _NUMBER_LETTERS and word not in "NGMP":
            value, i = self._value(s, i, word)
            tokens.append(("W", word, value, format_value(value)))
            return i
        if word in _NAMED:
            value, i = self._value(s, i, word)
            tokens.append(("NAMED", word, value, format_value(value)))
            return i
        if word in ("AP", "RP"):
            raise SinumerikError(f"{word}= is not supported (polar coordinates)")
        if len(word) == 1:
            raise SinumerikError(self._letter_refusal(word) if word not in _NUMBER_LETTERS
                                 else f"{word}= is not supported (write {word}<number>)")
        raise SinumerikError(f"{word}= is not supported (settings the translator knows: SD, PW, PL, ADIS, ADISPOS, "
                             f"CR, RPL)")

    def _cycle832(self, s: str, k: int, tokens: list) -> int:
        """CYCLE832(<tolerance>, <machining type>, ...): s[k] == '('."""
        end = self._skip_parenthesis(s, k, "CYCLE832")
        i = k + 1
        while i < end and s[i] in " \t":
            i += 1
        tolerance = 0.0
        if s[i] not in ",)":
            tolerance, i = self._expression(s, i, 1, "CYCLE832(")
            while s[i] in " \t":
                i += 1
            if s[i] not in ",)":
                raise SinumerikError(f"',' or ')' after the tolerance of CYCLE832, got {_shown(s[i])}")
        if not (math.isfinite(tolerance) and tolerance >= 0.0):
            raise SinumerikError("a tolerance >= 0 in CYCLE832")
        kind = 1
        if s[i] == ",":
            i += 1
            while s[i] in " \t":
                i += 1
            j = _word_end(s, i)
            word = _upper(s[i:j])
            if word in _CYCLE832_TYPES:
                kind = _CYCLE832_TYPES[word]
            elif word and all(_is_digit(ch) for ch in word):
                kind = ord(word[-1]) - 48
            elif word:
                raise SinumerikError(f"a machining type of CYCLE832 (_OFF, _ROUGH, _SEMIFIN, _FINISH or a number), "
                                     f"got {word}")
        tokens.append(("CYCLE832", tolerance if kind != 0 else 0.0))
        return end

    def _proc(self, s: str, k: int, tokens: list) -> int:
        j = _word_end(s, k)
        name = _upper(s[k:j])
        if not name or not _is_letter(name[0]):
            raise SinumerikError("a subprogram name after PROC")
        if len(name) > NAME_LENGTH:
            raise SinumerikError(f"a subprogram name of at most {NAME_LENGTH} characters")
        m = j
        while m < len(s) and s[m] in " \t":
            m += 1
        if m < len(s) and s[m] == "(":
            raise SinumerikError(f"PROC {name} is not supported with parameters (subprograms without parameters)")
        tokens.append(("PROC", name))
        return j

    # translation ----------------------------------------------------------------------------------------------
    def _add_note(self, word: str, notes: list[str]) -> None:
        index, what = _NOTED[word]
        if index not in self.noted:
            self.noted.add(index)
            notes.append(f"{word}: {what}: not modelled")

    def translate(self, line: str) -> str:
        """One line of the Sinumerik program -> one line of the core syntax (raises SinumerikError)."""
        self.note = ""
        s = line.rstrip("\r")
        i = 0
        while i < len(s) and s[i] in " \t":
            i += 1
        if i >= len(s) or s[i] == ";":
            return ""
        if s[i] == "%":
            return self._header(s[i:])
        if s[i] == "/":
            return ""
        tokens = self._lex(s)
        if not tokens:
            return ""
        after_header = self.after_header
        self.after_header = ""
        notes: list[str] = []
        out = self._line(tokens, after_header, notes)
        if len(out) > MAX_OUTPUT:
            raise SinumerikError(f"a translated line of at most {MAX_OUTPUT} characters")
        self.note = "; ".join(notes)
        return out

    def _header(self, s: str) -> str:
        text = s.split(";", 1)[0].rstrip(" \t")
        if text == "%":
            return ""
        if _upper(text[:4]) == "%_N_" and _upper(text[-4:]) in ("_MPF", "_SPF") and len(text) > 8:
            name = _upper(text[4:-4])
            if len(name) > NAME_LENGTH or not all(_is_name_char(c) for c in name) or not _is_letter(name[0]):
                raise SinumerikError(f"a program name of at most {NAME_LENGTH} letters, digits and _ (starting with a "
                                     f"letter)")
            if self.spline_open:
                raise SinumerikError("the end of the B spline (a line with G0, G1, G2, G3, M2, M30, M17 or RET) "
                                     "before the next program section")
            self.spline = False
            self.after_header = ""
            if _upper(text[-4:]) == "_MPF":
                self.section = 0
                return ""
            index = self._register(name)
            if index < 0:
                raise SinumerikError(f"at most {MAX_SUBPROGRAMS} subprograms in one file")
            self.after_header = name
            self.section = 1 + index
            return f"O{FIRST_SUBPROGRAM + index}"
        raise SinumerikError("a section header %_N_<name>_MPF or %_N_<name>_SPF, or % alone")

    def _line(self, tokens: list[tuple], after_header: str, notes: list[str]) -> str:
        for t in tokens:
            if t[0] == "K" and t[1] in _FRAME_WORDS:
                return self._frame(tokens, t[1])
        for t in tokens:
            if t[0] == "PROC":
                return self._proc_line(tokens, t[1], after_header)
        # what the line holds
        gs: list[int] = []
        ms: list[int] = []
        named: dict[str, tuple] = {}
        has_axes = bspline = ret = False
        calls = 0
        for t in tokens:
            if t[0] == "W" and t[1] in "GM":
                if not (-1e6 < t[2] < 1e6 and t[2] == int(t[2])):
                    raise SinumerikError(f"{t[1]}{t[3]} is not supported")
                (gs if t[1] == "G" else ms).append(int(t[2]))
            elif t[0] == "W" and t[1] in "XYZ":
                has_axes = True
            elif t[0] == "NAMED":
                named[t[1]] = t
            elif t[0] == "K":
                bspline = bspline or t[1] == "BSPLINE"
                ret = ret or t[1] == "RET"
                if t[1] in _PROC_ATTRIBUTES:
                    raise SinumerikError(f"{t[1]} is not supported (an attribute of a PROC line)")
            elif t[0] == "CALL":
                calls += 1
        if calls > 1:
            raise SinumerikError("one subprogram call per line")
        if "RPL" in named:
            raise SinumerikError("RPL= with ROT or AROT")
        motion = any(g in (0, 1, 2, 3) for g in gs)
        closes = motion or ret or any(m in (2, 17, 30) for m in ms)
        # B spline mode
        pieces: list[str] = []
        if self.spline_open and closes:
            if has_axes and not motion:
                raise SinumerikError("the end of the program or subprogram in a line after the last B spline point")
            pieces.append("G5.3")
            self.spline_open = False
        if bspline and motion:
            raise SinumerikError("either BSPLINE or G0, G1, G2, G3 in a line (both select the motion)")
        if closes:
            self.spline = False
        if bspline:
            self.spline = True
        if "SD" in named:
            if named["SD"][2] not in (2.0, 3.0):
                raise SinumerikError(f"a B spline degree SD of 2 or 3, got SD={named['SD'][3]}")
            if self.spline_open:
                raise SinumerikError("SD before the first point of the B spline")
            self.degree = int(named["SD"][2])
        for key, what in (("PW", "weight"), ("PL", "knot interval")):
            if key in named:
                if not self.spline:
                    raise SinumerikError(f"{key} in BSPLINE mode (the {what} of a B spline point)")
                if not has_axes:
                    raise SinumerikError(f"{key} with the point (X, Y, Z) it belongs to")
        spline_point = self.spline and has_axes
        opening = spline_point and not self.spline_open
        g4 = 4 in gs
        if g4 and has_axes:
            raise SinumerikError("G4 in a line of its own (with F, the dwell in seconds)")
        # the tool, the tool change and D first: D1 and G41/G42 refer to the tool active after the line's M6
        for t in tokens:
            if t[0] == "W" and t[1] == "T":
                if not (t[2] == int(t[2]) and 0 <= t[2] <= 2147483647):
                    raise SinumerikError(f"a tool number T of 0 to 2147483647, got T{t[3]}")
                self.tool = int(t[2])
        if 6 in ms:
            self.active = self.tool
            self.active_section = self.section
        edge_set = False
        for t in tokens:
            if t[0] == "W" and t[1] == "D":
                if t[2] not in (0.0, 1.0):
                    raise SinumerikError(f"D{t[3]} is not supported (one cutting edge per tool: D1, or D0)")
                if t[2] == 1.0 and self.active_section != self.section:
                    raise SinumerikError("a tool change (T<n> M6) in this program section before D1, without a "
                                         "subprogram call between (the tool here depends on the calls)")
                if t[2] == 1.0 and self.active == 0:
                    raise SinumerikError("a tool change (T<n> M6) before D1")
                self.edge = int(t[2])
                self.edge_section = self.section
                edge_set = True
        if "ADIS" in named:
            if not named["ADIS"][2] >= 0.0:
                raise SinumerikError(f"ADIS >= 0, got ADIS={named['ADIS'][3]}")
            self.adis = named["ADIS"][2]
        count = ""
        for t in tokens:
            if t[0] == "W" and t[1] == "P":
                if not calls:
                    raise SinumerikError("P (the number of passes) with a subprogram call")
                if not (t[2] == int(t[2]) and 1 <= t[2] <= 9999):
                    raise SinumerikError(f"a number of passes P of 1 to 9999, got P{t[3]}")
                count = f" L{int(t[2])}"
        blend_set = False
        first_axis = True
        for t in tokens:
            kind = t[0]
            if kind == "N":
                pieces.append(f"N{t[1]}")
            elif kind == "W":
                letter = t[1]
                if letter == "N":
                    pieces.append(f"N{t[3]}")
                elif letter == "G":
                    code = int(t[2])
                    piece = self._g(code, notes)
                    if piece:
                        pieces.append(piece)
                    blend_set = blend_set or 641 <= code <= 645
                elif letter == "M":
                    pieces.append(self._m(int(t[2])))
                elif letter in "XYZ":
                    if opening and first_axis:
                        pieces.append(f"G5.2 L{self.degree + 1}")
                    first_axis = False
                    pieces.append(f"{letter}{t[3]}")
                elif letter in "IJK":
                    if self.spline:
                        raise SinumerikError(f"{letter} is not supported in BSPLINE mode (arc words)")
                    pieces.append(f"{letter}{t[3]}")
                elif letter == "F":
                    pieces.append(f"P{t[3]}" if g4 else f"F{t[3]}")
                elif letter == "S":
                    if g4:
                        raise SinumerikError("G4 S is not supported (dwell in spindle revolutions: program G4 F<s>)")
                    pieces.append(f"S{t[3]}")
                elif letter == "T":
                    pieces.append(f"T{int(t[2])}")
                elif letter == "D":
                    pieces.append(f"G43 H{self.active}" if t[2] == 1.0 else "G49")
            elif kind == "NAMED":
                word = t[1]
                if word == "CR":
                    if self.spline:
                        raise SinumerikError("CR is not supported in BSPLINE mode (arc words)")
                    pieces.append(f"R{t[3]}")
                elif word == "ADIS":
                    if self.blend and not blend_set:
                        pieces.append(f"G64 P{t[3]}" if t[2] > 0.0 else "G64")
                elif word == "ADISPOS":
                    self._add_note("ADISPOS", notes)
            elif kind == "K":
                if t[1] == "RET":
                    pieces.append("M99")
                elif t[1] == "SUPA":
                    pieces.append("G53")
                elif t[1] in _NOTED:
                    self._add_note(t[1], notes)
            elif kind == "NOTE":
                self._add_note(t[1], notes)
            elif kind == "CALL":
                if self.spline:
                    raise SinumerikError("the end of the B spline (G0, G1, G2, G3) before a subprogram call (the "
                                         "called program's points would continue the spline)")
                pieces.append(f"M98 P{self._call_number(t[1])}{count}")
                self.frame_section = self.active_section = self.edge_section = -1
            elif kind == "CYCLE832":
                pieces.append(f"G64 P{format_value(t[1])}" if t[1] > 0.0 else "G64")
                self.blend = False
        if spline_point:
            self.spline_open = True
            if "PW" in named:
                if not named["PW"][2] > 0.0:
                    raise SinumerikError(f"a point weight PW > 0, got PW={named['PW'][3]}")
                pieces.append(f"P{named['PW'][3]}")
            if "PL" in named:
                if not named["PL"][2] > 0.0:
                    raise SinumerikError(f"a knot interval PL > 0, got PL={named['PL'][3]}")
                pieces.append(f"K{named['PL'][3]}")
        if 6 in ms and self.edge == 1 and self.edge_section == self.section and not edge_set:
            pieces.append(f"G43 H{self.active}")
        return " ".join(pieces)

    def _proc_line(self, tokens: list[tuple], name: str, after_header: str) -> str:
        """PROC <name>: nothing right after its own section header, else O<n> alone (the core's program number
        line; a block number N is dropped)."""
        pieces: list[str] = []
        for t in tokens:
            if not (t[0] == "N" or (t[0] == "W" and t[1] == "N") or t[0] == "PROC"
                    or (t[0] == "K" and t[1] in _PROC_ATTRIBUTES)):
                raise SinumerikError("PROC <name> in a line of its own")
        if self.spline_open:
            raise SinumerikError("the end of the B spline (a line with G0, G1, G2, G3, M2, M30, M17 or RET) "
                                 "before the next program section")
        self.spline = False
        if name != after_header:
            index = self._register(name)
            if index < 0:
                raise SinumerikError(f"at most {MAX_SUBPROGRAMS} subprograms in one file")
            self.section = 1 + index
            pieces.append(f"O{FIRST_SUBPROGRAM + index}")
        return " ".join(pieces)

    def _subprogram_index(self, name: str) -> int:
        key = _name_key(name)
        return self.subprograms.index(key) if key in self.subprograms else -1

    def _g(self, code: int, notes: list[str]) -> str:
        """The core form of G<code> ("" for an accepted, not modelled code)."""
        if code in (0, 1, 2, 3, 4, 9, 17, 18, 19, 40, 53, 54, 55, 56, 57, 90, 91, 94, 95, 500):
            return f"G{code}"
        if code in (41, 42):
            if self.edge_section != self.section:
                raise SinumerikError(f"D1 in this program section before G{code}, without a subprogram call between "
                                     f"(the tool here depends on the calls)")
            if self.edge != 1:
                raise SinumerikError(f"G{code} with an active tool offset (D1 after the tool change)")
            return f"G{code} D{self.active}"
        if code == 153:
            return "G53"
        if code == 60:
            self.blend = False
            return "G61"
        if code == 64:
            self.blend = False
            return "G64"
        if 641 <= code <= 645:
            self.blend = True
            return f"G64 P{format_value(self.adis)}" if self.adis > 0.0 else "G64"
        if code in (70, 700):
            return "G20"
        if code in (71, 710):
            return "G21"
        if code in (601, 602, 603, 450, 451):
            self._add_note(f"G{code}", notes)
            return ""
        if code in (58, 59):
            need = "axial programmable offsets"
        elif 505 <= code <= 599:
            need = "settable work offsets beyond G57"
        elif 110 <= code <= 112:
            need = "polar coordinates"
        else:
            need = ("G codes the translator knows: G0-G4, G9, G17-G19, G40-G42, G53-G57, G60, G64, G641-G645, G70, "
                    "G71, G90, G91, G94, G95, G153, G500, G700, G710")
        raise SinumerikError(f"G{code} is not supported ({need})")

    @staticmethod
    def _m(code: int) -> str:
        if code in (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 19, 30):
            return f"M{code}"
        if code == 17:
            return "M99"
        raise SinumerikError(f"M{code} is not supported (M0-M9, M17, M19, M30)")

    def _frame(self, tokens: list[tuple], word: str) -> str:
        values: dict[str, float] = {}
        pieces: list[str] = []
        rpl = 0.0
        for t in tokens:
            if t[0] == "N":
                pieces.append(f"N{t[1]}")
            elif t[0] == "W" and t[1] == "N":
                pieces.append(f"N{t[3]}")
            elif t[0] == "W" and t[1] in "XYZ" and t[1] not in values:
                values[t[1]] = t[2]
            elif t[0] == "NAMED" and t[1] == "RPL" and word in ("ROT", "AROT"):
                rpl = t[2]
            elif not (t[0] == "K" and t[1] == word):
                raise SinumerikError(f"{word} in a line of its own, with N and the axes X, Y, Z (frame instructions)")
        clear = False
        if word == "ATRANS" and self.frame_section != self.section:
            raise SinumerikError("TRANS in this program section before ATRANS, without a subprogram call between (the "
                                 "frame here depends on the calls)")
        if word in ("TRANS", "ATRANS"):
            for a, letter in enumerate("XYZ"):
                if word == "TRANS":
                    self.frame[a] = values.get(letter, 0.0)
                else:
                    self.frame[a] = self.frame[a] + values.get(letter, 0.0)
        elif word in ("ROT", "AROT"):
            if rpl != 0.0 or any(v != 0.0 for v in values.values()):
                raise SinumerikError(f"{word} with angles 0 (frame rotation is not modelled)")
            clear = word == "ROT"
        elif word in ("SCALE", "ASCALE"):
            if any(v != 1.0 for v in values.values()):
                raise SinumerikError(f"{word} with factors 1 (frame scaling is not modelled)")
            clear = word == "SCALE"
        else:
            if values:
                raise SinumerikError(f"{word} without axes (mirroring is not modelled)")
            clear = word == "MIRROR"
        if word in ("AROT", "ASCALE", "AMIRROR"):
            return " ".join(pieces)
        if clear:
            self.frame = [0.0, 0.0, 0.0]
        self.frame_section = self.section
        pieces.append("G52 " + " ".join(f"{letter}{format_value(self.frame[a])}" for a, letter in enumerate("XYZ")))
        return " ".join(pieces)

"""A part program with new feeds: only F words changed, every line where it was, checked by parsing both.

:func:`rewrite_feeds` takes the program text and a feed factor per program line (1-based; the lines the optimizer
changes) and returns the text with each of those lines' feed moves at ``factor x`` their programmed feed. F is
modal, so a line that inherits its feed gets an F word of its own, and the line after a changed one gets back the
feed it had (an F word where the new program's modal feed differs from the one that line must run at). The value
written is the old F word's value times the factor, in the program's own units (mm/min, in/min, or mm/rev under
G95: the factor applies to any of them), with at least four significant digits. Nothing else of a line changes:
its other words, spacing, comments, line numbers and line endings stay as they are.

The result is parsed again with the Interpolator's own parser and compared move by move with the original: the
same moves (kind, line, geometry, spindle, tool) and each feed move's feed the factor of its line times the old
one (to the written digits). A program this cannot rewrite exactly is refused with a :class:`ProgramEditError`
naming the file and line: a feed given by an expression (Sinumerik ``F=R1``), or lines run out of their order
(a subprogram called, a jump: the F a line inherits then depends on the call).
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path

from milling_twin.models.interpolator.parser import (DIALECT_SINUMERIK, DIALECTS, MOVE_DWELL, MOVE_RAPID, Move,
                                                     Program, ProgramError, word_spans)
from milling_twin.orchestrator.part.blocks import feed_lines

__all__ = ["FEED_DIGITS", "ProgramEditError", "EditedProgram", "rewrite_feeds", "format_feed"]

FEED_DIGITS = 4            # significant digits at least of a written F value
# Sinumerik: an F address (not part of a longer name: FGROUP, FFWON, AFIS), and its numeric forms F1000, F=1000.5
_SINUMERIK_F_AT = re.compile(r"(?<![A-Za-z0-9_$])F(?=\s*=|\s*[\d.+-])", re.IGNORECASE)
_SINUMERIK_F_NUMBER = re.compile(r"F(\s*=\s*|)([+-]?(?:\d+\.?\d*|\.\d+))(?![\w.\[(*/+-])", re.IGNORECASE)
_SINUMERIK_S_AT = re.compile(r"(?<![A-Za-z0-9_$])S(?=\s*=|\s*[\d.+-])", re.IGNORECASE)
_SINUMERIK_S_NUMBER = re.compile(r"S(\s*=\s*|)([+-]?(?:\d+\.?\d*|\.\d+))(?![\w.\[(*/+-])", re.IGNORECASE)
# geometry and machine state a rewritten program must keep, move by move (everything but the feed)
_KEPT = tuple(f.name for f in fields(Move) if f.name != "feed")


class ProgramEditError(ValueError):
    """A program the optimizer cannot rewrite: ``file line N: "text": why``."""


@dataclass(frozen=True)
class EditedProgram:
    text: str
    changed_lines: tuple[int, ...]      # lines whose text changed (an F word replaced or added)
    factors: dict[int, float]           # the factor each feed-move line runs at (1 where unchanged)
    speeds: dict[int, float] = field(default_factory=dict)  # the spindle speed ratio of each tool whose S changed


def format_feed(value: float) -> str:
    """An F value with at least FEED_DIGITS significant digits and a decimal point (1663.2, 0.1234, 12.50)."""
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"a feed must be a positive number, got {value!r}")
    decimals = max(1, FEED_DIGITS - 1 - math.floor(math.log10(value)))
    return f"{value:.{decimals}f}"


def _split_code_comment(raw: str, sinumerik: bool) -> int:
    """Index where the line's trailing comment starts (';', and for Fanuc/LinuxCNC a '(' comment at the end is
    kept where it is by inserting before the first comment), len(raw) without one."""
    if sinumerik:
        at = raw.find(";")
        return len(raw) if at < 0 else at
    for i, c in enumerate(raw):
        if c in "(;":
            return i
    return len(raw)


@dataclass(frozen=True)
class _Word:
    start: int
    end: int
    value: float
    text: str        # the number as written


def _too_long(raw: str) -> str:
    return raw.strip()[:80]


def _words(raw: str, file: str, line: int, sinumerik: bool, letter: str = "F") -> list[_Word]:
    """The F (or S) words of one program line with their spans."""
    if sinumerik:
        at_re, number_re = (_SINUMERIK_F_AT, _SINUMERIK_F_NUMBER) if letter == "F" else \
            (_SINUMERIK_S_AT, _SINUMERIK_S_NUMBER)
        code = raw[:_split_code_comment(raw, True)]
        found = []
        for at in at_re.finditer(code):
            number = number_re.match(code, at.start())
            if number is None:
                what = "feed" if letter == "F" else "spindle speed"
                raise ProgramEditError(f'{file} line {line}: "{_too_long(raw)}": the {what} is an expression; the '
                                       f"optimizer writes numeric {letter} words only (give the {what} as a number)")
            found.append(_Word(number.start(), number.end(), float(number.group(2)), number.group(2)))
        return found
    try:
        words = word_spans(raw, file, line)
    except ProgramError as exc:
        raise ProgramEditError(str(exc)) from None
    return [_Word(a, b, value, text) for word, value, text, a, b in words if word == letter]


def _check_in_order(program: Program, file: str, lines: list[str]) -> None:
    last = 0
    for move in program.moves:
        if move.line < last:
            raise ProgramEditError(
                f'{file} line {move.line}: "{lines[move.line - 1].strip()[:80]}": runs after line {last} (a '
                f"subprogram call or a jump); the optimizer rewrites programs whose lines run in their order")
        last = move.line


def _next_tools(program: Program, n_lines: int) -> list[int]:
    """For each line (index), the tool of the first move at or after it (what an S word there is for)."""
    first: dict[int, int] = {}
    for move in program.moves:
        first.setdefault(move.line, move.tool)
    tools, current = [0] * n_lines, -1
    for index in range(n_lines - 1, -1, -1):
        current = first.get(index + 1, current)
        tools[index] = current
    return tools


def rewrite_feeds(text: str, factors: Mapping[int, float], parse, file: str = "program.nc",
                  dialect: str = "fanuc", speeds: Mapping[int, float] | None = None) -> EditedProgram:
    """``text`` with each feed move of line L at ``factors[L]`` x its feed (lines not in ``factors``: 1), and each
    S word for tool T (the tool of the next move) at ``speeds[T]`` x its value, rounded to whole rpm.

    ``parse(text) -> Program`` is the Interpolator's parser with the part's settings (tools, machine): the
    original is parsed to find the feed moves, the result to check it."""
    sinumerik = DIALECTS[dialect] == DIALECT_SINUMERIK
    speeds = {tool: ratio for tool, ratio in (speeds or {}).items() if ratio != 1.0}
    original = parse(text)
    keep_ends = text.splitlines(keepends=True)
    lines = [ln.rstrip("\r\n") for ln in keep_ends]
    _check_in_order(original, file, lines)
    moving = feed_lines(original)
    next_tool = _next_tools(original, len(lines)) if speeds else []
    for line, factor in factors.items():
        if line not in moving:
            raise ProgramEditError(f"{file} line {line}: no feed move on this line to change the feed of")
        if not (math.isfinite(factor) and factor > 0.0):
            raise ProgramEditError(f"{file} line {line}: feed factor {factor!r} is not a positive number")
    old_modal: _Word | None = None     # the F word in force in the original, line by line
    new_modal: float | None = None      # the F value in force in the rewritten program
    out: list[str] = []
    changed: list[int] = []
    used: dict[int, float] = {}
    speed_used: dict[int, float] = {}
    for index, raw in enumerate(lines):
        number = index + 1
        skipped = raw.lstrip(" \t").startswith("/")  # block skip: the parser leaves the line out
        words = _words(raw, file, number, sinumerik) if "f" in raw.lower() and not skipped else []
        if len(words) > 1:
            raise ProgramEditError(f'{file} line {number}: "{_too_long(raw)}": more than one F word')
        own = words[0] if words else None
        if own is not None:
            old_modal = own
        edits: list[tuple[int, int, str]] = []   # (start, end, replacement) in raw
        if number in moving:
            if old_modal is None:
                raise ProgramEditError(f'{file} line {number}: "{_too_long(raw)}": a feed move with no F word '
                                       f"before it")
            factor = float(factors.get(number, 1.0))
            # the value this line must run at, as written: the old word itself when the factor is 1
            value = old_modal.text if factor == 1.0 else format_feed(old_modal.value * factor)
            want = float(value)
            if own is not None and want != own.value:
                edits.append((own.start, own.end, _f_text(raw[own.start:own.end], value, sinumerik)))
            elif own is None and want != new_modal:
                edits.append(_f_insertion(raw, value, sinumerik))
            new_modal = want
            used[number] = want / old_modal.value
        elif own is not None:
            new_modal = own.value
        if speeds and not skipped and "s" in raw.lower() and next_tool[index] in speeds:
            tool = next_tool[index]
            for word in _words(raw, file, number, sinumerik, "S"):
                new_speed = float(round(word.value * speeds[tool]))
                edits.append((word.start, word.end, _f_text(raw[word.start:word.end], f"{new_speed:.0f}",
                                                            sinumerik)))
                speed_used[tool] = new_speed / word.value if word.value else 1.0
        new_line = raw
        for start, end, replacement in sorted(edits, reverse=True):
            new_line = new_line[:start] + replacement + new_line[end:]
        if new_line != raw:
            changed.append(number)
        out.append(new_line + keep_ends[index][len(raw):])
    edited = "".join(out)
    _check_same_program(original, parse(edited), used, speed_used, file, lines)
    return EditedProgram(edited, tuple(changed), used, speed_used)


def _f_text(old: str, value: str, sinumerik: bool) -> str:
    """The F word ``old`` (as written: its letter's case, Sinumerik's '=') with the value ``value``."""
    letter = old[0]
    if sinumerik and "=" in old:
        return f"{letter}={value}"
    return f"{letter}{value}"


def written_in_lower_case(code: str) -> bool:
    """Whether a line's words are written in lower case (``g1 x10 f500``): words added to it follow."""
    return any(c.isalpha() and c.islower() for c in code) and not any(c.isalpha() and c.isupper() for c in code)


def _f_insertion(raw: str, value: str, sinumerik: bool) -> tuple[int, int, str]:
    """An F word added after the line's last word (before a trailing comment), as an edit of ``raw``."""
    at = _split_code_comment(raw, sinumerik)
    code, rest = raw[:at], raw[at:]
    stripped = code.rstrip()
    lower = written_in_lower_case(stripped)
    space = "" if code[len(stripped):] or not rest else " "
    return len(stripped), len(stripped), f" {'f' if lower else 'F'}{value}{space}"


def _check_same_program(old: Program, new: Program, factors: Mapping[int, float], speeds: Mapping[int, float],
                        file: str, lines: list[str]) -> None:
    """The rewritten program makes the same moves, each feed move at its line's factor x the old feed, each move of
    a tool in ``speeds`` at its ratio x the old spindle speed."""
    if len(old.moves) != len(new.moves):
        raise ProgramEditError(f"{file}: the rewritten program makes {len(new.moves)} moves, the original "
                               f"{len(old.moves)} (a bug of the rewriting: please report it)")
    for a, b in zip(old.moves, new.moves):
        if a.tool in speeds and not math.isclose(b.spindle, a.spindle * speeds[a.tool], rel_tol=1e-9):
            raise ProgramEditError(f'{file} line {a.line}: "{lines[a.line - 1].strip()[:80]}": the rewritten '
                                   f"program turns the spindle at {b.spindle * 30 / math.pi:.6g} rpm, not "
                                   f"{a.spindle * speeds[a.tool] * 30 / math.pi:.6g} (an S word for T{a.tool} that "
                                   f"the optimizer did not find before this line)")
        for name in _KEPT:
            if name == "spindle" and a.tool in speeds:
                continue
            if getattr(a, name) != getattr(b, name):
                raise ProgramEditError(f'{file} line {a.line}: "{lines[a.line - 1].strip()[:80]}": the rewritten '
                                       f"line's {name} differs from the original's (a bug of the rewriting)")
        if a.kind in (MOVE_RAPID, MOVE_DWELL):
            continue
        want = a.feed * factors.get(a.line, 1.0)
        if not math.isclose(b.feed, want, rel_tol=1e-9, abs_tol=0.0):
            raise ProgramEditError(f'{file} line {a.line}: "{lines[a.line - 1].strip()[:80]}": the rewritten '
                                   f"program runs it at {b.feed * 60000:.6g} mm/min, not {want * 60000:.6g}")


def read_program(path: Path) -> str:
    """The program's text as the Interpolator reads it (bytes as Latin-1, so every byte round-trips)."""
    return path.read_text(encoding="latin-1")

"""Sub-blocks: a long straight line whose engagement changes along it split into parts that can each get their F.

A line that runs from air into full width, across an earlier slot or into a corner has one feed for its whole
length, so the heaviest part of it sets the feed of all of it. :func:`plan_sub_blocks` reads the original run's
samples of every cutting straight line (the resultant force against the position along the line; the force at a
fixed feed follows the engagement, which the path alone decides), cuts the line into bins of half the tool's
diameter (or of the shortest sub-block, if longer), joins neighbouring bins whose largest forces are within
:data:`LEVEL_RATIO` of each other (air, force 0, is a level of its own), merges parts shorter than the shortest
sub-block (default: the tool's radius) into their closest neighbour, and keeps at most :data:`MAX_PARTS`. Each
boundary moves :data:`MARGIN` x the tool diameter away from the heavier part, so that part covers its whole rise.

:func:`split_lines` writes the program with each planned line as its sub-blocks: the line itself stays as it was
(the last part, ending where it always ended) and the parts before it are new lines inserted above it, ``G1``,
the axis words of the part's end point and the line's own F word if it has one, with a comment naming the
original line (``(SUB-BLOCK 1/3 OF N310, LINE 69)``; Sinumerik ``; sub-block 1/3 of N310, line 69``); the feed
schedule then writes each part's F. The result is parsed again and compared with the original move by move:
every move the same but for its line, each split move's parts chained end to end on the original segment (within
:data:`ON_LINE` m). A line qualifies only when this is exact by construction: one straight feed move (``G1``),
absolute coordinates, no cutter radius compensation, no exact stop, and no word but N, G1, X, Y, Z and F (a word
that changes the machine's state would take effect after the inserted parts, not before).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from milling_twin.models.interpolator.parser import (COMP_OFF, DIALECT_SINUMERIK, DIALECTS, MOVE_LINE, Move,
                                                     Program, ProgramError, word_spans)
from milling_twin.orchestrator.optimize.program_edit import (ProgramEditError, _check_in_order, _KEPT,
                                                             _split_code_comment, written_in_lower_case)
from milling_twin.orchestrator.part.blocks import Signals, feed_lines
from milling_twin.orchestrator.part.model import FORCE, INTERPOLATOR

__all__ = ["LEVEL_RATIO", "MARGIN", "MAX_PARTS", "ON_LINE", "LineProfile", "SubBlockPlan", "SplitProgram",
           "line_profiles", "plan_line", "plan_sub_blocks", "split_lines", "splittable_lines"]

LEVEL_RATIO = 1.25    # neighbouring bins whose largest forces are within this ratio are one part
MAX_PARTS = 4         # sub-blocks of one line at most
MARGIN = 0.1          # a boundary moves this share of the tool diameter into the lighter part
ON_LINE = 1e-6        # m: how far a written boundary point may lie off the original segment (its rounding)
_SCALES = (1e-3, 0.0254)   # m per program unit: mm, inch
_ALLOWED = {"N", "X", "Y", "Z", "F"}


@dataclass(frozen=True)
class LineProfile:
    """A straight line's samples in one run: the position along it (0 at its start, 1 at its end) and the
    resultant force there."""
    line: int
    length: float            # m
    diameter: float          # m: the cutting tool's
    fraction: np.ndarray
    force: np.ndarray        # N


@dataclass(frozen=True)
class SubBlockPlan:
    line: int
    boundaries: tuple[float, ...]   # the inner boundaries as shares of the line's length, increasing in (0, 1)
    peaks: tuple[float, ...]        # N: the largest force of each part in the run the plan was made from


@dataclass(frozen=True)
class SplitProgram:
    text: str
    origin: dict[int, int]                    # each line of the new text -> its line in the original program
    parts: dict[int, tuple[int, int]]         # each line of a split line's parts -> (part, parts), 1-based
    plans: dict[int, SubBlockPlan]            # by original line

    def label(self, line: int) -> str:
        """``"69"`` or, for a part, ``"69 (1/3)"``: the original line of a line of the new text."""
        original = self.origin.get(line, line)
        part = self.parts.get(line)
        return f"{original}" if part is None else f"{original} ({part[0]}/{part[1]})"


def line_profiles(frame: pd.DataFrame, program: Program, lines: Collection[int],
                  diameter_of: Callable[[int], float | None]) -> list[LineProfile]:
    """The profiles of ``lines`` (straight lines, one move each) that cut in a run's samples; ``diameter_of``: the
    cutting tool's diameter (m) of a move's tool number (None: a tool the part does not cut with)."""
    signals = Signals(frame)
    number = np.nan_to_num(signals[f"{INTERPOLATOR}.line_number"], nan=0.0).astype(np.int64)
    force = np.sqrt(sum(np.nan_to_num(signals[f"{FORCE}.F{a}"], nan=0.0) ** 2 for a in "xyz"))
    xyz = np.column_stack([signals[f"{INTERPOLATOR}.{a}"] for a in "xyz"])
    order = np.argsort(number, kind="stable")
    starts = np.searchsorted(number[order], sorted(lines))
    stops = np.searchsorted(number[order], sorted(lines), side="right")
    moves = feed_lines(program)
    out = []
    for line, a, b in zip(sorted(lines), starts, stops):
        rows = order[a:b]
        move = moves[line][0]
        diameter = diameter_of(move.tool)
        if rows.size == 0 or diameter is None or not (force[rows] > 0.0).any():
            continue
        direction = np.subtract(move.end, move.start)
        length = float(np.linalg.norm(direction))
        fraction = (xyz[rows] - np.asarray(move.start)) @ direction / length ** 2
        out.append(LineProfile(line, length, diameter, fraction, force[rows]))
    return out


def plan_line(profile: LineProfile, min_length: float) -> SubBlockPlan | None:
    """The parts of one line (None: one part is enough)."""
    if profile.length <= 0.0 or profile.fraction.size == 0:
        return None
    bin_length = max(profile.diameter / 2.0, min_length / 2.0, profile.length / 64.0)
    n_bins = int(profile.length // bin_length)
    if n_bins < 2:
        return None
    index = np.minimum((np.clip(profile.fraction, 0.0, 1.0) * n_bins).astype(int), n_bins - 1)
    peak = np.zeros(n_bins)
    np.maximum.at(peak, index, np.nan_to_num(profile.force, nan=0.0))
    # parts: [first bin, one past the last bin, largest force]
    parts: list[list[float]] = []
    low = high = 0.0
    for i, value in enumerate(peak):
        same_kind = (value > 0.0) == (high > 0.0)   # air stays air, cut stays cut
        if parts and same_kind and (high == 0.0 or max(high, value) <= LEVEL_RATIO * min(low, value)):
            parts[-1][1], parts[-1][2] = i + 1, max(parts[-1][2], value)
            low, high = min(low, value), max(high, value)
            continue
        parts.append([i, i + 1, value])
        low = high = value

    def length(p: list[float]) -> float:
        return (p[1] - p[0]) * profile.length / n_bins

    def merge(i: int) -> None:  # part i into part i + 1
        parts[i + 1] = [parts[i][0], parts[i + 1][1], max(parts[i][2], parts[i + 1][2])]
        del parts[i]

    def closeness(a: float, b: float) -> float:
        return math.inf if min(a, b) <= 0.0 < max(a, b) else max(a, b) / max(min(a, b), 1e-300)

    while len(parts) > 1:
        short = [i for i, p in enumerate(parts) if length(p) < min_length]
        same = [i for i in range(len(parts) - 1) if closeness(parts[i][2], parts[i + 1][2]) <= LEVEL_RATIO]
        if not short and not same and len(parts) <= MAX_PARTS:
            break
        if same:
            merge(same[0])
            continue
        if short:
            i = min(short, key=lambda k: length(parts[k]))
        else:  # too many parts: the shortest
            i = min(range(len(parts)), key=lambda k: length(parts[k]))
        left = closeness(parts[i - 1][2], parts[i][2]) if i > 0 else math.inf
        right = closeness(parts[i][2], parts[i + 1][2]) if i + 1 < len(parts) else math.inf
        merge(i - 1 if left <= right and i > 0 else i)
    if len(parts) < 2:
        return None
    margin = MARGIN * profile.diameter / profile.length
    boundaries = []
    for a, b in zip(parts, parts[1:]):
        at = b[0] / n_bins
        at += margin if a[2] > b[2] else -margin
        boundaries.append(at)
    lows = [p[0] / n_bins for p in parts]
    highs = [p[1] / n_bins for p in parts]
    # the margins must leave every part some length
    if any(not (lo < at < hi) for at, lo, hi in zip(boundaries, lows[:-1], highs[1:])) or \
            any(b - a <= 0.0 for a, b in zip([0.0, *boundaries], [*boundaries, 1.0])):
        return None
    return SubBlockPlan(profile.line, tuple(boundaries), tuple(p[2] for p in parts))


def plan_sub_blocks(profiles: Sequence[LineProfile], min_length: float | None = None) -> dict[int, SubBlockPlan]:
    """The lines worth splitting (``min_length``: the shortest part, m; None: each tool's radius)."""
    plans = {}
    for profile in profiles:
        plan = plan_line(profile, profile.diameter / 2.0 if min_length is None else min_length)
        if plan is not None:
            plans[profile.line] = plan
    return plans


def _scale_absolute(move: Move, words: list[tuple[str, float, str, int, int]]) -> float | None:
    """The program unit (m) in which the line's axis words are absolute coordinates of its end, or None when they
    are not (G91) or could also be incremental (the start on the program zero on every written axis)."""
    axes = [("XYZ".index(w[0]), w[1]) for w in words if w[0] in "XYZ"]
    if not axes:
        return None
    for scale in _SCALES:
        absolute = all(math.isclose(value * scale + move.offset[a], move.end[a], rel_tol=1e-12, abs_tol=1e-12)
                       for a, value in axes)
        incremental = all(math.isclose(move.start[a] + value * scale, move.end[a], rel_tol=1e-12, abs_tol=1e-12)
                          for a, value in axes)
        if absolute and not incremental:
            return scale
    return None


def splittable_lines(program: Program, text: str, file: str = "program.nc") -> dict[int, float]:
    """The lines whose single straight feed move can be split exactly, each with its program unit (m)."""
    lines = text.splitlines()
    out: dict[int, float] = {}
    for line, moves in feed_lines(program).items():
        if len(moves) != 1 or sum(m.line == line for m in program.moves) != 1:
            continue
        move = moves[0]
        if move.kind != MOVE_LINE or move.comp != COMP_OFF or move.exact_stop:
            continue
        raw = lines[line - 1]
        if raw.lstrip(" \t").startswith("/") or "=" in raw[:_split_code_comment(raw, True)]:
            continue
        try:
            words = word_spans(raw, file, line)
        except ProgramError:
            continue
        if any(w[0] not in _ALLOWED and not (w[0] == "G" and w[1] == 1.0) for w in words):
            continue
        scale = _scale_absolute(move, words)
        if scale is not None:
            out[line] = scale
    return out


def _number(value: float, scale: float) -> str:
    """A coordinate in program units with a decimal point (0.1 um in mm, 10 uin in inch)."""
    digits = 4 if scale == 1e-3 else 5
    text = f"{value:.{digits}f}".rstrip("0")
    text = "0." if text in ("-0.", "0.") else text
    return text


def _inserted(raw: str, move: Move, scale: float, at: float, part: int, parts: int, line: int,
              sinumerik: bool) -> str:
    lower = written_in_lower_case(raw[:_split_code_comment(raw, sinumerik)])
    words = ["G1"]
    for a, letter in enumerate("XYZ"):
        if move.end[a] != move.start[a]:
            point = move.start[a] + at * (move.end[a] - move.start[a])
            words.append(f"{letter}{_number((point - move.offset[a]) / scale, scale)}")
    # the line's own F word: the parts run at the line's feed, not at the one before it
    words += [f"F{w[2]}" for w in word_spans(raw) if w[0] == "F"]
    code = " ".join(words)
    code = code.lower() if lower else code
    numbered = [w for w in word_spans(raw) if w[0] == "N"]
    name = f"N{numbered[0][2]}, " if numbered else ""
    if sinumerik:
        return f"{code} ; sub-block {part}/{parts} of {name}line {line}"
    return f"{code} (SUB-BLOCK {part}/{parts} OF {name}LINE {line})"


def split_lines(text: str, plans: Mapping[int, SubBlockPlan], parse, file: str = "program.nc",
                dialect: str = "fanuc") -> SplitProgram:
    """``text`` with each planned line (of :func:`splittable_lines`) as its sub-blocks, checked by parsing it."""
    sinumerik = DIALECTS[dialect] == DIALECT_SINUMERIK
    original = parse(text)
    keep_ends = text.splitlines(keepends=True)
    lines = [ln.rstrip("\r\n") for ln in keep_ends]
    _check_in_order(original, file, lines)
    able = splittable_lines(original, text, file)
    moves = feed_lines(original)
    for line in plans:
        if line not in able:
            raise ProgramEditError(f'{file} line {line}: "{lines[line - 1].strip()[:80]}": not a line the '
                                   f"optimizer splits (one G1 move, absolute, no compensation, only N G1 X Y Z F)")
    out: list[str] = []
    origin: dict[int, int] = {}
    parts: dict[int, tuple[int, int]] = {}
    for index, raw in enumerate(lines):
        number = index + 1
        plan = plans.get(number)
        if plan is not None:
            ending = keep_ends[index][len(raw):] or "\n"
            count = len(plan.boundaries) + 1
            for k, at in enumerate(plan.boundaries):
                out.append(_inserted(raw, moves[number][0], able[number], at, k + 1, count, number, sinumerik)
                           + ending)
                origin[len(out)] = number
                parts[len(out)] = (k + 1, count)
        out.append(keep_ends[index])
        origin[len(out)] = number
        if plan is not None:
            parts[len(out)] = (count, count)
    edited = "".join(out)
    result = SplitProgram(edited, origin, parts, dict(plans))
    _check_split(original, parse(edited), result, file, lines)
    return result


def _check_split(old: Program, new: Program, split: SplitProgram, file: str, lines: list[str]) -> None:
    """The new program makes the original's moves, each split one as its parts chained along its segment."""
    it = iter(new.moves)
    for a in old.moves:
        count = len(split.plans[a.line].boundaries) + 1 if a.line in split.plans else 1
        group = [next(it, None) for _ in range(count)]
        where = f'{file} line {a.line}: "{lines[a.line - 1].strip()[:80]}"'
        if any(b is None for b in group):
            raise ProgramEditError(f"{where}: the split program makes fewer moves (a bug of the splitting)")
        for b in group:
            if split.origin.get(b.line) != a.line:
                raise ProgramEditError(f"{where}: the split program's move from line {b.line} is not this line's")
            for name in _KEPT:
                if name in ("line", "start", "end") or (name == "block" and b is not group[-1]):
                    continue  # an inserted part has no N word
                if getattr(a, name) != getattr(b, name):
                    raise ProgramEditError(f"{where}: a sub-block's {name} differs from the line's (a bug of "
                                           f"the splitting)")
        if count == 1:
            if group[0].start != a.start or group[0].end != a.end:
                raise ProgramEditError(f"{where}: the split program moves elsewhere (a bug of the splitting)")
            continue
        direction = np.subtract(a.end, a.start)
        length = float(np.linalg.norm(direction))
        last = 0.0
        if group[0].start != a.start or group[-1].end != a.end:
            raise ProgramEditError(f"{where}: its sub-blocks do not start and end where the line does")
        for b, c in zip(group, group[1:]):
            point = np.asarray(b.end)
            along = float(np.dot(point - a.start, direction)) / length
            off = float(np.linalg.norm(point - np.asarray(a.start) - along / length * direction))
            if b.end != c.start or off > ON_LINE or not last < along < length:
                raise ProgramEditError(f"{where}: its sub-block ends at {tuple(round(v * 1e3, 6) for v in b.end)} "
                                       f"mm, not on the line ahead of the part before")
            last = along
    if next(it, None) is not None:
        raise ProgramEditError(f"{file}: the split program makes more moves than the original (a bug of the "
                               f"splitting)")

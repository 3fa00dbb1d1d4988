"""The checks of a whole-part scenario's program against its stock and tool, before anything runs.

The program is parsed once, as the Interpolator FMU parses it (the Python reference of its parser, with the
dialect, the tool table and the machine parameters of the part), and every feed move (G1, G2/G3, NURBS; not G0)
is followed as the path of the tool tip, sampled at most ``SAMPLE_SPACING`` apart (the rapid moves too, kept
apart), in the program's coordinates
(the Interpolator's ``x_program``, ``y_program``, ``z_program``: the work offset and the tool length of G43
taken off; the stock is given in them). At each
sample the tool, of the radius its tool table entry gives, is

- *over the stock* when its circle overlaps the stock's rectangle in x-y (the distance from the tip's x-y to the
  rectangle is below the radius), and
- *in the stock* when it is over the stock with the tip below the stock top.

Errors (:class:`ScenarioError`, naming the scenario file, the key and the program file and line):

- the program selects a tool the tool table does not hold (the parser's refusal, naming the line and T);
- it cuts with no tool selected (no ``T.. M6``) while the tool table holds more than one tool;
- the tip goes below the stock bottom while over the stock (the depth below the bottom, mm);
- the program zero moves between cutting moves other than by the tools' G43 lengths (another work offset or G52;
  one tool at two lengths): the Workpiece is fed the machine position, continuous through such changes, and holds
  the stock at the program zero of the cut; each tool's length is its tip's distance below that position.

Warnings (logged on the logger ``milling_twin.part`` and returned, so a run summary or report can list them), for
each tool that cuts where it is in the spindle:

- no feed move is ever in the stock (the stock is never touched: wrong origin, or a program for another setup);
- the tip goes deeper below the stock top than the tool's flute length while over the stock (line and tool);
- a feed move is in the stock with the spindle stopped (line);
- a rapid move (G0) takes the tool tip into the stock where no earlier feed move has cut (line, tool, depth): a
  collision on the machine (only the tip's axis point is tested, so a rapid grazing material beside it is left to
  the run, whose process report names every rapid that removes material).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable, Mapping, Sequence
from typing import NoReturn

import numpy as np

from milling_twin.models.interpolator.definition import default_parameters
from milling_twin.models.interpolator.nurbs import Nurbs
from milling_twin.models.interpolator.parser import (DIALECTS, MOVE_ARC, MOVE_LINE, MOVE_NURBS, MOVE_RAPID,
                                                    Program, Tool, parse_program)
from milling_twin.models.interpolator.path import ArcShape
from milling_twin.models.interpolator.tool_table import find_tool
from milling_twin.orchestrator.part.model import Stock

SAMPLE_SPACING = 0.5e-3   # m: the longest distance between two samples of a feed move
ARC_STEP = math.pi / 36   # rad: the largest angle between two samples of an arc
TOLERANCE = 1e-6          # m: a tip this close to the stock top or bottom counts as on it
_log = logging.getLogger("milling_twin.part")


@dataclass(frozen=True)
class FeedPath:
    """The feed moves of a program as samples of the tool tip: position (m, program coordinates: the work
    coordinates of G54..G59 and G52, the tip with G43), and for each
    sample its program line, its tool number (0: none selected) and whether the spindle runs."""
    file: str
    points: np.ndarray      # (n, 3)
    lines: np.ndarray       # (n,) int
    tools: np.ndarray       # (n,) int
    spindle_on: np.ndarray  # (n,) bool
    offsets: np.ndarray     # (n, 3): the machine position of the program zero (work offset, G52, G43 tool length)
    selected: tuple[int, ...] = ()  # the tools the moves run with (rapids too), in order, without repetition
    # the rapid moves (G0) sampled the same way: tip positions (program coordinates), line, tool, and how many feed
    # samples come before each (the feed moves run before it)
    rapid_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rapid_lines: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    rapid_tools: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    rapid_after: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))


def parse(program: Path, dialect: str, tools: Sequence[Tool], machine: Mapping[str, float]) -> Program:
    """The program as the Interpolator reads it; a ProgramError (file, line, text, expected) for a refusal."""
    return parse_text(program.read_text(encoding="latin-1"), str(program), dialect, tools, machine)


def parse_text(text: str, file: str, dialect: str, tools: Sequence[Tool], machine: Mapping[str, float]) -> Program:
    """``text`` as the Interpolator reads it, with the part's dialect, tool table and machine parameters (messages
    name ``file``): the program of ``parse`` and the optimizer's rewritten programs alike."""
    return parse_program(text, {**default_parameters(), **machine}, file, dialect=DIALECTS[dialect], tools=tools)


def _line_samples(move) -> list[list[float]]:
    length = math.dist(move.start, move.end)
    n = max(1, math.ceil(length / SAMPLE_SPACING))
    a, b = np.asarray(move.start), np.asarray(move.end)
    return [list(a + (b - a) * (k / n)) for k in range(n + 1)]


def _in_program(samples: list, offset: Sequence[float]) -> list[list[float]]:
    """Machine positions less the program zero (work offset, G52, G43 tool length): program coordinates."""
    return [[q[0] - offset[0], q[1] - offset[1], q[2] - offset[2]] for q in samples]


def feed_path(program: Program) -> FeedPath:
    """The tool tip along every feed move, sampled at most SAMPLE_SPACING (and ARC_STEP on arcs) apart, and along
    every rapid move (kept apart: rapids do not cut)."""
    points: list[list[float]] = []
    lines: list[int] = []
    tools: list[int] = []
    spindle: list[bool] = []
    offsets: list[tuple[float, float, float]] = []
    rapids: list[list[float]] = []
    rapid_lines: list[int] = []
    rapid_tools: list[int] = []
    rapid_after: list[int] = []
    curves: dict[int, Nurbs] = {}
    for move in program.moves:
        if move.kind == MOVE_RAPID:
            samples = _line_samples(move)
            rapids.extend(_in_program(samples, move.offset))
            rapid_lines.extend([move.line] * len(samples))
            rapid_tools.extend([move.tool] * len(samples))
            rapid_after.extend([len(points)] * len(samples))
            continue
        if move.kind == MOVE_LINE:
            samples = _line_samples(move)
        elif move.kind == MOVE_ARC:
            arc = ArcShape(move)
            n = max(1, math.ceil(arc.length / SAMPLE_SPACING), math.ceil(abs(move.sweep) / ARC_STEP))
            samples = [arc.point(k / n) for k in range(n + 1)]
        elif move.kind == MOVE_NURBS:
            curve = curves.setdefault(move.curve, Nurbs(program.curves[move.curve]))
            lo, hi = curve.span_range(move.u0, move.u1)
            coarse = [curve.evaluate(move.u0 + (move.u1 - move.u0) * k / 16, 0, lo, hi)[0] for k in range(17)]
            length = sum(math.dist(p, q) for p, q in zip(coarse, coarse[1:]))
            n = max(16, math.ceil(length / SAMPLE_SPACING))
            samples = [curve.evaluate(move.u0 + (move.u1 - move.u0) * k / n, 0, lo, hi)[0] for k in range(n + 1)]
        else:
            continue  # dwells do not move
        offset = move.offset
        points.extend(_in_program(samples, offset))
        lines.extend([move.line] * len(samples))
        tools.extend([move.tool] * len(samples))
        spindle.extend([move.spindle_on] * len(samples))
        offsets.extend([tuple(offset)] * len(samples))
    return FeedPath(program.file, np.asarray(points, dtype=float).reshape(-1, 3), np.asarray(lines, dtype=int),
                    np.asarray(tools, dtype=int), np.asarray(spindle, dtype=bool),
                    np.asarray(offsets, dtype=float).reshape(-1, 3),
                    tuple(dict.fromkeys(move.tool for move in program.moves)),
                    np.asarray(rapids, dtype=float).reshape(-1, 3), np.asarray(rapid_lines, dtype=int),
                    np.asarray(rapid_tools, dtype=int), np.asarray(rapid_after, dtype=int))


def _effective_tools(path: FeedPath, tools: Sequence[Tool], numbers: np.ndarray | None = None) -> np.ndarray:
    """Each sample's tool (``numbers``: of other samples than the feed path's, its rapids'); tool 0 (none selected)
    is the table's only tool when it holds exactly one."""
    numbers = path.tools if numbers is None else numbers
    if len(tools) == 1:
        return np.where(numbers == 0, tools[0].number, numbers)
    return numbers


def _over(path: FeedPath, stock: Stock, radius: np.ndarray | float) -> np.ndarray:
    """Per sample: the tool's circle overlaps the stock's x-y rectangle."""
    x, y = path.points[:, 0], path.points[:, 1]
    x0, y0 = stock.origin[0], stock.origin[1]
    dx = np.maximum(np.maximum(x0 - x, x - (x0 + stock.size[0])), 0.0)
    dy = np.maximum(np.maximum(y0 - y, y - (y0 + stock.size[1])), 0.0)
    distance = np.hypot(dx, dy)
    return (distance < radius) | (distance <= 0.0)  # a tip over the rectangle is over it whatever the radius


def _radii(numbers: np.ndarray, tools: Sequence[Tool]) -> np.ndarray:
    table = {t.number: 0.5 * t.diameter for t in tools}
    return np.array([table.get(int(n), 0.0) for n in numbers], dtype=float)


def cutting_tools(path: FeedPath, tools: Sequence[Tool], stock: Stock,
                  fail: Callable[[str], NoReturn]) -> list[Tool]:
    """The tools the program cuts the stock with, in the order of their first cut. ``fail(message)`` raises the
    caller's error when it cuts with none selected among several, or has no tool to cut with at all. A program that
    never reaches the stock (a warning of check_part) gives the first tool a feed move runs with."""
    if not tools:
        fail("the tool table holds no tool")
    numbers = _effective_tools(path, tools)
    inside = _over(path, stock, _radii(numbers, tools)) & (path.points[:, 2] < stock.top - TOLERANCE)
    cutting = numbers[inside]
    lines = path.lines[inside]
    used = list(dict.fromkeys(int(n) for n in cutting))
    if not used:
        selected = [n for n in path.selected if n != 0]
        if selected:
            return [find_tool(tools, selected[0]) or tools[0]]
        if len(tools) == 1:
            return [tools[0]]
        fail(f"{path.file}: no feed move reaches the stock and the program selects no tool (T.. M6), while the "
             f"tool table holds {len(tools)} tools: the part's tool is unknown")
    if 0 in used:
        line = int(lines[np.argmax(cutting == 0)])
        fail(f"{path.file} line {line}: cuts the stock with no tool selected (no T.. M6 before it) while the tool "
             f"table holds {len(tools)} tools: select the tool with T<n> M6")
    found = [find_tool(tools, n) for n in used]
    assert all(t is not None for t in found)  # the parser refuses a T the table does not hold
    return found  # type: ignore[return-value]


def _cut_by(path: FeedPath, tools: Sequence[Tool], tool: Tool, stock: Stock) -> np.ndarray:
    """Per sample: ``tool`` is in the spindle and in the stock."""
    mine = _effective_tools(path, tools) == tool.number
    return mine & _over(path, stock, 0.5 * tool.diameter) & (path.points[:, 2] < stock.top - TOLERANCE)


def cutting_offsets(path: FeedPath, tools: Sequence[Tool], cutting: Sequence[Tool], stock: Stock,
                    fail: Callable[[str], NoReturn]) -> list[tuple[float, float, float]]:
    """For each tool of ``cutting``: the machine position of the program zero while it cuts the stock (work offset,
    G52 and its G43 tool length: the Workpiece, fed with the machine position, holds the stock there); the first
    feed move's when nothing cuts. ``fail(message)`` when the cuts have two zeros other than by the tools' lengths
    (the stock would have to move): one tool at two zeros, or two tools at two x-y positions of it."""
    if not len(path.points):
        return [(0.0, 0.0, 0.0) for _ in cutting]
    zeros: list[tuple[float, float, float]] = []
    first_line = 0
    for tool in cutting:
        inside = _cut_by(path, tools, tool, stock)
        offsets = path.offsets[inside] if inside.any() else path.offsets[:1]
        lines = path.lines[inside] if inside.any() else path.lines[:1]
        differ = np.any(np.abs(offsets - offsets[0]) > TOLERANCE, axis=1)
        if differ.any():
            _two_zeros(path, int(lines[0]), int(lines[int(np.argmax(differ))]), offsets[0],
                       offsets[int(np.argmax(differ))], fail)
        if zeros and np.any(np.abs(offsets[0][:2] - np.asarray(zeros[0][:2])) > TOLERANCE):
            _two_zeros(path, first_line, int(lines[0]), np.asarray(zeros[0]), offsets[0], fail)
        if not zeros:
            first_line = int(lines[0])
        zeros.append(tuple(float(v) for v in offsets[0]))  # type: ignore[arg-type]
    return zeros


def _two_zeros(path: FeedPath, line_a: int, line_b: int, a: np.ndarray, b: np.ndarray,
               fail: Callable[[str], NoReturn]) -> NoReturn:
    fail(f"{path.file} lines {line_a} and {line_b}: the program cuts the stock with two positions of its zero, "
         f"x y z = {' '.join(_mm(v) for v in a)} and {' '.join(_mm(v) for v in b)} mm in machine coordinates (work "
         f"offset G54..G59, G52, G43 tool length): the stock is placed with one")


def check_part(path: FeedPath, tools: Sequence[Tool], cutting: Sequence[tuple[Tool, float]], stock: Stock,
               fail: Callable[[str], NoReturn]) -> list[str]:
    """The checks of the module's docstring for each tool of ``cutting`` (the tool and its flute length) where it is
    in the spindle; returns (and logs) the warnings, ``fail(message)`` raises the caller's error."""
    z = path.points[:, 2]
    numbers = _effective_tools(path, tools)
    warnings: list[str] = []
    if not any(_cut_by(path, tools, tool, stock).any() for tool, _ in cutting):
        warnings.append(f"{path.file}: no feed move reaches the stock (x {_mm(stock.origin[0])} .. "
                        f"{_mm(stock.origin[0] + stock.size[0])}, y {_mm(stock.origin[1])} .. "
                        f"{_mm(stock.origin[1] + stock.size[1])}, z {_mm(stock.origin[2])} .. {_mm(stock.top)} mm): "
                        f"the program never cuts it")
    bottom = stock.origin[2]
    stopped = np.zeros(len(z), dtype=bool)
    for tool, flute_length in cutting:
        # a single tool's checks cover every sample (as the run does: the Workpiece has its geometry throughout)
        mine = numbers == tool.number if len(cutting) > 1 else np.ones(len(z), dtype=bool)
        over = mine & _over(path, stock, 0.5 * tool.diameter)
        below = over & (z < bottom - TOLERANCE)
        if below.any():
            k = int(np.argmax(below))
            line = int(path.lines[k])
            lowest = float(z[below & (path.lines == line)].min())
            fail(f"{path.file} line {line}: the tool tip goes down to z = {_mm(lowest)} mm over the stock, "
                 f"{_mm(bottom - lowest)} mm below the stock bottom (z = {_mm(bottom)} mm)")
        deep = over & (stock.top - z > flute_length + TOLERANCE)
        if deep.any():
            deep_lines = list(dict.fromkeys(int(n) for n in path.lines[deep]))
            depth = stock.top - float(z[deep].min())
            more = f" (and {len(deep_lines) - 1} more lines)" if len(deep_lines) > 1 else ""
            warnings.append(f"{path.file} line {deep_lines[0]}{more}: T{tool.number} cuts {_mm(depth)} mm below "
                            f"the stock top, deeper than its flute length {_mm(flute_length)} mm")
        stopped |= over & (z < stock.top - TOLERANCE) & ~path.spindle_on
    warnings += _rapids_into_uncut_stock(path, tools, stock)
    if stopped.any():
        stopped_lines = list(dict.fromkeys(int(n) for n in path.lines[stopped]))
        more = f" (and {len(stopped_lines) - 1} more lines)" if len(stopped_lines) > 1 else ""
        warnings.append(f"{path.file} line {stopped_lines[0]}{more}: a feed move in the stock with the spindle "
                        f"stopped")
    for text in warnings:
        _log.warning("%s", text)
    return warnings


def _rapids_into_uncut_stock(path: FeedPath, tools: Sequence[Tool], stock: Stock) -> list[str]:
    """One warning per line whose rapid move takes the tool tip into the stock where no earlier feed move has cut:
    inside the stock's block, and no feed sample before it within its tool's radius (plus half the sample spacing,
    which covers the path between samples) in x-y at or below the rapid's height, nor an earlier rapid sample (the
    way out of a collision is not a second one). Only the tip's axis point is
    tested, so every warning is a collision on the machine; a rapid that grazes uncut material beside its axis is
    left to the run (the process report names each rapid that removes material)."""
    x, y, z = path.rapid_points[:, 0], path.rapid_points[:, 1], path.rapid_points[:, 2]
    x0, y0 = stock.origin[0], stock.origin[1]
    inside = ((x > x0 + TOLERANCE) & (x < x0 + stock.size[0] - TOLERANCE) & (y > y0 + TOLERANCE)
              & (y < y0 + stock.size[1] - TOLERANCE) & (z < stock.top - TOLERANCE) & (z > stock.origin[2]))
    if not inside.any():
        return []
    reach = _radii(_effective_tools(path, tools), tools) + 0.5 * SAMPLE_SPACING
    numbers = _effective_tools(path, tools, path.rapid_tools)
    rapid_reach = _radii(numbers, tools) + 0.5 * SAMPLE_SPACING
    found: dict[int, tuple[int, float, np.ndarray]] = {}  # line -> (tool, depth below the top, first point)

    def cut(points: np.ndarray, radii: np.ndarray, k: int) -> bool:
        return bool(np.any((np.hypot(points[:, 0] - x[k], points[:, 1] - y[k]) < radii)
                           & (points[:, 2] <= z[k] + TOLERANCE)))

    for k in np.flatnonzero(inside):
        line = int(path.rapid_lines[k])
        n = int(path.rapid_after[k])
        # cut by a feed move before it, or by an earlier rapid (the way out of a collision is no second one)
        if cut(path.points[:n], reach[:n], k) or cut(path.rapid_points[:k], rapid_reach[:k], k):
            continue
        depth = stock.top - float(z[k])
        if line not in found or depth > found[line][1]:
            point = found[line][2] if line in found else path.rapid_points[k]
            found[line] = (int(numbers[k]), depth, point)
    return [f"{path.file} line {line}: the rapid move (G0) with T{tool} goes {_mm(depth)} mm into the stock where no "
            f"earlier feed move has cut (from x y z = {' '.join(_mm(v) for v in point)} mm): on the machine a "
            f"collision" for line, (tool, depth, point) in found.items()]


def _mm(value: float) -> str:
    text = f"{value * 1000.0:.3f}"
    return "0.000" if text == "-0.000" else text

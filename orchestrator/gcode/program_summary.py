"""What a part program asks of the machine, before it is co-simulated: ``milling-twin program PROGRAM``.

The program is read as the Interpolator FMU reads it (the Python reference of its parser and engine, in the
chosen dialect and with the tool table), then interpolated at the FMU's period with the given limits: the moves
by kind, the path length, the machining time at 100 % feed override, the time and path per tool, and the words
the program holds that the twin accepts without modelling them (M0, M19, ...). A program the FMU would refuse is
refused here with the same message (file, line, quoted text, what was expected).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

from milling_twin.models.interpolator.engine import Interpolator
from milling_twin.models.interpolator.parser import (DIALECTS, MOVE_ARC, MOVE_DWELL, MOVE_LINE, MOVE_NURBS,
                                                    MOVE_RAPID, Tool)
from milling_twin.models.interpolator.tool_table import find_tool, read_tool_table
from milling_twin.orchestrator.gcode.recognise import check_part_program, check_tool_table
from milling_twin.orchestrator.input_files import read_input

KIND_NAMES = {MOVE_RAPID: "rapid", MOVE_LINE: "line", MOVE_ARC: "arc", MOVE_NURBS: "NURBS", MOVE_DWELL: "dwell"}
MAX_TICKS = 50_000_000  # 14 h at 1 ms: a program longer than that is reported as not finished


@dataclass
class ToolUse:
    """One tool's share of the program (tool 0: before the first tool change)."""
    number: int
    diameter: float | None          # m; None when the tool table has no entry
    first_line: int
    time: float = 0.0               # s
    length: float = 0.0             # m of path
    moves: int = 0


@dataclass
class ProgramSummary:
    file: str
    dialect: str
    moves: dict[str, int]
    length: float                   # m
    time: float                     # s at 100 % override, to rest on the last point
    finished: bool
    tools: list[ToolUse] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        """The summary as a person reads it (mm, min:s)."""
        minutes, seconds = divmod(self.time, 60.0)
        out = [f"{self.file} ({self.dialect})",
               "moves: " + ", ".join(f"{n} {kind}" for kind, n in self.moves.items() if n) if any(
                   self.moves.values()) else "moves: none",
               f"path length: {self.length * 1000.0:.1f} mm",
               f"machining time: {int(minutes)} min {seconds:.1f} s ({self.time:.3f} s) at 100 % feed override"
               + ("" if self.finished else " (NOT finished: the limit of simulated time was reached)")]
        for tool in self.tools:
            size = "no tool table entry" if tool.diameter is None else f"D {tool.diameter * 1000.0:g} mm"
            name = "before the first tool change" if tool.number == 0 else f"T{tool.number} ({size})"
            out.append(f"  {name}: from line {tool.first_line}, {tool.moves} moves, "
                       f"{tool.length * 1000.0:.1f} mm, {tool.time:.3f} s")
        out += [f"not modelled: {note}" for note in self.notes]
        return out


def summarize(program: Path, dialect: str = "fanuc", tools: Sequence[Tool] = (),
              parameters: Mapping[str, float] | None = None) -> ProgramSummary:
    """Reads and interpolates ``program``; raises ``ProgramError`` (a ValueError) for a program the FMU refuses,
    ``NotThatFileError`` (a ValueError) for a path that is not a regular file or a file that is not a program."""
    if dialect not in DIALECTS:
        raise ValueError(f"dialect {dialect!r}: expected one of {', '.join(DIALECTS)}")
    check_part_program(program)
    text = read_input(program, "part program").decode("latin-1")
    engine = Interpolator(text, dict(parameters or {}), str(program),
                          dialect=DIALECTS[dialect], tools=tools)
    moves = engine.program.moves
    counts = {name: sum(1 for m in moves if m.kind == kind) for kind, name in KIND_NAMES.items()}
    uses: dict[int, ToolUse] = {}
    for index, move in enumerate(moves):
        if move.tool not in uses:
            entry = find_tool(tools, move.tool)
            uses[move.tool] = ToolUse(move.tool, entry.diameter if entry else None, move.line)
        use = uses[move.tool]
        use.moves += 1
        use.length += engine.path.move_length[index]
    engine.set_override(1.0, 0.0)
    ticks = 0
    while not engine.out["finished"] and ticks < MAX_TICKS and moves:
        engine.tick()
        ticks += 1
        uses[moves[engine.move].tool].time += engine.period
    return ProgramSummary(str(program), dialect, counts, sum(engine.path.move_length), ticks * engine.period,
                          bool(engine.out["finished"]) or not moves, sorted(uses.values(), key=lambda u: u.first_line),
                          list(engine.program.notes))


def command(args: argparse.Namespace) -> int:
    """``milling-twin program PROGRAM [--dialect D] [--tool-table FILE] [--param NAME=VALUE ...]``."""
    parameters: dict[str, float] = {}
    for text in args.param or ():
        name, eq, value = text.partition("=")
        try:
            parameters[name] = float(value)
        except ValueError:
            raise ValueError(f"--param {text!r}: expected NAME=VALUE in SI units, e.g. acceleration=2") from None
        if not eq:
            raise ValueError(f"--param {text!r}: expected NAME=VALUE in SI units, e.g. acceleration=2")
    if args.tool_table:
        check_tool_table(args.tool_table)
    tools = read_tool_table(args.tool_table) if args.tool_table else ()
    summary = summarize(args.program, args.dialect, tools, parameters)
    for line in summary.lines():
        print(line)
    return 0

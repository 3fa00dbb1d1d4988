"""The tool table: LinuxCNC's tool table format, read by the Interpolator (the String parameter ``tool_table``).
Mirrors ``fmus/interpolator/tool_table.c``.

One tool per line, words in any order, a ``;`` comment to the end of the line (LinuxCNC's own format, so a
LinuxCNC machine's ``tool.tbl`` is read as it is)::

    T1 P1 D10.000 Z+50.000 ; 10 mm end mill corner_radius=0.5 flutes=3 helix=30 stick_out=40 name=END10

- ``T`` tool number (a whole number 1..99999, once per table; required), ``P`` pocket (read, not used);
- ``D`` diameter (mm, >= 0), ``Z`` tool length offset (mm, used by G43/G44 H..: the tool tip lies ``Z`` below
  the spindle gauge line), ``X Y A B C U V W I J Q`` (other offsets, angles, orientation: read, not used);
- in the comment, the geometry LinuxCNC has no column for, as ``key=value``: ``corner_radius`` (mm, at most
  half the diameter), ``flutes`` (a whole number), ``helix`` (degrees, 0 <= helix < 90), ``stick_out`` (mm),
  ``name`` (the Sinumerik tool name of ``T="name"``, at most 31 characters); the rest of the comment is the
  description.

Lengths are millimetres (a metric machine's table); inside everything is SI (m, rad). A malformed line is an
error ``<file> line <n>: "<text>": <what was expected>``, like the part program's.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Sequence

from milling_twin.models.interpolator.numbers import NumberError, read_number
from milling_twin.models.interpolator.parser import ProgramError, Tool

MAX_TOOLS = 1000
MAX_TOOL_NUMBER = 99999
MAX_TOOL_NAME = 31
MAX_TOOL_VALUE = 1e5   # mm (and degrees, counts): far above any real tool
TOOL_WORDS = "TPXYZABCUVWDIJQ"
TOOL_COMMENT_KEYS = ("corner_radius", "flutes", "helix", "stick_out", "name")


def _number(text: str) -> float | None:
    """The whole of ``text`` as a plain decimal number (the part program's reader); else None."""
    try:
        value, end = read_number(text, 0, "")
    except NumberError:
        return None
    return value if end == len(text) else None


def _split(text: str) -> list[str]:
    """Tokens separated by blanks and tabs (only those, as the C reader)."""
    return [t for t in re.split("[ \t]+", text) if t]


def parse_tool_table(text: str, file: str = "tool.tbl") -> tuple[Tool, ...]:
    """The tools of a tool table's text, in the order written."""
    tools: list[Tool] = []
    lines = text.split("\n")
    for number, raw_line in enumerate(lines, start=1):
        raw = raw_line.rstrip("\r")

        def fail(expected: str) -> None:
            raise ProgramError(file, number, raw, expected)

        body, _, comment = raw.partition(";")
        words: dict[str, float] = {}
        for token in _split(body):
            letter = token[0].upper() if token[0].isascii() else token[0]
            if letter not in TOOL_WORDS:
                fail(f"a tool table word {', '.join(TOOL_WORDS)} (letter and number), got '{token[:40]}'")
            value = _number(token[1:])
            if value is None:
                fail(f"a number after '{letter}', got '{token[:40]}'")
            if letter in words:
                fail(f"one {letter} word per tool")
            if abs(value) > MAX_TOOL_VALUE:
                fail(f"a value of magnitude at most {MAX_TOOL_VALUE:g} after '{letter}', got '{token[:40]}'")
            words[letter] = value
        if not words:
            continue
        if "T" not in words:
            fail("the tool number T")
        t = words["T"]
        if t != math.floor(t) or not 1 <= t <= MAX_TOOL_NUMBER:
            fail(f"a whole tool number T of 1 to {MAX_TOOL_NUMBER}")
        if any(tool.number == int(t) for tool in tools):
            fail(f"tool T{int(t)} once in the table")
        if len(tools) >= MAX_TOOLS:
            fail(f"at most {MAX_TOOLS} tools")
        diameter = words.get("D", 0.0)
        if diameter < 0.0:
            fail("a diameter D >= 0")
        extra: dict[str, str] = {}
        for token in _split(comment):
            key, eq, value_text = token.partition("=")
            if not eq or key not in TOOL_COMMENT_KEYS:
                continue
            if key in extra:
                fail(f"one {key}= per tool")
            extra[key] = value_text
        values: dict[str, float] = {}
        for key in ("corner_radius", "flutes", "helix", "stick_out"):
            if key in extra:
                value = _number(extra[key])
                if value is None or abs(value) > MAX_TOOL_VALUE:
                    fail(f"a number of magnitude at most {MAX_TOOL_VALUE:g} after {key}=, got '{extra[key][:40]}'")
                values[key] = value
        corner = values.get("corner_radius", 0.0)
        if corner < 0.0 or corner > 0.5 * diameter:
            fail(f"a corner_radius of 0 to half the diameter ({0.5 * diameter:g} mm), "
                 f"got {extra['corner_radius'][:40]}")
        flutes = values.get("flutes", 0.0)
        if flutes < 0.0 or flutes != math.floor(flutes):
            fail(f"a whole number of flutes >= 0, got {extra['flutes'][:40]}")
        helix = values.get("helix", 0.0)
        if not 0.0 <= helix < 90.0:
            fail(f"a helix angle of 0 to less than 90 degrees, got {extra['helix'][:40]}")
        stick_out = values.get("stick_out", 0.0)
        if stick_out < 0.0:
            fail(f"a stick_out >= 0, got {extra['stick_out'][:40]}")
        name = extra.get("name", "")
        if len(name) > MAX_TOOL_NAME or '"' in name:
            fail(f"a name of at most {MAX_TOOL_NAME} characters without '\"'")
        if name and any(tool.name == name for tool in tools):
            fail(f"the name {name} once in the table")
        tools.append(Tool(number=int(t), name=name, diameter=diameter / 1000.0, corner_radius=corner / 1000.0,
                          length=words.get("Z", 0.0) / 1000.0, stick_out=stick_out / 1000.0,
                          helix=helix * (math.pi / 180.0), flutes=int(flutes)))
    return tuple(tools)


def read_tool_table(path: str | Path) -> tuple[Tool, ...]:
    path = Path(path)
    return parse_tool_table(path.read_text(encoding="latin-1"), str(path))


def find_tool(tools: Sequence[Tool], number: int) -> Tool | None:
    for tool in tools:
        if tool.number == number:
            return tool
    return None


def _mm(value: float) -> str:
    text = f"{value * 1000.0:.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def tool_table_text(tools: Sequence[Tool]) -> str:
    """A tool table file for the tools (LinuxCNC format with the extra geometry in the comment)."""
    lines = []
    for tool in tools:
        extra = [f"corner_radius={_mm(tool.corner_radius)}", f"flutes={tool.flutes}",
                 f"helix={tool.helix * 180.0 / math.pi:.6g}", f"stick_out={_mm(tool.stick_out)}"]
        if tool.name:
            extra.append(f"name={tool.name}")
        lines.append(f"T{tool.number} P{tool.number} D{_mm(tool.diameter)} Z{_mm(tool.length)} ; {' '.join(extra)}")
    return "\n".join(lines) + ("\n" if lines else "")

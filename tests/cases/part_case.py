"""A minimal whole-part scenario for the tests: a 10 mm 3-flute end mill cuts one 2 mm deep slot, 10 mm wide,
along x through a 50 x 20 x 10 mm block (top z = 0); the program, its tool table and the part file are
written into a folder. ``edits`` are (old, new) text replacements (each must apply)."""
from __future__ import annotations

from pathlib import Path

PROGRAM = """\
G21 G90 G17
T1 M6
S6000 M3
G0 X-10 Y10 Z5
G1 Z-2 F300
G1 X60 F600
G0 Z5
M5
M30
"""

TOOLS = """\
T1 P1 D10 Z50 ; end mill corner_radius=0.5 flutes=3 helix=30 stick_out=25
T2 P2 D6 Z50 ; drill flutes=2 helix=30 stick_out=20
"""

PART = """\
[scenario]
name = "tiny_part"
description = "one slot through a small block"

[part]
program = "prog.nc"
tool_table = "tool.tbl"
material = "Al7075-T6"
[part.stock]
origin = { value = [0.0, 0.0, -10.0], unit = "mm" }
size = { value = [50.0, 20.0, 10.0], unit = "mm" }
resolution = { value = 0.5, unit = "mm" }
[part.machine]
rapid_feed = { value = 15000, unit = "mm/min" }
start_x = { value = -10, unit = "mm" }
start_y = { value = 10, unit = "mm" }
start_z = { value = 5, unit = "mm" }
[part.spindle]
P_idle = { value = 0.3, unit = "kW" }
""" + (MODES := """\
[part.tool_modes]
x = [ { frequency = 1200.0, damping = 0.03, stiffness = 2.0e7 } ]
y = [ { frequency = 1300.0, damping = 0.02, stiffness = { value = 30, unit = "N/um" } },
      { frequency = 3000.0, damping = 0.05, stiffness = 8.0e7 } ]
""")


def edited(text: str, *edits: tuple[str, str]) -> str:
    for old, new in edits:
        if old not in text:
            raise AssertionError(f"edit does not apply: {old!r} is not in the text")
        text = text.replace(old, new, 1)
    return text


def write_part(folder: Path, *edits: tuple[str, str], program: str = PROGRAM, tools: str = TOOLS,
               name: str = "part.toml") -> Path:
    """The part file (with ``edits``), ``prog.nc`` and ``tool.tbl`` in ``folder``; returns the part file."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "prog.nc").write_text(program)
    (folder / "tool.tbl").write_text(tools)
    path = folder / name
    path.write_text(edited(PART, *edits))
    return path

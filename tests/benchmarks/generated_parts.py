"""Whole parts from seeded random programs, for benchmarks that must not fit the committed parts only.

Each program cuts the bracket's stock (``scenarios/al_bracket.toml``: 80 x 60 x 20 mm, top at Z0) with its
10 mm 3-flute end mill in Al7075-T6, as a CAM system links operations: slots across the block entered from
outside at depth, short slots entered by a plunge, passes along an edge at 2 mm radial engagement, each
followed by a retract, a rapid traverse in air and sometimes a dwell; depths 0.5 to 3 mm, feeds 800 to
2000 mm/min, one spindle speed per program (8000, 9000 or 11000 rpm). Deep full slots chatter with the
bracket's assumed tool modes, as they would on a machine.

    .venv/bin/python tests/benchmarks/generated_parts.py OUT SEED [SEED ...]   # writes OUT/generated_<seed>/
"""
from __future__ import annotations

import random
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
BRACKET = REPO / "scenarios" / "al_bracket.toml"


def program(seed: int, operations: int = 8) -> str:
    """The Fanuc-dialect program of ``seed``: ``operations`` cuts with what links them."""
    r = random.Random(seed)
    lines = ["%", f"O{3000 + seed} (GENERATED FROM SEED {seed})", "G90 G94 G17 G49 G40 G80", "G21", "T1 M6",
             f"S{r.choice([8000, 9000, 11000])} M3", "G54", "G0 X-10. Y-10.", "G43 Z25. H1"]
    for _ in range(operations):
        kind = r.choice(["slot", "plunge_slot", "edge", "slot_and_dwell"])
        depth, feed = r.uniform(0.5, 3.0), r.choice([800, 1000, 1400, 2000])
        if kind in ("slot", "slot_and_dwell"):
            y = r.uniform(5.0, 55.0)
            x0, x1 = (-8.0, 88.0) if r.random() < 0.5 else (88.0, -8.0)
            lines += [f"G0 X{x0:.2f} Y{y:.2f}", "Z2.", f"G1 Z{-depth:.2f} F{feed}.", f"X{x1:.2f}", "G0 Z25."]
            if kind == "slot_and_dwell":
                lines.append(f"G4 P{r.choice([0.5, 1.0, 2.0])}")
        elif kind == "plunge_slot":
            x, y, length = r.uniform(15.0, 65.0), r.uniform(15.0, 45.0), r.uniform(5.0, 15.0)
            lines += [f"G0 X{x:.2f} Y{y:.2f}", "Z2.", f"G1 Z{-depth:.2f} F300.", f"X{x + length:.2f} F{feed}.",
                      "G0 Z25."]
        else:  # along the front or back face, the tool's axis 3 mm outside it: 2 mm radial engagement
            y = r.choice([-3.0, 63.0])
            lines += [f"G0 X-8. Y{y:.2f}", "Z2.", f"G1 Z{-depth:.2f} F{feed}.", "X88.", "G0 Z25."]
        lines.append(f"G0 X{r.uniform(-20.0, 100.0):.2f} Y{r.uniform(-20.0, 80.0):.2f}")  # a traverse in air
    lines += ["G0 Z50.", "M5", "M30", "%"]
    return "\n".join(lines) + "\n"


def write_generated_part(out: Path, seed: int) -> Path:
    """``out/generated_<seed>/``: the program and the bracket's part file pointing at it; returns the part file."""
    folder = out / f"generated_{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "program.nc").write_text(program(seed))
    text = BRACKET.read_text()
    text = text[:text.index("\n[optimize]")] + "\n" if "\n[optimize]" in text else text
    edits = {'program = "parts/al_pocket.nc"': f'program = "{(folder / "program.nc").as_posix()}"',
             'tool_table = "parts/tool.tbl"': f'tool_table = "{(REPO / "scenarios/parts/tool.tbl").as_posix()}"',
             'name = "al_bracket"': f'name = "generated_{seed}"',
             'description = "Aluminium bracket: slot, pocket, profile and NURBS wall through every model"':
                 f'description = "A random program (seed {seed}) on the bracket\'s stock and tool"'}
    for old, new in edits.items():
        if old not in text:
            raise ValueError(f"{BRACKET}: no {old!r} to replace")
        text = text.replace(old, new)
    path = folder / "part.toml"
    path.write_text(text)
    return path


if __name__ == "__main__":
    for arg in sys.argv[2:]:
        print(write_generated_part(Path(sys.argv[1]), int(arg)))

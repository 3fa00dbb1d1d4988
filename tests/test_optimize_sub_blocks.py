"""Sub-blocks of the feed optimizer (orchestrator/optimize/sub_blocks.py): where a line's force profile is cut into
parts, how the parts are written into the program (checked by the Interpolator's parser), which lines are never
split, and a whole optimization whose slot line starts in air."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import milling_twin
from cases.part_case import PROGRAM, write_part
from milling_twin.models.interpolator.definition import default_parameters
from milling_twin.models.interpolator.parser import DIALECT_SINUMERIK, MOVE_LINE, Tool, parse_program
from milling_twin.orchestrator.optimize import program_edit
from milling_twin.orchestrator.optimize.program_edit import ProgramEditError
from milling_twin.orchestrator.optimize.sub_blocks import (MARGIN, LineProfile, SubBlockPlan, plan_line,
                                                           split_lines, splittable_lines)

D = 0.010   # m: a 10 mm tool


def profile(forces_per_mm: list[float], diameter: float = D) -> LineProfile:
    """A line of len(forces_per_mm) mm, 20 samples per mm, each mm at its force."""
    n = len(forces_per_mm)
    fraction = (np.arange(20 * n) + 0.5) / (20 * n)
    force = np.repeat(np.asarray(forces_per_mm, dtype=float), 20)
    return LineProfile(7, n * 1e-3, diameter, fraction, force)


def test_a_line_from_air_into_full_width_is_cut_where_the_force_starts() -> None:
    plan = plan_line(profile([0.0] * 30 + [200.0] * 50), D / 2)
    assert plan is not None and len(plan.boundaries) == 1 and plan.peaks == (0.0, 200.0)
    # the bins are 5 mm: the boundary at 30 mm, moved 1 mm (0.1 D) into the air, so the cut part covers its rise
    assert plan.boundaries[0] * 80 == pytest.approx(30 - MARGIN * 10)


def test_even_force_small_changes_and_short_peaks_keep_the_line_whole() -> None:
    assert plan_line(profile([100.0] * 60), D / 2) is None
    assert plan_line(profile([100.0] * 30 + [120.0] * 30), D / 2) is None   # within 1.25
    # a 5 mm peak at the end of a 60 mm line is a part of its own with parts down to the radius, not with 10 mm
    corner = profile([80.0] * 55 + [110.0] * 5)
    assert plan_line(corner, D / 2) is not None and plan_line(corner, D) is None
    assert plan_line(profile([0.0] * 4 + [200.0] * 4), D / 2) is None       # shorter than two bins


def test_a_line_has_at_most_four_parts_and_an_intermittent_cut_is_one() -> None:
    stairs = profile([50.0] * 10 + [100.0] * 10 + [200.0] * 10 + [400.0] * 10 + [800.0] * 10)
    plan = plan_line(stairs, D / 2)
    assert plan is not None and plan.peaks == (100.0, 200.0, 400.0, 800.0)   # the lightest two joined
    assert [round(b * 50, 6) for b in plan.boundaries] == [20 - 1, 30 - 1, 40 - 1]   # into the lighter part
    # cutting 5 mm, 5 mm in air, six times over: one part at the force of the cuts (a part per gap would be 12)
    assert plan_line(profile(([0.0] * 5 + [200.0] * 5) * 6), D / 2) is None


TOOLS = (Tool(1, 0.010), Tool(2, 0.006))


def parse(text: str, dialect: int = 0, file: str = "prog.nc"):
    return parse_program(text, default_parameters(), file, dialect=dialect, tools=TOOLS)


def test_a_planned_line_is_written_as_its_parts_above_it_with_a_comment_naming_it() -> None:
    text = PROGRAM.replace("G1 X60 F600", "N60 G1 X60 F600 (SLOT)")
    program = parse(text)
    assert set(splittable_lines(program, text)) == {5, 6}
    split = split_lines(text, {6: SubBlockPlan(6, (0.25, 0.5), (0.0, 150.0, 120.0))}, parse)
    lines = split.text.splitlines()
    assert lines[5:8] == ["G1 X7.5 F600 (SUB-BLOCK 1/3 OF N60, LINE 6)", "G1 X25. F600 (SUB-BLOCK 2/3 OF N60, LINE 6)",
                          "N60 G1 X60 F600 (SLOT)"]
    assert split.origin[6] == split.origin[7] == split.origin[8] == 6 and split.origin[9] == 7
    assert split.parts == {6: (1, 3), 7: (2, 3), 8: (3, 3)} and split.label(7) == "6 (2/3)" and split.label(9) == "7"
    moves = [m for m in parse(split.text).moves if m.line in (6, 7, 8)]
    assert [round(m.end[0] * 1e3, 9) for m in moves] == [7.5, 25.0, 60.0] and {m.feed for m in moves} == {0.01}
    # the feed schedule then gives each part its own F; the original line keeps every word but F
    edited = program_edit.rewrite_feeds(split.text, {6: 4.0, 7: 1.0, 8: 0.5}, parse)
    new = edited.text.splitlines()
    assert new[5].startswith("G1 X7.5 F2400.") and new[6].startswith("G1 X25. F600 ")
    assert new[7] == "N60 G1 X60 F300.0 (SLOT)"


def test_inch_lowercase_and_sinumerik_programs_get_parts_in_their_own_words() -> None:
    inch = "g20 g90 g17\nt1 m6\ns6000 m3\ng0 x-0.5 y0.4 z0.2\ng1 z-0.08 f12\ng1 x2.5 f24\nm30\n"
    split = split_lines(inch, {6: SubBlockPlan(6, (0.5,), (0.0, 1.0))}, parse)
    assert split.text.splitlines()[5] == "g1 x1. f24 (SUB-BLOCK 1/2 OF LINE 6)"
    sinumerik = "G90 G17 G71\nT1\nM6\nS6000 M3\nG0 X-10 Y10 Z5\nG1 Z-2 F300\nN70 G1 X60 F600\nM30\n"

    def parse_s(t: str):
        return parse(t, DIALECT_SINUMERIK, "PART.MPF")
    split = split_lines(sinumerik, {7: SubBlockPlan(7, (0.5,), (0.0, 1.0))}, parse_s, "PART.MPF", "sinumerik")
    assert split.text.splitlines()[6] == "G1 X25. F600 ; sub-block 1/2 of N70, line 7"


@pytest.mark.parametrize("line, why", [
    ("G91 G1 X70 F600", "incremental"),
    ("G1 G41 D1 X60 F600", "cutter radius compensation"),
    ("G1 X60 F600 S5000", "a word that changes the machine's state"),
    ("G2 X60 Y10 I35 J0 F600", "an arc"),
])
def test_lines_that_cannot_be_split_exactly_are_left_whole(line: str, why: str) -> None:
    text = PROGRAM.replace("G1 X60 F600", line)
    program = parse(text)
    assert 6 not in splittable_lines(program, text), why
    with pytest.raises(ProgramEditError, match=r"prog.nc line 6: .*not a line the optimizer splits"):
        split_lines(text, {6: SubBlockPlan(6, (0.5,), (0.0, 1.0))}, parse, "prog.nc")


def test_a_slot_that_starts_in_air_runs_its_air_part_at_the_fastest_feed(tmp_path: Path, fmu_dir: Path) -> None:
    """The tiny part's slot line starts 30 mm before the block: with sub-blocks the air goes at the largest feed
    per tooth, the slot at its force limit; the optimized program keeps every original line (F aside) and each
    inserted part names its line; its re-simulation holds the limits, and the cycle is shorter than with one feed
    for the line."""
    program = PROGRAM.replace("G0 X-10 Y10 Z5", "G0 X-40 Y10 Z5")
    section = ('[optimize]\nmax_iterations = 4\n[optimize.limits]\nforce = { value = 150, unit = "N" }\n'
               'feed_per_tooth = { value = [0.01, 0.1], unit = "mm" }\n[part.spindle]')
    part = write_part(tmp_path / "part", ("[part.spindle]", section),
                      ('start_x = { value = -10', 'start_x = { value = -40'), program=program)
    whole = milling_twin.optimize(part, fmu_dir=fmu_dir, out=tmp_path / "whole", sub_blocks=False)
    result = milling_twin.optimize(part, fmu_dir=fmu_dir, out=tmp_path / "split")
    assert result.sub_blocks is not None and 6 in result.sub_blocks.plans
    best = result.best
    assert best.sub_blocks and best.feasible and max(best.peak_force.values()) <= 150.0 * 1.01
    assert best.cycle_time < whole.best.cycle_time - 0.2, (best.cycle_time, whole.best.cycle_time)
    new = result.program.read_text().splitlines()
    inserted = [ln for ln in new if "SUB-BLOCK" in ln]
    assert inserted and all(re.search(r"SUB-BLOCK \d/\d OF LINE 6\)", ln) for ln in inserted)
    kept = [ln for ln in new if "SUB-BLOCK" not in ln]
    assert [re.sub(r"F[\d.]+", "", ln).strip() for ln in kept] == \
        [re.sub(r"F[\d.]+", "", ln).strip() for ln in program.splitlines()]
    air = [m for m in parse(result.program.read_text()).moves if m.kind == MOVE_LINE and m.end[0] < -0.006]
    assert air and air[0].feed * 60000 == pytest.approx(0.1 * 3 * 6000, rel=1e-3)   # fz max x flutes x rpm
    table = (result.folder / "blocks_before_after.csv").read_text()
    assert "sub-block" in table.splitlines()[0] and (",1/2," in table or ",1/3," in table)

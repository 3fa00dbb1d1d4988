"""The optimizer's program rewriting (orchestrator/optimize/program_edit.py): only F words change, modal feeds are
restored after a changed line, the result is checked against the original by the Interpolator's parser, and what
cannot be rewritten exactly is refused naming the line."""
from __future__ import annotations

import math
import random
import re
from pathlib import Path

import pytest

from milling_twin.models.interpolator.definition import default_parameters
from milling_twin.models.interpolator.parser import DIALECTS, Tool, parse_program
from milling_twin.models.interpolator.tool_table import read_tool_table
from milling_twin.orchestrator.optimize.program_edit import ProgramEditError, format_feed, rewrite_feeds
from milling_twin.orchestrator.part.blocks import feed_lines

REPO = Path(__file__).resolve().parents[1]
TOOLS = (Tool(1, 0.01, flutes=3), Tool(2, 0.006, flutes=2))
CORPUS = REPO / "scenarios" / "programs" / "corpus"
BRACKET = REPO / "scenarios" / "parts" / "al_pocket.nc"


def parser(dialect: str = "fanuc", tools=()):
    def parse(text: str):
        return parse_program(text, default_parameters(), "part.nc", dialect=DIALECTS[dialect], tools=tools)
    return parse


def without_f(line: str) -> str:
    """A line with its F words taken out (what must stay the same)."""
    return re.sub(r"\s?F=?[-+]?(\d+\.?\d*|\.\d+)", "", line, flags=re.IGNORECASE).rstrip()


SIMPLE = """G21 G90 G17
S6000 M3
G0 X0 Y0 Z1
G1 Z-1 F300 (plunge)
X10 F1200
Y10
X0
G0 Z5
M30
"""


def test_a_changed_line_gets_its_feed_and_the_next_line_gets_back_the_old_one() -> None:
    edited = rewrite_feeds(SIMPLE, {5: 1.5, 6: 0.5}, parser())
    lines = edited.text.splitlines()
    assert lines[4] == "X10 F1800.0"                     # its own F word replaced
    assert lines[5] == "Y10 F600.0"                      # inherited: an F word of its own
    assert lines[6] == "X0 F1200"                        # back to the feed it had, as written
    assert lines[3] == "G1 Z-1 F300 (plunge)"            # untouched
    assert edited.changed_lines == (5, 6, 7)
    moves = {m.line: m.feed for m in parser()(edited.text).moves}
    assert moves[5] == pytest.approx(0.03) and moves[6] == pytest.approx(0.01) and moves[7] == pytest.approx(0.02)


def test_a_skipped_line_with_an_f_word_stays_as_it_is() -> None:
    text = SIMPLE.replace("Y10\n", "/G1 Y5 F99\nY10\n")
    edited = rewrite_feeds(text, {7: 2.0}, parser())
    assert edited.text.splitlines()[5] == "/G1 Y5 F99" and edited.text.splitlines()[6] == "Y10 F2400.0"


def test_a_tool_s_spindle_speed_changes_in_its_s_words_and_its_moves() -> None:
    text = "G21 G90\nT1 M6\nS6000 M3\nG0 X0 Y0 Z1\nG1 Z-1 F300\nT2 M6\nS8000 M3 (T2)\nG1 X5\nM30\n"
    edited = rewrite_feeds(text, {5: 2.0}, parser("fanuc", TOOLS), speeds={1: 1.0225})
    lines = edited.text.splitlines()
    assert lines[2] == "S6135 M3" and lines[6] == "S8000 M3 (T2)" and lines[4] == "G1 Z-1 F600.0"
    assert edited.speeds == {1: pytest.approx(6135 / 6000)}
    spindles = {m.line: m.spindle * 30 / math.pi for m in parser("fanuc", TOOLS)(edited.text).moves}
    assert spindles[5] == pytest.approx(6135.0) and spindles[8] == pytest.approx(8000.0)


def test_factor_one_everywhere_leaves_the_text_as_it_is() -> None:
    edited = rewrite_feeds(SIMPLE, {line: 1.0 for line in feed_lines(parser()(SIMPLE))}, parser())
    assert edited.text == SIMPLE and edited.changed_lines == ()


def test_comments_spacing_and_line_endings_stay() -> None:
    text = SIMPLE.replace("\n", "\r\n").replace("X10 F1200", "x10 f1200 ; along x")
    edited = rewrite_feeds(text, {5: 2.0}, parser())
    assert edited.text.splitlines(keepends=True)[4] == "x10 f2400.0 ; along x\r\n"
    assert edited.text.count("\r\n") == text.count("\r\n")


def test_the_bracket_program_with_random_feeds_keeps_every_move_and_only_f_words_change() -> None:
    text = BRACKET.read_text(encoding="latin-1")
    tools = read_tool_table(REPO / "scenarios" / "parts" / "tool.tbl")
    parse = parser("fanuc", tools)
    lines = sorted(feed_lines(parse(text)))
    rng = random.Random(7)
    factors = {line: rng.uniform(0.3, 3.0) for line in lines}
    edited = rewrite_feeds(text, factors, parse)  # raises when a move or a feed does not come out as asked
    old, new = text.splitlines(), edited.text.splitlines()
    assert len(old) == len(new)
    assert [without_f(a) for a in old] == [without_f(b) for b in new]
    assert set(edited.changed_lines) >= set(lines) - {line for line in lines if abs(factors[line] - 1) < 1e-4}
    for line in lines:
        assert edited.factors[line] == pytest.approx(factors[line], rel=1e-3)


@pytest.mark.parametrize("program", sorted(p for p in CORPUS.glob("*/*") if p.suffix.lower() in
                                           (".nc", ".ngc", ".mpf")), ids=lambda p: p.name)
def test_every_corpus_program_is_rewritten_exactly_or_refused_naming_the_line(program: Path) -> None:
    dialect = program.parent.name
    parse = parser(dialect, read_tool_table(CORPUS / "tool.tbl"))
    text = program.read_text(encoding="latin-1")
    lines = sorted(feed_lines(parse(text)))
    factors = {line: 1.0 + 0.37 * ((k % 5) - 2) / 2 for k, line in enumerate(lines)}
    try:
        edited = rewrite_feeds(text, factors, parse, str(program), dialect)
    except ProgramEditError as exc:
        assert re.search(rf"{re.escape(str(program))} line \d+: ", str(exc)), exc
        return
    assert len(edited.text.splitlines()) == len(text.splitlines())
    assert [without_f(a) for a in text.splitlines()] == [without_f(b) for b in edited.text.splitlines()]


def test_lines_run_out_of_their_order_are_refused_naming_the_line() -> None:
    """A subprogram called twice: the F a line inherits depends on the call, not on the text above it."""
    text = ("G21 G90\nS6000 M3\nG0 X0 Y0 Z1\nG1 Z0 F500\nM98 P100 L2\nG1 X30\nM30\n"
            "O100\nG91 G1 X5 F800\nY5\nG90\nM99\n")
    with pytest.raises(ProgramEditError, match=r"part.nc line 9: .*runs after line 10 \(a subprogram call"):
        rewrite_feeds(text, {9: 2.0}, parser(), "part.nc")


def test_a_one_line_subprogram_with_its_own_feed_is_rewritten() -> None:
    text = "G21 G90\nS6000 M3\nG0 X0 Y0 Z1\nG1 Z0 F500\nM98 P100 L2\nM30\nO100\nG91 G1 X5 F800\nG90\nM99\n"
    edited = rewrite_feeds(text, {8: 2.0}, parser(), "part.nc")
    assert [m.feed for m in parser()(edited.text).moves if m.line == 8] == pytest.approx([0.16 / 6] * 2)


def test_a_sinumerik_feed_expression_is_refused_and_a_number_rewritten() -> None:
    parse = parser("sinumerik")
    text = "G71 G90 G17\nS6000 M3\nG0 X0 Y0 Z1\nR1=400\nG1 Z0 F=R1\nG1 X10 F=1200\nM30\n"
    with pytest.raises(ProgramEditError, match=r"part.nc line 5: .*expression"):
        rewrite_feeds(text, {6: 1.5}, parse, "part.nc", "sinumerik")
    text = text.replace("F=R1", "F400")
    edited = rewrite_feeds(text, {6: 1.5}, parse, "part.nc", "sinumerik")
    assert edited.text.splitlines()[5] == "G1 X10 F=1800.0"


def test_a_line_without_a_feed_move_cannot_be_given_a_factor() -> None:
    with pytest.raises(ProgramEditError, match="line 3: no feed move"):
        rewrite_feeds(SIMPLE, {3: 2.0}, parser(), "part.nc")


@pytest.mark.parametrize("value,text", [(1663.2, "1663.2"), (1386.0, "1386.0"), (0.12345, "0.1235"),
                                        (12.5, "12.50"), (25000.4, "25000.4")])
def test_feeds_are_written_with_four_significant_digits_at_least(value: float, text: str) -> None:
    assert format_feed(value) == text

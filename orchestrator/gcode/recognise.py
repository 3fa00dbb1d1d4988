"""Is a file a part program (or a tool table) at all? Checked before a parser reads it, so that a file of another
kind is refused without any of its content in the message.

A parser's messages quote the offending line of a file (``<file> line 3: "G1 X": a number after 'X'``). That is
right for a part program with a mistake, and wrong for a file that is not one: the first line of a system file, a
process's environment. So the orchestrator opens the file first (:mod:`milling_twin.orchestrator.input_files`:
a regular file only) and reads its first 64 KiB; it is a part program (or tool table) when

* it holds no NUL or other control byte (but tab, line feed, form feed, carriage return and the tape's DC2/DC4),
* and its first line with content (after blank lines, comments ``( )`` and ``;``, ``%`` tape marks and block-skip
  ``/``) starts with a G-code word: an address letter and a number (``G21``, ``N10``, ``T1``, ``O1000``,
  ``o100 sub``), ``:1000``, an address or R parameter with ``=`` (Sinumerik: ``R1=5``, ``T="END10"``,
  ``ADIS=0.1``) or one of the Sinumerik statements the translator reads (``MSG``, ``PROC``, ``TRANS``,
  ``BSPLINE``, ``CYCLE832``, ...).

Otherwise :class:`NotThatFileError` says "not a part program" (or "not a tool table") and why, naming the path and
at most a line number and a byte value.
"""
from __future__ import annotations

import re
from pathlib import Path

from milling_twin.orchestrator.input_files import InputFileError, open_input

__all__ = ["NotThatFileError", "check_part_program", "check_tool_table"]

SNIFF_BYTES = 65536
_CONTROL = re.compile(rb"[\x00-\x08\x0b\x0e-\x11\x13\x15-\x1f\x7f]")
_COMMENTS = re.compile(r"\([^)]*\)?|;.*")
# The Sinumerik statements the translator (models/interpolator/sinumerik.py) reads without an address and number.
_STATEMENTS = ("MSG", "PROC", "TRANS", "ATRANS", "ROT", "AROT", "SCALE", "ASCALE", "MIRROR", "AMIRROR", "BSPLINE",
               "CYCLE832", "CALL", "RET", "SUPA", "SOFT", "BRISK", "FFWON", "FFWOF", "COMPOF", "COMPCAD", "COMPCURV",
               "COMPSURF", "UPATH", "SPATH", "FNORM", "CFC", "CFTCP", "CFIN", "DIAMOF", "TRAFOOF", "STOPRE")
_ASSIGNED = ("ADISPOS", "ADIS", "CR", "SD", "PW", "PL", r"R\d+", "[A-Z]")
_WORD = re.compile(r"(?i)\s*(?:[a-z]\s*[-+]?\s*[.\d]|(?:" + "|".join(_ASSIGNED) + r")\s*=|:\s*\d|(?:"
                   + "|".join(_STATEMENTS) + r")\b)")


class NotThatFileError(ValueError):
    """A file that cannot be read as the kind asked for; the message names the path, never its content."""


def _first_content_line(text: str) -> tuple[int, str] | None:
    for number, line in enumerate(text.split("\n"), 1):
        rest = _COMMENTS.sub("", line).strip()
        if not rest or rest.startswith("%") or rest.startswith("/"):
            continue
        return number, rest
    return None


def _check(path: Path, what: str) -> None:
    try:
        with open_input(path, what) as fh:
            start = fh.read(SNIFF_BYTES)
    except InputFileError as exc:
        raise NotThatFileError(exc.detail) from None
    control = _CONTROL.search(start)
    if control:
        line = start.count(b"\n", 0, control.start()) + 1
        raise NotThatFileError(f"{path}: not a {what} (binary content: byte 0x{start[control.start()]:02x} in "
                               f"line {line})")
    if len(start) == SNIFF_BYTES:  # the last line may be cut: judge the lines before it
        start = start[:start.rfind(b"\n") + 1] or start
    first = _first_content_line(start.decode("latin-1"))
    if first is not None and not _WORD.match(first[1]):
        raise NotThatFileError(f"{path}: not a {what} (line {first[0]}, its first line with content, does not start "
                               f"with a G-code word such as G1, N10, T1 or O1000)")


def check_part_program(path: str | Path) -> None:
    """Raise NotThatFileError unless ``path`` is a regular file that looks like a part program (module text)."""
    _check(Path(path), "part program")


def check_tool_table(path: str | Path) -> None:
    """Raise NotThatFileError unless ``path`` is a regular file that looks like a tool table (``T1 P1 D12 ...``)."""
    _check(Path(path), "tool table")


#: String parameters that name a file an FMU parses, by (model identifier, variable): the check of its kind.
FILE_PARAMETERS = {("Interpolator", "program"): check_part_program, ("Interpolator", "tool_table"): check_tool_table}

"""Typed access to the values of a parsed TOML file, every error naming the file and the key.

Shared by the scenario and calibration-spec readers; each sets ``error`` to its own exception type,
built as ``error(path, key, message)``."""
from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, NoReturn

from milling_twin.orchestrator.input_files import InputFileError, decode_text, read_input

#: The deepest nesting of arrays, inline tables and tables (dotted keys and headers count) a file may have: the
#: project's files use at most 6 levels; a deeper file is refused before it can exhaust the parser's recursion.
MAX_TOML_DEPTH = 32


# The two kinds of file the readers take, by their top table: what to call one, and the command that takes it.
KINDS = {"scenario": ("scenario file", "run"), "calibration": ("calibration spec", "calibrate")}


class FileKeyError(ValueError):
    """A bad input file: ``path``, the TOML ``key`` (may be empty) and what is wrong (``detail``); the message is
    ``"<path>: <key>: <detail>"``. The scenario, calibration-spec and study errors are its kinds."""

    def __init__(self, path: Path | str, key: str, message: str) -> None:
        self.path, self.key, self.detail = Path(path), key, message
        super().__init__(f"{path}: {key}: {message}" if key else f"{path}: {message}")


class TomlAccess:
    error: Callable[[Path, str, str], Exception]

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, message: str) -> NoReturn:
        raise type(self).error(self.path, key, message)

    def parse(self, what: str) -> tuple[bytes, dict[str, Any]]:
        """The file's bytes and its parsed TOML; a missing file fails as "``what`` not found", a path that is not
        a regular file (a FIFO, a device, /proc) as such (:mod:`milling_twin.orchestrator.input_files`), a byte
        that is not UTF-8 with its line and column, a file that is not TOML as "invalid TOML" with the parser's
        line and column, one nested deeper than MAX_TOML_DEPTH as such."""
        try:
            raw = read_input(self.path, what)
            text = decode_text(raw, self.path, what)
        except InputFileError as exc:
            detail = exc.detail.removeprefix(f"{self.path}: ").removeprefix(f"{self.path} ")
            self.fail("", detail)
        deep = nesting_problem(text)
        if deep:
            self.fail("", deep)
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            self.fail("", f"invalid TOML: {exc}")
        except RecursionError:  # not reached after nesting_problem; kept so that no traceback can escape
            self.fail("", f"invalid TOML: nested deeper than {MAX_TOML_DEPTH} levels")
        deep = _document_depth_problem(doc)
        if deep:
            self.fail("", deep)
        return raw, doc

    def document(self, kind: str) -> tuple[bytes, dict[str, Any]]:
        """The file's bytes and its parsed TOML, a file of ``kind`` ("scenario" or "calibration"); a missing
        file, invalid TOML, or a file of the other kind fails, the last saying which command takes it."""
        raw, doc = self.parse(KINDS[kind][0])
        other = next(k for k in KINDS if k != kind)
        if other in doc and kind not in doc:
            what, command = KINDS[other]
            self.fail("", f"this is a {what} ([{other}] table), not a {KINDS[kind][0]}: use "
                          f"`milling-twin {command} {self.path}`")
        return raw, doc

    def table(self, value: Any, key: str, allowed: Sequence[str]) -> dict[str, Any]:
        if value is None:  # absent (an empty or truncated file lacks every table)
            self.fail(key, "missing required table")
        if not isinstance(value, dict):
            self.fail(key, f"expected a table, got {type(value).__name__} {value!r}")
        for name in value:
            if name not in allowed:
                self.fail(f"{key}.{name}" if key else name,
                          f"unknown key {name!r}; known keys: {', '.join(allowed)}")
        return value

    def number(self, table: dict, key: str, name: str, default: Any = ..., positive: bool = False,
               minimum: float | None = None) -> Any:
        if name not in table:
            if default is ...:
                self.fail(f"{key}.{name}", "missing required key")
            return default
        value = table[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.fail(f"{key}.{name}", f"expected a finite number, got {value!r}")
        if positive and value <= 0:
            self.fail(f"{key}.{name}", f"must be > 0, got {value!r}")
        if minimum is not None and value < minimum:
            self.fail(f"{key}.{name}", f"must be >= {minimum!r}, got {value!r}")
        return float(value)

    def integer(self, table: dict, key: str, name: str, default: int, minimum: int) -> int:
        value = table.get(name, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            self.fail(f"{key}.{name}", f"expected a whole number >= {minimum}, got {value!r}")
        return value

    def string(self, table: dict, key: str, name: str, default: Any = ...,
               choices: Sequence[str] | None = None) -> Any:
        if name not in table:
            if default is ...:
                self.fail(f"{key}.{name}", "missing required key")
            return default
        value = table[name]
        if not isinstance(value, str):
            self.fail(f"{key}.{name}", f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            self.fail(f"{key}.{name}", f"{value!r} is not one of {', '.join(choices)}")
        return value

    def strings(self, table: dict, key: str, name: str, count: int) -> tuple[str, ...]:
        value = table.get(name, [])
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value) or len(value) != count:
            self.fail(f"{key}.{name}", f"expected a list of {count} strings, got {value!r}")
        return tuple(value)


def nesting_problem(text: str, limit: int = MAX_TOML_DEPTH) -> str | None:
    """Where TOML ``text`` nests arrays and inline tables deeper than ``limit`` ("line L, column C: ..."), or
    None; strings and comments are skipped, the rest of the syntax is left to the parser."""
    if text.count("[") + text.count("{") <= limit:  # cannot nest deeper: the scan is skipped
        return None
    depth, line, start, i, n = 0, 1, 0, 0, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            line, start = line + 1, i + 1
        elif c == "#":
            end = text.find("\n", i)
            i = n if end < 0 else end
            continue
        elif c in "\"'":
            quote = text[i:i + 3] if text[i:i + 3] in ('"""', "'''") else c
            j = i + len(quote)
            while j < n and not text.startswith(quote, j):
                if text[j] == "\\" and quote[0] == '"':
                    j += 1  # the escaped character (a line end: a line continuation, counted below)
                if j < n and text[j] == "\n":
                    if len(quote) == 1:
                        break  # an unclosed one-line string: the parser says so
                    line, start = line + 1, j + 1
                j += 1
            i = j + len(quote) if text.startswith(quote, j) else j
            continue
        elif c in "[{":
            depth += 1
            if depth > limit:
                return f"line {line}, column {i - start + 1}: arrays and inline tables nested more than {limit} levels"
        elif c in "]}":
            depth = max(depth - 1, 0)
        i += 1
    return None


def _document_depth_problem(doc: dict[str, Any], limit: int = MAX_TOML_DEPTH) -> str | None:
    """A parsed document nested (tables, dotted keys, arrays) deeper than ``limit``, named by the key path to the
    first such value (its first components), or None; iterative, so any depth is measured."""
    stack: list[tuple[Any, tuple[str, ...]]] = [(doc, ())]
    while stack:
        value, keys = stack.pop()
        if len(keys) > limit:
            shown = ".".join(k[:20] for k in keys[:4])
            return f"{shown}...: tables, dotted keys and arrays nested more than {limit} levels"
        if isinstance(value, dict):
            stack.extend((v, keys + (str(k),)) for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((v, keys + (f"[{i}]",)) for i, v in enumerate(value))
    return None

"""Typed access to the values of a parsed TOML file, every error naming the file and the key.

Shared by the scenario and calibration-spec readers; each sets ``error`` to its own exception type,
built as ``error(path, key, message)``."""
from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, NoReturn


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
        """The file's bytes and its parsed TOML; a missing file fails as "``what`` not found", a file that is not
        UTF-8 TOML as "invalid TOML" with the parser's line and column."""
        try:
            raw = self.path.read_bytes()
            return raw, tomllib.loads(raw.decode("utf-8"))
        except FileNotFoundError:
            self.fail("", f"{what} not found")
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            self.fail("", f"invalid TOML: {exc}")

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

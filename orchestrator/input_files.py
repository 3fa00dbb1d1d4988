"""The one place that opens the files a user names: scenario and calibration-spec files, parameter sets, part
programs, tool tables and recordings.

A user file is untrusted input, so only a regular file is opened:

* a missing path, a directory, a FIFO (named pipe), a socket or a device is refused before it is opened (a FIFO
  would block the reader until something writes to it);
* a file under ``/proc``, ``/sys`` or ``/dev`` (kernel interfaces: their "regular files" are a process's
  environment, its memory map, ...) is refused by its resolved path;
* the file is opened with ``O_NONBLOCK`` and checked again on the open descriptor (``fstat``: still a regular
  file, the same inode as the path named), so a path swapped for a FIFO between the check and the open neither
  blocks nor is read.

Every refusal is an :class:`InputFileError` (a ``ValueError``) whose ``detail`` names the path and says what it
is; callers add the key or option that named the path (``[recorded].file: ...``). Nothing of a file's content is
in these messages.

:func:`decode_text` decodes bytes and names the line and column (1-based, the column counted in characters
before the byte) of the first byte that is not valid in the encoding.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

__all__ = ["InputFileError", "check_regular", "decode_text", "open_input", "read_input", "text_position"]

#: Folders whose files are kernel interfaces, never user data (resolved paths, so a symbolic link is followed).
KERNEL_FOLDERS = (Path("/proc"), Path("/sys"), Path("/dev"))


class InputFileError(ValueError):
    """A user file that cannot be read as one: ``path`` and what is wrong (``detail``, which names the path)."""

    def __init__(self, path: Path | str, detail: str) -> None:
        self.path, self.detail = Path(path), detail
        super().__init__(detail)


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a regular file"


def _kernel_folder(path: Path) -> Path | None:
    resolved = Path(os.path.realpath(path))
    return next((folder for folder in KERNEL_FOLDERS if resolved.is_relative_to(folder)), None)


def check_regular(path: str | Path, what: str = "file") -> os.stat_result:
    """The ``stat`` of ``path`` if it is a regular file outside the kernel folders; else InputFileError saying
    what ``path`` is (``what``: the kind of file expected, for the message: "part program", "recording")."""
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise InputFileError(path, f"{path}: {what} not found") from None
    except OSError as exc:
        raise InputFileError(path, f"{path}: cannot read the {what}: {exc.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputFileError(path, f"{path} is {_kind(info.st_mode)}, not a regular file (the {what} must be one)")
    folder = _kernel_folder(path)
    if folder is not None:
        raise InputFileError(path, f"{path} is under {folder}, a kernel interface, not a regular file (the {what} "
                                   f"must be one)")
    return info


def open_input(path: str | Path, what: str = "file") -> BinaryIO:
    """``path`` opened for reading in binary, once checked to be a regular file (:func:`check_regular`, then
    again on the open descriptor); the caller closes it."""
    path = Path(path)
    before = check_regular(path, what)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise InputFileError(path, f"{path}: {what} not found") from None
    except OSError as exc:
        raise InputFileError(path, f"{path}: cannot open the {what}: {exc.strerror}") from None
    try:
        after = os.fstat(fd)
        if not stat.S_ISREG(after.st_mode) or (after.st_dev, after.st_ino) != (before.st_dev, before.st_ino):
            raise InputFileError(path, f"{path} changed while it was opened (now {_kind(after.st_mode)}, the {what} "
                                       f"must be a regular file that stays in place)")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_input(path: str | Path, what: str = "file") -> bytes:
    """The bytes of the regular file ``path`` (see :func:`open_input`)."""
    with open_input(path, what) as fh:
        try:
            return fh.read()
        except OSError as exc:
            raise InputFileError(path, f"{path}: cannot read the {what}: {exc.strerror}") from None


def text_position(raw: bytes, offset: int, encoding: str = "utf-8") -> tuple[int, int]:
    """Line and column (1-based) of byte ``offset`` of ``raw``: the column counts the characters before it on its
    line (a multi-byte character counts once)."""
    start = raw.rfind(b"\n", 0, offset) + 1
    column = len(raw[start:offset].decode(encoding, errors="replace")) + 1
    return raw.count(b"\n", 0, offset) + 1, column


def decode_text(raw: bytes, path: str | Path, what: str = "file", encoding: str = "utf-8") -> str:
    """``raw`` decoded; a byte that is not valid ``encoding`` is an InputFileError naming its line, column and
    value (the byte alone, nothing else of the file)."""
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        line, column = text_position(raw, exc.start, encoding)
        name = "UTF-8" if encoding.lower().replace("_", "-").startswith("utf-8") else encoding
        raise InputFileError(path, f"{path} line {line}, column {column}: byte 0x{raw[exc.start]:02x} is not "
                                   f"valid {name}: the {what} must be {name} text") from None

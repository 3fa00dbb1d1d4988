"""Files written atomically: complete under their final name, or not changed at all.

A report, a figure or a calibration output is written to a temporary file in the same folder (a hidden
``.<name>.<random>.tmp``, which no ``*.png`` or ``*.parquet`` pattern matches; a writer that chooses the
format by the suffix, such as matplotlib's ``savefig``, is given the format), flushed to the disk (``fsync``)
and renamed over the final name (``os.replace``, atomic on POSIX and Windows within one folder). On any error
(a full disk, an I/O error, Ctrl-C) the temporary file is removed and the final name keeps what it had. An
``OSError`` is raised again naming the final file (``[Errno 28] No space left on device: '<path>'``), so that
the one-line message of the command says which file could not be written.

:func:`write_text` and :func:`write_bytes` take the content; :func:`write_with` takes a function that writes
a path (a library's writer: ``savefig(tmp, format="png")``, ``to_parquet``, ``to_csv``); :func:`writing` is
the context manager under both, for code that writes into an open file.
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any, TypeVar

__all__ = ["temporary_name", "write_bytes", "write_text", "write_with", "writing"]

T = TypeVar("T")


def temporary_name(path: Path) -> Path:
    """A fresh hidden name beside ``path`` (``report.html`` -> ``.report.html.1f2e3d4c.tmp``)."""
    return path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")


def _fsync(path: Path) -> None:
    """Flush ``path``'s content to the disk (opened for writing: Windows needs it for FlushFileBuffers)."""
    fd = os.open(path, os.O_RDWR | getattr(os, "O_BINARY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _failed(path: Path, tmp: Path, exc: OSError) -> OSError:
    """``exc`` naming the final file ``path`` instead of the temporary one or none (an error that names
    another file, e.g. of a nested atomic write, is left as it is)."""
    if exc.filename is not None and str(exc.filename) != str(tmp):
        return exc
    if exc.errno is None:  # numpy's tofile on a full disk: "20000 requested and 2947 written", no errno
        return OSError(errno.EIO, f"{exc} (a short write)", str(path))
    return OSError(exc.errno, exc.strerror or str(exc), str(path))  # FileNotFoundError etc. by its errno


@contextlib.contextmanager
def _replacing(path: Path, sync: bool) -> Iterator[Path]:
    """The temporary path to write; on a clean exit it is flushed and renamed to ``path``, else removed."""
    tmp = temporary_name(path)
    try:
        yield tmp
        if sync:
            _fsync(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        error = _failed(path, tmp, exc)
        if error is exc:
            raise
        raise error from exc
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(tmp)


@contextlib.contextmanager
def writing(path: str | Path, mode: str = "wb", *, encoding: str | None = None, newline: str | None = None,
            sync: bool = True) -> Iterator[IO[Any]]:
    """An open temporary file (``mode`` "w" or "wb") that becomes ``path`` when the block ends without error."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic write of {path}: mode {mode!r}, expected 'w' or 'wb'")
    path = Path(path)
    with _replacing(path, sync) as tmp:
        with open(tmp, mode.replace("w", "x"), encoding=encoding, newline=newline) as fh:
            yield fh


def write_bytes(path: str | Path, data: bytes, *, sync: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    with writing(path, "wb", sync=sync) as fh:
        fh.write(data)
    return Path(path)


def write_text(path: str | Path, text: str, *, encoding: str = "utf-8", sync: bool = True) -> Path:
    """Write ``text`` to ``path`` atomically (``encoding``, no newline translation); returns ``path``."""
    with writing(path, "w", encoding=encoding, newline="", sync=sync) as fh:
        fh.write(text)
    return Path(path)


def write_with(path: str | Path, writer: Callable[[Path], T], *, sync: bool = True) -> T:
    """Call ``writer`` with a temporary path beside ``path`` (suffix ``.tmp``), then rename it to ``path``;
    returns what ``writer`` returned. The writer creates the file (a library's ``savefig``, ``to_csv``, ...)."""
    path = Path(path)
    with _replacing(path, sync) as tmp:
        result = writer(tmp)
        if not tmp.is_file():
            raise OSError(errno.ENOENT, "the writer did not create the file", str(path))
    return result

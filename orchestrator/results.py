"""Incremental results of a run, safe against the process dying at any moment.

A run folder holds::

    run.json                      provenance and status (see RunWriter)
    chunks/chunk_000001.parquet   rows in time order, one file per flush
    chunks/chunk_000002.parquet   ...

Units: the values are SI. Each chunk's Parquet schema carries, per column, the field metadata
``b"unit"`` (the variable's SI unit, e.g. ``b"W"``; ``b"s"`` for ``time``; ``b"bool"`` for booleans) and
``b"display_unit"`` (e.g. ``b"kW"``) where the model description gives them, so that every chunk,
even of a killed run, says what its numbers are; ``run.json`` holds the same as ``"units"``:
``{column: {"unit": ..., "display_unit": ...}}``. ``load_results`` returns them as
``df.attrs["units"]`` (column -> unit, "" where none is declared) and ``df.attrs["display_units"]``
(column -> display unit, only the columns that have one).

Every file is written to a temporary name in its final folder and then renamed with
``os.replace``, so a chunk or ``run.json`` is either complete or absent. Chunks are
flushed every ``flush_rows`` rows, after ``flush_seconds`` of wall time since the last
flush (checked when a row arrives), and at the end. ``load_results`` therefore reads a
consistent prefix of the run even if it was killed (its ``run.json`` then still says
``"running"``).

Durability: the rename is what protects against a killed or crashed process (the data of a
written file is in the kernel's page cache, which outlives the process), so chunks and the
first ``run.json`` are not fsynced: an fsync costs about 3 ms here and would only add
protection against the operating system itself stopping (power loss, kernel crash) within
the few seconds before the kernel writes the data back. One fsync is kept: the final
``run.json`` (status, rows written, wall times), the record a later reader trusts to know how
the run ended; after a power loss it then still says how many rows the run wrote.

Ownership: a run owns its folder exclusively (:class:`RunFolder`): an operating-system lock on the file
``.run.lock`` in the folder (``fcntl.flock`` on POSIX, ``msvcrt.locking`` on Windows), held from before the
first file is removed or written until the run (and what is written after it, such as its report) is done,
and released by the operating system when the process dies, so a killed run never leaves the folder busy. A
second run into a busy folder refuses (:class:`RunFolderBusy`, naming the folder and the process holding
it), waits for it, or takes the first free ``<folder>-2``, ``<folder>-3``, ... (``if_busy``: "refuse",
"wait", "new"). On POSIX the lock file is removed when the lock is released (a waiting run then checks that
the file it locked is still the folder's); on Windows it stays. Each run has an id (``run_id``, 32 hex
digits) written into ``run.json`` and into every chunk's schema metadata (``b"run_id"``): ``load_results``
refuses a folder whose chunks come from more than one run (:class:`MixedRunError`, naming the chunk).

Failures: a file that cannot be written (disk full, an I/O error) raises :class:`ResultsWriteError` (an
``OSError``) naming the file; its temporary file is removed. ``finish`` then still writes ``run.json`` with
status ``failed: <message>`` when it can (when the atomic rename cannot be made for want of space, by
rewriting ``run.json`` in place, which frees its old blocks first).

pandas and pyarrow are imported when first needed (writing a chunk, loading results), not
with this module: a command-line run does not pay for pandas.
"""
from __future__ import annotations

import datetime as _dt
import errno
import hashlib
import itertools
import json
import os
import platform
import time
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import sys
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["IF_BUSY", "MixedRunError", "ResultsWriteError", "RunFolder", "RunFolderBusy", "RunWriter", "load_results",
           "read_run_info", "sha256_of", "software_versions"]

CHUNK_DIR = "chunks"
RUN_INFO = "run.json"
LOCK_FILE = ".run.lock"
IF_BUSY = ("refuse", "wait", "new")  # what a run does when its folder is owned by another run
RUN_ID_KEY = b"run_id"  # the chunks' schema metadata key of the run's id


def sha256_of(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def software_versions() -> dict[str, str]:
    """Versions of Python, fmpy, numpy and of pandas, pyarrow and casadi when they are loaded."""
    import fmpy

    versions = {"python": platform.python_version(), "fmpy": fmpy.__version__, "numpy": np.__version__}
    for name in ("pandas", "pyarrow", "casadi"):
        if name in sys.modules:
            versions[name] = sys.modules[name].__version__
    return versions


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


class ResultsWriteError(OSError):
    """A file of a run could not be written (disk full, I/O error, ...): the message names the file."""


class RunFolderBusy(RuntimeError):
    """The run folder is owned by another run (see :class:`RunFolder`)."""


class MixedRunError(ValueError):
    """A run folder holds chunks of more than one run."""


def _replace_atomically(path: Path, write: Any, durable: bool = False) -> None:
    """Write ``path`` through a temporary file and a rename; ``durable``: fsync the file and its folder.
    An ``OSError`` becomes :class:`ResultsWriteError` naming ``path``; the temporary file is removed."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        try:
            tmp.unlink()
        except OSError:
            pass
        if isinstance(exc, ResultsWriteError):
            raise
        error = ResultsWriteError(f"cannot write {path}: {exc.strerror or exc}")
        error.errno = exc.errno
        raise error from exc
    if durable:
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _lock(fd: int, blocking: bool) -> bool:
    """Lock the open file ``fd`` exclusively; False when another process holds it and not ``blocking``."""
    if os.name == "nt":  # pragma: no cover - Windows
        import msvcrt

        while True:
            try:
                os.lseek(fd, 0, os.SEEK_SET)
                msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
                return True
            except OSError:
                if not blocking:
                    return False
                time.sleep(0.1)
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
    except BlockingIOError:
        return False
    return True


def _unlock(fd: int) -> None:
    if os.name == "nt":  # pragma: no cover - Windows
        import msvcrt

        os.lseek(fd, 0, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
    else:
        import fcntl

        fcntl.flock(fd, fcntl.LOCK_UN)


def _try_lock(folder: Path, blocking: bool) -> int | None:
    """The descriptor of ``folder``'s lock file, locked by this process, or None when another run holds it.
    A lock file removed by its previous owner between our open and our lock is not the folder's any more:
    open the new one and try again."""
    path = folder / LOCK_FILE
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            if not _lock(fd, blocking):
                os.close(fd)
                return None
            try:
                same = os.stat(path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
        except BaseException:
            os.close(fd)
            raise
        if same:
            return fd
        os.close(fd)


def _owner(folder: Path) -> str:
    """Who holds ``folder``'s lock, as its owner wrote it (pid, run id, since), for the busy message."""
    try:
        owner = json.loads((folder / LOCK_FILE).read_text())
        return f"process {owner['pid']} (run {owner['run_id']}, since {owner['since']})"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"


class RunFolder:
    """A run folder owned exclusively by this run until :meth:`release` (see the module text). Made by
    :meth:`claim`; a context manager releasing it at exit. ``path``: the folder (with ``if_busy="new"``,
    perhaps a suffixed one); ``run_id``: the run's id."""

    def __init__(self, path: Path, fd: int) -> None:
        self.path = path
        self.run_id = uuid.uuid4().hex
        self._fd: int | None = fd
        record = json.dumps({"pid": os.getpid(), "run_id": self.run_id, "since": _now()}).encode()
        try:  # written, then cut to its length if longer (truncating to 0 first makes ext4 flush it on close)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, record)
            if os.fstat(fd).st_size > len(record):
                os.ftruncate(fd, len(record))
        except OSError:  # only informative (the busy message); a full disk must not stop the run here
            pass

    @classmethod
    def claim(cls, path: str | Path, if_busy: str = "refuse", *, what: str = "run") -> "RunFolder":
        """Own ``path`` (created if missing). When another run owns it: "refuse" raises
        :class:`RunFolderBusy`, "wait" blocks until it is free, "new" claims the first of ``<path>-2``,
        ``<path>-3``, ... that does not exist yet. ``what``: "run", or what else owns the folder ("study",
        "calibration": their folders are claimed the same way, refusing with a message that says so)."""
        if if_busy not in IF_BUSY:
            raise ValueError(f"if_busy={if_busy!r}: expected one of {', '.join(IF_BUSY)}")
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        fd = _try_lock(path, blocking=if_busy == "wait")
        if fd is not None:
            return cls(path, fd)
        if if_busy == "refuse" and what != "run":
            raise RunFolderBusy(f"{path} is the folder of a {what} in progress ({_owner(path)}): its files would "
                                f"mix with this {what}'s; wait for it or choose another output folder (--out)")
        if if_busy == "refuse":
            raise RunFolderBusy(f"{path} is the folder of a run in progress ({_owner(path)}): its results would "
                                "mix with this run's; wait for it, choose another output folder, or give "
                                "--if-busy wait (start when it ends) or --if-busy new (a new folder "
                                f"{path.name}-2, ...)")
        for n in itertools.count(2):
            candidate = path.with_name(f"{path.name}-{n}")
            try:
                candidate.mkdir()
            except FileExistsError:
                continue
            fd = _try_lock(candidate, blocking=False)
            if fd is not None:
                return cls(candidate, fd)
        raise AssertionError("unreachable")

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Give the folder up (idempotent). POSIX: the lock file is removed first, while still locked."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            if os.name != "nt":
                try:
                    os.unlink(self.path / LOCK_FILE)
                except OSError:
                    pass
            _unlock(fd)
        finally:
            os.close(fd)

    def __enter__(self) -> "RunFolder":
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:
        try:
            self.release()
        except Exception:
            pass


class RunWriter:
    """Writes the rows of one run into ``run_dir`` (created; earlier results there are removed): a
    :class:`RunFolder` the caller claimed (and releases), or a path the writer claims (refusing a busy folder)
    and releases in :meth:`finish` or :meth:`close`.

    ``columns``: "time" first, then "instance.variable"; ``bool_columns``: those stored
    as booleans, ``int_columns``: as int32 (Int32 outputs; rows carry them as float64, which
    holds every int32 exactly). ``units``: by column, ``{"unit": ..., "display_unit": ...}`` (either
    may be absent or ""), written into every chunk's schema and into ``run.json`` (see the module
    text). ``info``: provenance for ``run.json`` (scenario, FMUs, ...), to which
    the writer adds versions, wall times, status, rows written and ``extra`` of
    :meth:`finish`.
    """

    def __init__(self, run_dir: str | Path | RunFolder, columns: Sequence[str], bool_columns: Sequence[str] = (),
                 info: dict[str, Any] | None = None, flush_rows: int = 10_000,
                 flush_seconds: float = 1.0, int_columns: Sequence[str] = (),
                 units: Mapping[str, Mapping[str, str]] | None = None) -> None:
        self._own_folder = not isinstance(run_dir, RunFolder)
        self.folder = RunFolder.claim(run_dir) if not isinstance(run_dir, RunFolder) else run_dir
        if not self.folder.held:
            raise ValueError(f"{self.folder.path}: the run folder was released before the run started")
        self.run_dir = self.folder.path
        self.run_id = self.folder.run_id
        self.columns = list(columns)
        self._types = [bool if c in set(bool_columns) else np.int32 if c in set(int_columns) else None
                       for c in self.columns]
        self.units = {c: {k: v for k, v in (units or {}).get(c, {}).items() if v} for c in self.columns}
        self._schema: Any = None  # the chunks' pyarrow schema, made at the first flush
        self._buffer = np.empty((flush_rows, len(self.columns)))
        self._fill = 0
        self._flush_seconds = flush_seconds
        self._last_flush = time.monotonic()
        self.chunks = 0
        self.rows_written = 0
        chunk_dir = self.run_dir / CHUNK_DIR
        chunk_dir.mkdir(parents=True, exist_ok=True)
        for stale in [*chunk_dir.iterdir(), *self.run_dir.glob("compare_*.png"),
                      self.run_dir / "report.json"]:
            if stale.is_file():
                stale.unlink()
        self.info = {**(info or {}), "run_id": self.run_id, "columns": self.columns, "bool_columns": list(bool_columns),
                     "int_columns": list(int_columns), "units": self.units,
                     "versions": software_versions(), "start_wall_time": _now(),
                     "end_wall_time": None, "status": "running", "rows_written": 0}
        self._write_info()

    def append(self, row: Sequence[float]) -> None:
        self._buffer[self._fill] = row
        self._fill += 1
        if self._fill == len(self._buffer) or time.monotonic() - self._last_flush >= self._flush_seconds:
            self.flush()

    def flush(self) -> None:
        self._last_flush = time.monotonic()
        if self._fill == 0:
            return
        import pyarrow as pa
        import pyarrow.parquet as pq

        block = self._buffer[: self._fill]
        arrays = [pa.array(block[:, i] if kind is None else block[:, i].astype(kind))
                  for i, kind in enumerate(self._types)]
        if self._schema is None:
            self._schema = _schema(self.columns, self._types, self.units).with_metadata(
                {RUN_ID_KEY: self.run_id.encode()})
        table = pa.Table.from_arrays(arrays, schema=self._schema)
        self.chunks += 1
        path = self.run_dir / CHUNK_DIR / f"chunk_{self.chunks:06d}.parquet"
        # no dictionary encoding for float columns: continuous signals hardly repeat, and trying costs
        # 7x the writing time (110 vs 16 ms per 100,000 rows of 5 columns) for larger files
        dictionary = [c for c, kind in zip(self.columns, self._types) if kind is not None]
        _replace_atomically(path, lambda fh: pq.write_table(table, fh, use_dictionary=dictionary))
        self.rows_written += self._fill
        self._fill = 0

    def finish(self, status: str, **extra: Any) -> None:
        """Flush the remaining rows and record the final ``status`` and ``extra`` in run.json; release the
        folder if the writer claimed it. When the rows cannot be written, run.json says ``failed: <message>``
        (unless ``status`` already says the run failed) and the error is raised after run.json is written
        (when it can be)."""
        error: OSError | None = None
        try:
            try:
                self.flush()
            except OSError as exc:
                error, self._fill = exc, 0
                if not status.startswith("failed"):
                    status = f"failed: {exc}"
                else:
                    error = None  # the run failed already (perhaps for the same reason): that error is raised
            self.info.update(extra, status=status, end_wall_time=_now(), versions=software_versions())
            self._write_info(durable=True)
        finally:
            if self._own_folder:
                self.close()
        if error is not None:
            raise error

    def close(self) -> None:
        """Release the run folder if the writer claimed it (finish does; for a writer never finished)."""
        if self._own_folder:
            self.folder.release()

    def _write_info(self, durable: bool = False) -> None:
        self.info["rows_written"] = self.rows_written
        text = json.dumps(self.info, indent=2, default=str).encode()
        path = self.run_dir / RUN_INFO
        try:
            _replace_atomically(path, lambda fh: fh.write(text), durable)
        except ResultsWriteError as exc:
            if not durable or exc.errno not in (errno.ENOSPC, errno.EDQUOT) or not path.exists():
                raise
            # no room for a second copy: rewrite the old run.json in place (its blocks are freed first), so
            # that it says how the run ended rather than "running"
            try:
                with open(path, "r+b") as fh:
                    before = fh.read()
                    try:
                        _rewrite(fh, text)
                    except OSError:
                        _rewrite(fh, before)  # it fitted before: run.json stays readable
                        raise
            except OSError:
                raise exc from None


def _rewrite(fh: Any, text: bytes) -> None:
    fh.seek(0)
    fh.truncate(0)
    fh.write(text)
    fh.flush()
    os.fsync(fh.fileno())


def _schema(columns: Sequence[str], types: Sequence[Any], units: Mapping[str, Mapping[str, str]]) -> Any:
    """The chunks' schema: each column's type and its units as field metadata (b"unit", b"display_unit")."""
    import pyarrow as pa

    kinds = {None: pa.float64(), bool: pa.bool_(), np.int32: pa.int32()}
    return pa.schema([pa.field(c, kinds[t], metadata={k.encode(): v.encode() for k, v in units[c].items()} or None)
                      for c, t in zip(columns, types)])


def read_run_info(run_dir: str | Path) -> dict[str, Any]:
    return json.loads((Path(run_dir) / RUN_INFO).read_text())


def load_results(run_dir: str | Path) -> pd.DataFrame:
    """All chunks of a run in order: column ``time`` first, then "instance.variable"; SI values.
    ``df.attrs["units"]``: column -> unit ("" where none is declared); ``df.attrs["display_units"]``:
    column -> display unit, for the columns that have one (from the chunks' field metadata; for a run
    without chunks, from ``run.json``). Raises :class:`MixedRunError`, naming the chunk, when a chunk was
    written by another run than ``run.json`` (or, without ``run.json``, than the first chunk)."""
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    run_dir = Path(run_dir)
    chunks = sorted((run_dir / CHUNK_DIR).glob("chunk_*.parquet"),
                    key=lambda p: int(p.stem.split("_")[1]))
    if not chunks:
        info = read_run_info(run_dir) if (run_dir / RUN_INFO).exists() else {}
        columns = info.get("columns", ["time"])
        df = pd.DataFrame({c: pd.Series(dtype=float) for c in columns})
        units = {c: info.get("units", {}).get(c, {}) for c in columns}
    else:
        tables = [pq.read_table(p) for p in chunks]
        _check_one_run(run_dir, chunks, tables)
        table = pa.concat_tables(tables)
        df = table.to_pandas()
        units = {f.name: {k.decode(): v.decode() for k, v in (f.metadata or {}).items()} for f in table.schema}
    df.attrs["units"] = {c: u.get("unit", "") for c, u in units.items()}
    df.attrs["display_units"] = {c: u["display_unit"] for c, u in units.items() if u.get("display_unit")}
    return df


def _check_one_run(run_dir: Path, chunks: Sequence[Path], tables: Sequence[Any]) -> None:
    """Every chunk carries the run id of ``run.json`` (or, without it, of the first chunk); else MixedRunError."""
    ids = [(t.schema.metadata or {}).get(RUN_ID_KEY) for t in tables]
    ids = [None if i is None else i.decode() for i in ids]
    info_path = run_dir / RUN_INFO
    if info_path.exists():
        expected, source = read_run_info(run_dir).get("run_id"), f"{info_path}"
    else:
        expected, source = ids[0], f"{chunks[0]}"
    for chunk, got in zip(chunks, ids):
        if got != expected:
            raise MixedRunError(
                f"{chunk}: written by {'run ' + got if got else 'a run without an id'}, not by run "
                f"{expected or '(without an id)'} of {source}: {run_dir} mixes the results of two runs (run them "
                "into separate folders; a run refuses a folder in use unless told --if-busy wait or new)")

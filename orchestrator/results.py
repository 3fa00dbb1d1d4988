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

pandas and pyarrow are imported when first needed (writing a chunk, loading results), not
with this module: a command-line run does not pay for pandas.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import platform
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import sys
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["RunWriter", "load_results", "read_run_info", "sha256_of", "software_versions"]

CHUNK_DIR = "chunks"
RUN_INFO = "run.json"


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


def _replace_atomically(path: Path, write: Any, durable: bool = False) -> None:
    """Write ``path`` through a temporary file and a rename; ``durable``: fsync the file and its folder."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        write(fh)
        if durable:
            fh.flush()
            os.fsync(fh.fileno())
    os.replace(tmp, path)
    if durable:
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class RunWriter:
    """Writes the rows of one run into ``run_dir`` (created; earlier results there are removed).

    ``columns``: "time" first, then "instance.variable"; ``bool_columns``: those stored
    as booleans, ``int_columns``: as int32 (Int32 outputs; rows carry them as float64, which
    holds every int32 exactly). ``units``: by column, ``{"unit": ..., "display_unit": ...}`` (either
    may be absent or ""), written into every chunk's schema and into ``run.json`` (see the module
    text). ``info``: provenance for ``run.json`` (scenario, FMUs, ...), to which
    the writer adds versions, wall times, status, rows written and ``extra`` of
    :meth:`finish`.
    """

    def __init__(self, run_dir: str | Path, columns: Sequence[str], bool_columns: Sequence[str] = (),
                 info: dict[str, Any] | None = None, flush_rows: int = 10_000,
                 flush_seconds: float = 1.0, int_columns: Sequence[str] = (),
                 units: Mapping[str, Mapping[str, str]] | None = None) -> None:
        self.run_dir = Path(run_dir)
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
        self.info = {**(info or {}), "columns": self.columns, "bool_columns": list(bool_columns),
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
            self._schema = _schema(self.columns, self._types, self.units)
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
        """Flush the remaining rows and record the final ``status`` and ``extra`` in run.json."""
        self.flush()
        self.info.update(extra, status=status, end_wall_time=_now(), versions=software_versions())
        self._write_info(durable=True)

    def _write_info(self, durable: bool = False) -> None:
        self.info["rows_written"] = self.rows_written
        text = json.dumps(self.info, indent=2, default=str).encode()
        _replace_atomically(self.run_dir / RUN_INFO, lambda fh: fh.write(text), durable)


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
    without chunks, from ``run.json``)."""
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
        table = pa.concat_tables([pq.read_table(p) for p in chunks])
        df = table.to_pandas()
        units = {f.name: {k.decode(): v.decode() for k, v in (f.metadata or {}).items()} for f in table.schema}
    df.attrs["units"] = {c: u.get("unit", "") for c, u in units.items()}
    df.attrs["display_units"] = {c: u["display_unit"] for c, u in units.items() if u.get("display_unit")}
    return df

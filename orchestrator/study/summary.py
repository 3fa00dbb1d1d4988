"""The study's summary: one row per case, written as the cases finish, consolidated at the end.

Layout of ``<out>/<study name>/``:

- ``summary/<case id>.parquet``: one file per finished case, the Parquet dataset of the finished cases;
- ``summary.parquet`` and ``summary.csv``: the rows of the study's cases in the study's order, rewritten at the end
  of every sweep (also an interrupted one);
- ``study.json``: what ran (the study file, the base scenario, the cases with their values, the reductions).

A row: ``case_id``, ``status`` ("ok" or "failed"), ``error`` (the message, "" when ok), the study's variables in
the variable's SI unit as the case ran them (None when the case failed before it could set them), the reductions'
outputs (NaN when missing), ``run_status`` (the master's: "completed", "terminated: ..."), ``wall_time`` (s, the
case on its worker: setup, run, reductions) and ``run_dir`` (the case's run folder).

Every file is written atomically (``orchestrator.atomic_files``: a temporary name, then renamed): a killed study
or a full disk leaves only whole files and no temporary ones.
"""
from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from milling_twin.orchestrator import atomic_files
__all__ = ["SummaryStore"]

PARTS = "summary"
FIRST = ("case_id", "status", "error")
LAST = ("run_status", "wall_time", "run_dir")


class SummaryStore:
    """The summary files of one study folder. A sweep owns its folder (``RunFolder.claim``), so the rows are read
    from ``summary/`` once and then kept here as they are written (consolidating a study of refinement rounds
    re-read every file each round: 0.2 s for 290 cases)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.parts = folder / PARTS
        self._rows: dict[str, dict[str, Any]] | None = None  # by case id, once read

    def clear(self) -> None:
        """Forget the finished cases of an earlier sweep (their run folders are overwritten as the cases rerun)."""
        if self.parts.is_dir():
            for part in self.parts.glob("*.parquet"):
                part.unlink()
        self._rows = {}

    def write(self, row: Mapping[str, Any]) -> None:
        self.parts.mkdir(parents=True, exist_ok=True)
        table = pa.Table.from_pylist([dict(row)])
        atomic_files.write_with(self.parts / f"{row['case_id']}.parquet", lambda tmp: pq.write_table(table, tmp))
        if self._rows is not None:
            self._rows[str(row["case_id"])] = table.to_pylist()[0]  # as read back from the file

    def rows(self) -> dict[str, dict[str, Any]]:
        """The rows of every finished case, by case id."""
        if self._rows is None:
            found: dict[str, dict[str, Any]] = {}
            for part in sorted(self.parts.glob("*.parquet")) if self.parts.is_dir() else ():
                for row in pq.read_table(part).to_pylist():
                    found[row["case_id"]] = row
            self._rows = found
        return dict(self._rows)

    def finished_ok(self) -> set[str]:
        return {cid for cid, row in self.rows().items() if row.get("status") == "ok"}

    def consolidate(self, case_ids: Iterable[str], inputs: Iterable[str]) -> pd.DataFrame:
        """The rows of ``case_ids`` that have finished, in that order, written to summary.parquet and .csv."""
        rows = self.rows()
        ordered = [rows[cid] for cid in case_ids if cid in rows]
        inputs = list(inputs)
        outputs = list(dict.fromkeys(k for row in ordered for k in row
                                     if k not in (*FIRST, *LAST, *inputs)))
        columns = [*FIRST, *inputs, *outputs, *LAST]
        frame = pd.DataFrame(ordered, columns=columns).infer_objects()
        self.folder.mkdir(parents=True, exist_ok=True)
        for name, write in (("summary.parquet", lambda p: frame.to_parquet(p, index=False)),
                            ("summary.csv", lambda p: frame.to_csv(p, index=False))):
            atomic_files.write_with(self.folder / name, write)
        return frame

    def write_study(self, doc: Mapping[str, Any]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_files.write_text(self.folder / "study.json", json.dumps(doc, indent=2, default=str))

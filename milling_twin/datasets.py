"""Published data sets the project reads but does not ship: the slot-milling force recordings.

The five DynoWare exports of measured slot-milling forces (6000 rpm, 2 flutes, 3 mm axial depth, full slot,
feeds 300 ... 1500 mm/min, forces at 10 kHz) have no licence to redistribute: they stay outside the
repository. Their folder is an explicit option, else ``$MILLING_TWIN_SLOT_DATA``, else
``../shared/data/slot_milling_forces`` beside the repository. The file name gives the cutting conditions
(``6-n6000f300ap3ae25.csv``: n rpm, f mm/min, ap mm, ae mm).

Used by the slot-milling validation, the ``slot_forces`` calibration and the force net's fine-tuning.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.input_files import read_input

REPO = Path(__file__).resolve().parents[1]
DATA_ENV = "MILLING_TWIN_SLOT_DATA"
DEFAULT_DATA = REPO.parent / "shared" / "data" / "slot_milling_forces"
SOURCE = ("github.com/leekunhwee/ForceCalculation, commit 3fda341, folder 'General/Flat end milling' "
          "(files 6-n6000f300ap3ae25.csv ... 6-n6000f1500ap3ae25.csv)")
_NAME = re.compile(r"n(?P<rpm>\d+(?:\.\d+)?)f(?P<feed>\d+(?:\.\d+)?)ap(?P<ap>\d+(?:\.\d+)?)ae(?P<ae>\d+(?:\.\d+)?)")


class DataMissing(RuntimeError):
    """The recordings are not where they were looked for; the message says where to put them."""


def data_dir(option: str | Path | None = None) -> Path:
    """``option``, else $MILLING_TWIN_SLOT_DATA, else ../shared/data/slot_milling_forces beside the repo;
    raises DataMissing (saying where the files go) if it holds no recording."""
    folder = Path(option) if option else Path(os.environ[DATA_ENV]) if os.environ.get(DATA_ENV) else DEFAULT_DATA
    if not folder.is_dir() or not any(_NAME.search(p.name) for p in folder.glob("*.csv")):
        how = ("--data" if option else f"${DATA_ENV}" if os.environ.get(DATA_ENV) else "the default location")
        raise DataMissing(
            f"no slot-milling recordings in {folder} (from {how}). Put the five DynoWare CSV exports of {SOURCE} "
            f"into {DEFAULT_DATA} (beside this repository), or pass --data DIR or set {DATA_ENV}=DIR. "
            "They have no licence to redistribute: never copy them into the repository.")
    return folder


@dataclass(frozen=True)
class Recording:
    path: Path
    rpm: float
    feed: float  # mm/min
    axial_depth: float  # mm
    radial_depth: float  # mm
    sample_rate: float  # Hz
    time: np.ndarray
    forces: np.ndarray  # samples x (Fx, Fy, Fz) of the file, N

    @property
    def label(self) -> str:
        return f"f{self.feed:g}"


def read_recording(path: Path) -> Recording:
    """A DynoWare CSV export: header lines, ``Time,Fx,Fy,Fz``, a unit line ``s,N,N,N``, then data."""
    match = _NAME.search(path.stem)
    if not match:
        raise ValueError(f"{path}: the file name does not give the conditions as n<rpm>f<feed>ap<mm>ae<mm>")
    lines = read_input(path, "recording").decode("utf-8", errors="replace").splitlines()  # header text is free
    start = next((i for i, line in enumerate(lines) if line.replace(" ", "").startswith("Time,Fx,Fy,Fz")), None)
    if start is None:
        raise ValueError(f"{path}: no 'Time,Fx,Fy,Fz' header line")
    units = [u.strip() for u in lines[start + 1].split(",")]
    if units[:4] != ["s", "N", "N", "N"]:
        raise ValueError(f"{path}: line {start + 2}: expected units s,N,N,N, got {lines[start + 1]!r}")
    data = np.loadtxt(lines[start + 2:], delimiter=",", ndmin=2)
    if data.shape[1] < 4 or len(data) < 100:
        raise ValueError(f"{path}: expected at least 100 rows of Time,Fx,Fy,Fz, got {data.shape}")
    t = data[:, 0]
    dt = np.diff(t)
    if np.any(dt <= 0) or np.ptp(dt) > 1e-6 * np.mean(dt) + 1e-9:
        raise ValueError(f"{path}: time is not uniformly increasing")
    rate = next((float(line.split(",")[1]) for line in lines[:start] if line.startswith("Sampling rate")),
                1.0 / float(np.mean(dt)))
    if abs(rate * np.mean(dt) - 1.0) > 1e-6:
        raise ValueError(f"{path}: sampling rate {rate} Hz does not match the time column")
    return Recording(path, float(match["rpm"]), float(match["feed"]), float(match["ap"]), float(match["ae"]),
                     rate, t, data[:, 1:4])


def read_recordings(folder: Path) -> list[Recording]:
    recordings = [read_recording(p) for p in sorted(folder.glob("*.csv")) if _NAME.search(p.name)]
    return sorted(recordings, key=lambda r: r.feed)

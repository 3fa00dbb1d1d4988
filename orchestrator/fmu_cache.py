"""Unpacked FMUs, extracted once per FMU content and reused by later runs.

A run needs each FMU unzipped (fmpy loads its binary from there). Unzipping on every run costs
10-20 ms per FMU; instead :func:`unpack` keeps one folder per FMU *content*, named by the SHA-256
of the ``.fmu`` file (which ``run.json`` records anyway, so it is computed once for both): a
rebuilt FMU has another hash and gets its own folder, an unchanged one is reused as it is.

* Where: ``$MILLING_TWIN_FMU_CACHE`` (a folder; ``off`` or an empty value: no cache, every run
  unzips into a temporary folder and removes it at the end), else ``$XDG_CACHE_HOME/milling_twin/fmus``,
  else ``~/.cache/milling_twin/fmus``. When the cache folder cannot be created or written, the run
  falls back to a temporary folder and logs why.
* Safe against concurrent runs and killed processes: an FMU is unzipped into a temporary folder
  beside its final name and renamed into place in one step, so a folder under its hash is always
  complete; a run that loses the race uses the winner's folder. A process killed while unzipping
  leaves only a hidden ``.<hash>.*`` folder, removed by a later run after an hour.
* Bounded: at most :data:`KEEP` FMUs are kept; the least recently used are removed when a new one
  is added (each use touches its folder).
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from fmpy import extract

__all__ = ["CACHE_ENV", "KEEP", "Unpacked", "cache_root", "unpack"]

CACHE_ENV = "MILLING_TWIN_FMU_CACHE"
KEEP = 32  # FMUs kept in the cache
STALE_SECONDS = 3600.0  # a hidden temporary folder this old was left by a killed process
_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Unpacked:
    """An unpacked FMU: its folder, and whether the run must remove it (no cache)."""

    folder: str
    temporary: bool


def cache_root() -> Path | None:
    """The cache folder, or None when the cache is switched off."""
    env = os.environ.get(CACHE_ENV)
    if env is not None:
        return None if env.strip().lower() in ("", "off", "0", "none") else Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "milling_twin" / "fmus"


def unpack(fmu: Path, sha256: str) -> Unpacked:
    """The folder of ``fmu`` (whose content has the hash ``sha256``) unpacked."""
    root = cache_root()
    if root is None:
        return Unpacked(extract(str(fmu)), True)
    folder = root / sha256
    if folder.is_dir():
        try:
            os.utime(folder)  # least recently used goes first
        except OSError:
            pass
        return Unpacked(str(folder), False)
    try:
        root.mkdir(parents=True, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=f".{sha256}.", dir=root)
    except OSError as exc:
        _log.warning("FMU cache %s not usable (%s): unpacking %s into a temporary folder", root, exc, fmu)
        return Unpacked(extract(str(fmu)), True)
    try:
        extract(str(fmu), unzipdir=tmp)
        os.rename(tmp, folder)  # atomic; fails when another run has put it there first
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not folder.is_dir():
            raise
    _prune(root, folder)
    return Unpacked(str(folder), False)


def _prune(root: Path, keep: Path) -> None:
    """Remove the least recently used FMUs beyond KEEP and stale temporary folders."""
    try:
        entries = [(p.stat().st_mtime, p) for p in root.iterdir() if p.is_dir()]
    except OSError:
        return
    now = time.time()
    done = [(m, p) for m, p in entries if not p.name.startswith(".")]
    stale = [p for m, p in entries if p.name.startswith(".") and now - m > STALE_SECONDS]
    done.sort(reverse=True)
    for path in stale + [p for _, p in done[KEEP:] if p != keep]:
        shutil.rmtree(path, ignore_errors=True)

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
* Verified before each use: the unzipped files' list, sizes and SHA-256 are recorded beside them
  (:data:`MANIFEST`) and checked every time the folder is used; a folder that differs (a truncated or
  modified binary, a file missing or added, no record) is unzipped again and replaces it, with a warning.
* Safe to unzip: entry names must be relative paths with forward slashes and no ``..``, drive letter or
  device (:class:`FmuArchiveError` names the FMU and the entry otherwise); the unzipped size is limited
  (:data:`MAX_BYTES_ENV`, default :data:`MAX_BYTES`) and so is its ratio to the ``.fmu`` file's size
  (:data:`MAX_RATIO_ENV`, default :data:`MAX_RATIO`, checked once more than :data:`RATIO_FREE` bytes are
  out), counting the bytes actually written, not the sizes the archive declares. A refused or failed
  unzip leaves no folder behind.
* Bounded: at most :data:`KEEP` FMUs are kept; the least recently used are removed when a new one
  is added (each use touches its folder).
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

from milling_twin.orchestrator.user_cache import cache_folder

__all__ = ["CACHE_ENV", "KEEP", "MANIFEST", "MAX_BYTES", "MAX_BYTES_ENV", "MAX_RATIO", "MAX_RATIO_ENV",
           "FmuArchiveError", "Limits", "Unpacked", "cache_root", "extract", "limits", "unpack"]

CACHE_ENV = "MILLING_TWIN_FMU_CACHE"
MAX_BYTES_ENV = "MILLING_TWIN_FMU_MAX_BYTES"
MAX_RATIO_ENV = "MILLING_TWIN_FMU_MAX_RATIO"
MAX_BYTES = 1 << 30  # unzipped bytes of one FMU (the project's FMUs: 0.2-1.8 MB)
MAX_RATIO = 100.0  # unzipped bytes / .fmu file size (the project's FMUs: 2.4-5.3)
RATIO_FREE = 1 << 20  # the ratio is checked once this many bytes are unzipped (a tiny FMU may compress well)
MAX_ENTRIES = 100_000
KEEP = 32  # FMUs kept in the cache
STALE_SECONDS = 3600.0  # a hidden temporary folder this old was left by a killed process
MANIFEST = ".milling_twin_files.json"  # in each cached folder: {"files": {name: [size, sha256]}}
NO_RECORD = f"no record of its files ({MANIFEST})"
_CHUNK = 1 << 20
_DRIVE = re.compile(r"^[A-Za-z]:")
_log = logging.getLogger(__name__)


class FmuArchiveError(ValueError):
    """An FMU that cannot be unzipped safely: an unsafe entry name, or beyond the size or ratio limit."""


@dataclass(frozen=True)
class Unpacked:
    """An unpacked FMU: its folder, and whether the run must remove it (no cache)."""

    folder: str
    temporary: bool


@dataclass(frozen=True)
class Limits:
    """How much one FMU may unzip to: bytes in all, and bytes per byte of the ``.fmu`` file."""

    max_bytes: int = MAX_BYTES
    max_ratio: float = MAX_RATIO


def _env_number(name: str, default: float) -> float:
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    match = re.fullmatch(r"(\d+(?:\.\d*)?)\s*([kKmMgG]?)", text)
    if not match or float(match.group(1)) <= 0:
        raise ValueError(f"${name} = {text!r}: expected a positive number (bytes may end in K, M or G)")
    return float(match.group(1)) * 1024 ** " KMG".index((match.group(2) or " ").upper())


def limits() -> Limits:
    """The limits set by $MILLING_TWIN_FMU_MAX_BYTES (``512M``, ``2G``, bytes) and $MILLING_TWIN_FMU_MAX_RATIO."""
    return Limits(int(_env_number(MAX_BYTES_ENV, MAX_BYTES)), _env_number(MAX_RATIO_ENV, MAX_RATIO))


def cache_root() -> Path | None:
    """The cache folder, or None when the cache is switched off."""
    return cache_folder(CACHE_ENV, "fmus")


def _safe_parts(fmu: str | os.PathLike[str], name: str) -> list[str]:
    """The path components of entry ``name``, or FmuArchiveError naming the FMU and the entry."""
    problem = ("a backslash (entry names use forward slashes)" if "\\" in name
               else "an absolute path" if name.startswith("/")
               else "a drive letter or device (':')" if ":" in name or _DRIVE.match(name)
               else "a NUL character" if "\0" in name
               else "'..' (a path out of the FMU's folder)" if ".." in name.split("/")
               else "an empty name" if not name.strip("/")
               else f"the name of the cache's own record {MANIFEST!r}" if name.strip("/") == MANIFEST
               else None)
    if problem is not None:
        raise FmuArchiveError(f"FMU {fmu}: entry {name!r} has {problem}; the FMU is not unzipped")
    return [p for p in name.split("/") if p not in ("", ".")]


def extract(filename: str | os.PathLike[str], unzipdir: str | os.PathLike[str] | None = None,
            limit: Limits | None = None) -> str:
    """Unzip the FMU ``filename`` into ``unzipdir`` (None: a new temporary folder) after checking every entry
    name, within ``limit`` (default :func:`limits`); writes :data:`MANIFEST` there and returns the folder. On
    any error the files written are removed (and the folder too when it was created here)."""
    limit = limits() if limit is None else limit
    created = unzipdir is None
    folder = Path(tempfile.mkdtemp(prefix="milling_twin_fmu_") if unzipdir is None else unzipdir)
    written: list[Path] = []
    try:
        archive_size = max(os.path.getsize(filename), 1)
        files: dict[str, list[int | str]] = {}
        total = 0
        with zipfile.ZipFile(filename) as zf:
            infos = zf.infolist()
            if len(infos) > MAX_ENTRIES:
                raise FmuArchiveError(f"FMU {filename}: {len(infos)} entries, more than {MAX_ENTRIES}")
            entries = [(info, _safe_parts(filename, info.filename)) for info in infos]
            for info, parts in entries:
                target = folder.joinpath(*parts) if parts else folder
                if info.is_dir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                digest = hashlib.sha256()
                size = 0
                try:
                    with zf.open(info) as src, open(target, "xb") as dst:
                        written.append(target)
                        while chunk := src.read(_CHUNK):
                            size += len(chunk)
                            total += len(chunk)
                            _check_limits(filename, info.filename, total, archive_size, limit)
                            digest.update(chunk)
                            dst.write(chunk)
                except OSError as exc:  # a full disk: the message names the file (a write error names none)
                    if exc.filename is not None:
                        raise
                    raise OSError(exc.errno, f"FMU {filename}: cannot unzip {info.filename!r}: "
                                             f"{exc.strerror or exc}", str(target)) from exc
                files["/".join(parts)] = [size, digest.hexdigest()]
        manifest = folder / MANIFEST
        manifest.write_text(json.dumps({"files": files}, indent=0, sort_keys=True), encoding="utf-8")
    except BaseException:
        if created:
            shutil.rmtree(folder, ignore_errors=True)
        else:
            for path in written:
                path.unlink(missing_ok=True)
        raise
    return str(folder)


def _check_limits(fmu: str | os.PathLike[str], entry: str, total: int, archive_size: int, limit: Limits) -> None:
    if total > limit.max_bytes:
        raise FmuArchiveError(f"FMU {fmu}: unzipping entry {entry!r} goes beyond {limit.max_bytes} bytes "
                              f"(${MAX_BYTES_ENV} sets the limit); the FMU is not unzipped")
    if total > RATIO_FREE and total > limit.max_ratio * archive_size:
        raise FmuArchiveError(f"FMU {fmu}: unzipping entry {entry!r} goes beyond {limit.max_ratio:g} times the "
                              f"FMU's {archive_size} bytes (${MAX_RATIO_ENV} sets the limit); the FMU is not unzipped")


def damage(folder: Path) -> str | None:
    """Why the cached ``folder`` differs from its record (None: every recorded file as unzipped, no other)."""
    base = str(folder)
    if not os.path.isfile(os.path.join(base, MANIFEST)):
        return NO_RECORD
    try:
        with open(os.path.join(base, MANIFEST), encoding="utf-8") as fh:
            files = json.load(fh)["files"]
        found: dict[str, int] = {}
        pending = [("", base)]
        while pending:
            rel_dir, path = pending.pop()
            with os.scandir(path) as entries:
                for entry in entries:
                    rel = f"{rel_dir}{entry.name}"
                    if entry.is_symlink():
                        return f"{rel} is a symbolic link"
                    if entry.is_dir():
                        pending.append((f"{rel}/", entry.path))
                    elif rel != MANIFEST:
                        found[rel] = entry.stat().st_size
        if found.keys() != files.keys():
            extra, missing = sorted(found.keys() - files.keys()), sorted(files.keys() - found.keys())
            return f"files missing {missing[:3]}, not unzipped {extra[:3]}"
        for rel, (size, digest) in files.items():
            if found[rel] != size:
                return f"{rel} has {found[rel]} bytes instead of {size}"
        for rel, (size, digest) in files.items():
            with open(os.path.join(base, rel), "rb") as fh:
                if hashlib.file_digest(fh, "sha256").hexdigest() != digest:
                    return f"{rel} is modified (SHA-256 differs)"
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"its record {MANIFEST} is unreadable ({exc})"
    return None


def unpack(fmu: Path, sha256: str) -> Unpacked:
    """The folder of ``fmu`` (whose content has the hash ``sha256``) unpacked."""
    root = cache_root()
    if root is None:
        return Unpacked(extract(str(fmu)), True)
    folder = root / sha256
    if folder.is_dir():
        problem = damage(folder)
        if problem is None:
            try:
                os.utime(folder)  # least recently used goes first
            except OSError:
                pass
            return Unpacked(str(folder), False)
        if problem == NO_RECORD:  # unzipped by a version that kept no list: expected once after an upgrade
            _log.info("FMU cache: %s (of %s) has %s: unzipping it again", folder, fmu, problem)
        else:
            _log.warning("FMU cache: %s (of %s) is damaged (%s): unzipping it again", folder, fmu, problem)
    try:
        root.mkdir(parents=True, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=f".{sha256}.", dir=root)
    except OSError as exc:
        _log.warning("FMU cache %s not usable (%s): unpacking %s into a temporary folder", root, exc, fmu)
        return Unpacked(extract(str(fmu)), True)
    try:
        extract(str(fmu), unzipdir=tmp)
        if folder.is_dir() and damage(folder) is not None:  # moved aside in one step (a run using it keeps
            _discard(folder, sha256)  # its open files); one another run has just put there is used instead
        os.rename(tmp, folder)  # atomic; fails when another run has put it there first
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if not isinstance(exc, OSError) or not folder.is_dir() or damage(folder) is not None:
            raise
    _prune(root, folder)
    return Unpacked(str(folder), False)


def _discard(folder: Path, sha256: str) -> None:
    """Move the damaged ``folder`` aside and remove it (another run may have done either already)."""
    trash = folder.with_name(f".{sha256}.damaged.{os.getpid()}.{time.monotonic_ns()}")
    try:
        os.rename(folder, trash)
    except FileNotFoundError:
        return
    shutil.rmtree(trash, ignore_errors=True)


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

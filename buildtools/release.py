"""The FMU release: ``dist/milling-twin-fmus-<version>.tar.gz`` holds the ``.fmu`` files alone, with a README that
lists them (FMI version, platforms, what each models, the glibc its Linux binaries need), the project's licence and
the FMI headers' notice, for users who want only the FMUs. ``make release`` runs it:

    python -m buildtools.release --fmus build/fmus --licence LICENSE --out dist
"""
from __future__ import annotations

import argparse
import io
import os
import sys
import tarfile
import time
import tomllib
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

from buildtools.elf import ElfError, elf_needs, is_elf

ROOT = Path(__file__).resolve().parents[1]
NOTICE = ROOT / "fmus" / "third_party" / "README.md"  # the FMI headers inside every FMU's sources/


class ReleaseError(RuntimeError):
    """A release input is missing or unusable; the message names the file."""


@dataclass(frozen=True)
class FmuSummary:
    file: str
    fmi_version: str
    model_name: str
    description: str
    platforms: tuple[str, ...]  # binaries/<platform>/
    glibc: tuple[int, int] | None  # newest GLIBC_x.y its Linux binaries reference


def project_version(pyproject: Path = ROOT / "pyproject.toml") -> str:
    try:
        return str(tomllib.loads(pyproject.read_text())["project"]["version"])
    except (OSError, KeyError, tomllib.TOMLDecodeError) as exc:
        raise ReleaseError(f"{pyproject}: no [project].version ({exc})") from exc


def summarize(fmu: Path) -> FmuSummary:
    """What the README says of one FMU, read from its archive."""
    try:
        with zipfile.ZipFile(fmu) as archive:
            root = ET.fromstring(archive.read("modelDescription.xml"))
            binaries = [n for n in archive.namelist() if n.startswith("binaries/") and not n.endswith("/")]
            glibc = [elf_needs(data, f"{fmu}:{n}").glibc for n in binaries
                     if is_elf(data := archive.read(n))]
    except (OSError, KeyError, zipfile.BadZipFile, ET.ParseError, ElfError) as exc:
        raise ReleaseError(f"{fmu}: not a readable FMU ({exc})") from exc
    platforms = tuple(sorted({n.split("/")[1] for n in binaries if n.count("/") >= 2}))
    found = [v for v in glibc if v is not None]
    return FmuSummary(fmu.name, root.get("fmiVersion", "?"), root.get("modelName", fmu.stem),
                      " ".join((root.get("description") or "").split()), platforms, max(found) if found else None)


def readme(version: str, fmus: list[FmuSummary]) -> str:
    rows = "\n".join(f"| `{f.file}` | {f.fmi_version} | {f.model_name} | {', '.join(f.platforms) or '-'} | "
                     f"{f.description} |" for f in fmus)
    glibc = [f.glibc for f in fmus if f.glibc is not None]
    linux = (f"The Linux binaries need glibc {'.'.join(map(str, max(glibc)))} or newer.\n\n" if glibc else "")
    return f"""# Milling twin FMUs {version}

The co-simulation FMUs of the milling twin, a digital twin of CNC milling: each model in FMI 3.0 (`Name.fmu`)
and FMI 2.0 (`Name_fmi2.fmu`), generated from one model source. Every FMU carries its C sources (`sources/`,
with `buildDescription.xml`), so an importer on a platform without a binary here can build it.

| file | FMI | model | platforms (`binaries/`) | description |
| --- | --- | --- | --- | --- |
{rows}

{linux}Import them into any FMI co-simulation tool. The Python package `milling-twin` (the wheel) carries the same
FMUs with the orchestrator that runs whole-part scenarios on them (`milling-twin run SCENARIO`).

Licence: `LICENSE`. The FMI headers inside each FMU's `sources/`: `THIRD_PARTY.md`.
"""


def _add(tar: tarfile.TarFile, name: str, data: bytes, mtime: int) -> None:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = len(data), mtime, 0o644
    tar.addfile(info, io.BytesIO(data))


def write_release(fmu_dir: Path, licence: Path, out_dir: Path, version: str) -> Path:
    """Write ``out_dir/milling-twin-fmus-<version>.tar.gz`` (one top folder of the same name) and return it."""
    if not licence.is_file():
        raise ReleaseError(f"{licence}: no licence file (the release carries the project's licence: add it, or "
                           "pass LICENSE_FILE=... to make release)")
    fmus = sorted(fmu_dir.glob("*.fmu")) if fmu_dir.is_dir() else []
    if not fmus:
        raise ReleaseError(f"{fmu_dir}: no .fmu files (build them first: make fmus)")
    summaries = [summarize(f) for f in fmus]
    name = f"milling-twin-fmus-{version}"
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{name}.tar.gz"
    mtime = int(os.environ.get("SOURCE_DATE_EPOCH", time.time()))
    partial = target.with_suffix(".partial")
    with tarfile.open(partial, "w:gz") as tar:
        _add(tar, f"{name}/README.md", readme(version, summaries).encode(), mtime)
        _add(tar, f"{name}/LICENSE", licence.read_bytes(), mtime)
        _add(tar, f"{name}/THIRD_PARTY.md", NOTICE.read_bytes(), mtime)
        for fmu in fmus:
            _add(tar, f"{name}/{fmu.name}", fmu.read_bytes(), mtime)
    partial.replace(target)
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fmus", type=Path, required=True, help="folder of the .fmu files")
    parser.add_argument("--licence", type=Path, required=True, help="the project's licence file")
    parser.add_argument("--out", type=Path, default=Path("dist"))
    parser.add_argument("--version", default=None, help="default: pyproject.toml's [project].version")
    args = parser.parse_args(argv)
    try:
        print(write_release(args.fmus, args.licence, args.out, args.version or project_version()))
    except ReleaseError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The native files a wheel carries (every built FMU, FMI 2 and 3, and the stepper library) and the platform tag
they give it.

Where they come from: ``$MILLING_TWIN_WHEEL_FMUS`` (a folder of ``.fmu`` files; ``none``: a Python-only wheel),
else ``build/fmus-all/`` (the cross-compiled multi-platform FMUs) when it holds FMUs, else ``build/fmus/``; the stepper
library from ``$MILLING_TWIN_WHEEL_STEPPER``, else the cross-compiled one for this machine beside those FMUs
(``<fmus>/stepper/x86_64-linux/``), else ``build/stepper/libmilling_stepper.so``. Nothing is compiled here:
``make wheel`` builds them with CMake first.

The tag: the stepper library is native code loaded by ctypes (no CPython ABI), so the wheel is
``py3-none-manylinux_<glibc>_<arch>``, where <glibc> is the newest GLIBC_x.y symbol version the stepper library and
the FMUs' Linux binaries of the same architecture reference (2.17, manylinux2014, at the least).
"""
from __future__ import annotations

import os
import platform
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from buildtools.elf import ElfError, elf_needs, is_elf

FMUS_ENV = "MILLING_TWIN_WHEEL_FMUS"
STEPPER_ENV = "MILLING_TWIN_WHEEL_STEPPER"
STEPPER_NAME = "libmilling_stepper.so"
GLIBC_FLOOR = (2, 17)
# where they go inside the package (milling_twin/fmus/, milling_twin/stepper/: the stepper beside the FMUs' folder,
# where the orchestrator looks first)
PACKAGE_FMUS = Path("milling_twin") / "fmus"
PACKAGE_STEPPER = Path("milling_twin") / "stepper"


class WheelFilesError(RuntimeError):
    """The wheel's native files are missing or unusable; the message names the path and the variable."""


@dataclass(frozen=True)
class WheelFiles:
    """The FMUs and the stepper library to package; both empty for a Python-only wheel."""

    fmus: tuple[Path, ...]
    stepper: Path | None

    @property
    def native(self) -> bool:
        return self.stepper is not None

    def platform_tag(self) -> str:
        """manylinux_<major>_<minor>_<arch> from what the stepper library and the FMUs' binaries need."""
        if self.stepper is None:
            raise WheelFilesError("a Python-only wheel has no platform tag")
        data = self.stepper.read_bytes()
        if not is_elf(data):
            raise WheelFilesError(f"{self.stepper}: not a Linux shared library (ELF); only Linux wheels are built")
        try:
            stepper = elf_needs(data, str(self.stepper))
            needed = [stepper.glibc, *self._fmu_glibc(stepper.machine)]
        except ElfError as exc:
            raise WheelFilesError(str(exc)) from exc
        major, minor = max([GLIBC_FLOOR, *(v for v in needed if v is not None)])
        return f"manylinux_{major}_{minor}_{stepper.machine}"

    def _fmu_glibc(self, machine: str) -> list[tuple[int, int] | None]:
        """The glibc versions the FMUs' ELF binaries for ``machine`` need (other platforms' binaries are skipped)."""
        found = []
        for fmu in self.fmus:
            with zipfile.ZipFile(fmu) as archive:
                for name in archive.namelist():
                    if not name.startswith("binaries/") or name.endswith("/"):
                        continue
                    data = archive.read(name)
                    if is_elf(data):
                        needs = elf_needs(data, f"{fmu}:{name}")
                        if needs.machine == machine:
                            found.append(needs.glibc)
        return found


def _path(root: Path, text: str) -> Path:
    path = Path(text).expanduser()
    return path if path.is_absolute() else root / path


def select(root: Path, environ: Mapping[str, str] = os.environ) -> WheelFiles:
    """The FMUs and stepper library for a wheel built from the source tree ``root``; raises
    :class:`WheelFilesError` naming the folder and the variable when they are not built."""
    raw = environ.get(FMUS_ENV, "").strip()
    if raw.lower() == "none":
        return WheelFiles((), None)
    if raw:
        fmu_dir, origin = _path(root, raw), f"${FMUS_ENV}"
    else:
        fmu_dir = root / "build" / "fmus-all"
        fmu_dir = fmu_dir if any(fmu_dir.glob("*.fmu")) else root / "build" / "fmus"
        origin = "the default"
    fmus = tuple(sorted(fmu_dir.glob("*.fmu"))) if fmu_dir.is_dir() else ()
    hint = (f"build them first (`make wheel` runs CMake, then builds the wheel), set ${FMUS_ENV} to their folder, "
            f"or set {FMUS_ENV}=none for a Python-only wheel")
    if not fmus:
        raise WheelFilesError(f"{fmu_dir} ({origin}) holds no .fmu files: {hint}")
    stems = {p.stem for p in fmus}
    partners = {s: s.removesuffix("_fmi2") if s.endswith("_fmi2") else f"{s}_fmi2" for s in stems}
    missing = sorted(f"{partner}.fmu" for partner in partners.values() if partner not in stems)
    if missing:
        raise WheelFilesError(f"{fmu_dir} ({origin}): every FMU is packaged in FMI 3 and FMI 2; missing: "
                              f"{', '.join(missing)}")
    raw_stepper = environ.get(STEPPER_ENV, "").strip()
    if raw_stepper:
        stepper, origin = _path(root, raw_stepper), f"${STEPPER_ENV}"
    else:  # the cross-compiled one beside cross-compiled FMUs (for this machine's platform), else CMake's
        origin = "the default"
        candidates = [fmu_dir / "stepper" / f"{platform.machine()}-linux" / STEPPER_NAME,
                      root / "build" / "stepper" / STEPPER_NAME]
        stepper = next((c for c in candidates if c.is_file()), candidates[-1])
    if not stepper.is_file():
        raise WheelFilesError(f"{stepper} ({origin}): no stepper library: {hint}")
    return WheelFiles(fmus, stepper)

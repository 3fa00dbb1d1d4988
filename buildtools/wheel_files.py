"""The native files a wheel carries (every built FMU, FMI 2 and 3, and the stepper library) and the platform tag
they give it.

Where they come from: ``$MILLING_TWIN_WHEEL_FMUS`` (a folder of ``.fmu`` files; ``none``: a Python-only wheel),
else ``build/fmus-all/`` (the cross-compiled multi-platform FMUs) when it holds FMUs, else ``build/fmus/``; the stepper
library from ``$MILLING_TWIN_WHEEL_STEPPER``, else the cross-compiled one for this machine beside those FMUs
(``<fmus>/stepper/x86_64-linux/``), else ``build/stepper/libmilling_stepper.so``. Nothing is compiled here:
``make wheel`` builds them with CMake first.

The tag: the stepper library is native code loaded by ctypes (no CPython ABI), so the wheel is ``py3-none-<platform>``
for the system the stepper library is built for:

- Linux (ELF): ``manylinux_<glibc>_<arch>``, where <glibc> is the newest GLIBC_x.y symbol version the stepper library
  and the FMUs' Linux binaries of the same architecture reference (2.17, manylinux2014, at the least), when every
  FMU has a Linux binary of that architecture;
- Windows (PE): ``win_amd64`` (``win_arm64``), when every FMU has a Windows binary of that architecture;
- macOS (Mach-O): ``macosx_<major>_<minor>_<arch>`` (``universal2`` for a library of both architectures), the newest
  minimum macOS version of the library's slices and of the FMUs' slices of its architectures, when every FMU has
  them all.

A stepper library for another system than the FMUs were built for (the native build has Linux binaries only) is
refused, naming the FMUs that lack it.
"""
from __future__ import annotations

import os
import platform
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from buildtools.elf import ElfError, elf_needs, is_elf
from buildtools.native import NativeError, is_macho, is_pe, macho_slices, pe_machine

FMUS_ENV = "MILLING_TWIN_WHEEL_FMUS"
STEPPER_ENV = "MILLING_TWIN_WHEEL_STEPPER"
STEPPER_NAME = "libmilling_stepper.so"
GLIBC_FLOOR = (2, 17)
WINDOWS_TAGS = {"x86_64": "win_amd64", "aarch64": "win_arm64"}
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
        """The wheel's platform tag, from what the stepper library is built for and what the FMUs' binaries for
        that platform need (module docstring); raises :class:`WheelFilesError` naming the file."""
        if self.stepper is None:
            raise WheelFilesError("a Python-only wheel has no platform tag")
        data = self.stepper.read_bytes()
        try:
            if is_elf(data):
                return self._linux_tag(data)
            if is_pe(data):
                return self._windows_tag(data)
            if is_macho(data):
                return self._macos_tag(data)
        except (ElfError, NativeError) as exc:
            raise WheelFilesError(str(exc)) from exc
        raise WheelFilesError(f"{self.stepper}: neither a Linux (ELF), Windows (PE) nor macOS (Mach-O) library")

    def _linux_tag(self, data: bytes) -> str:
        """manylinux_<major>_<minor>_<arch>: the newest glibc the stepper and the FMUs' ELF binaries for its
        architecture reference (other platforms' binaries are skipped)."""
        stepper = elf_needs(data, str(self.stepper))
        needed, have = [stepper.glibc], set()
        for fmu, member, binary in self._binaries():
            if is_elf(binary):
                needs = elf_needs(binary, f"{fmu}:{member}")
                if needs.machine == stepper.machine:
                    needed.append(needs.glibc)
                    have.add(fmu)
        self._require(have, f"Linux {stepper.machine}")
        major, minor = max([GLIBC_FLOOR, *(v for v in needed if v is not None)])
        return f"manylinux_{major}_{minor}_{stepper.machine}"

    def _windows_tag(self, data: bytes) -> str:
        """win_amd64 or win_arm64, when every FMU has a Windows binary of the stepper's architecture."""
        arch = pe_machine(data, str(self.stepper))
        have = {fmu for fmu, member, binary in self._binaries()
                if is_pe(binary) and pe_machine(binary, f"{fmu}:{member}") == arch}
        self._require(have, f"Windows {arch}")
        return WINDOWS_TAGS[arch]

    def _macos_tag(self, data: bytes) -> str:
        """macosx_<major>_<minor>_<arch> (universal2 for a stepper of both architectures), the newest minimum macOS
        of the stepper's slices and of the FMUs' slices of those architectures, when every FMU has them all."""
        slices = macho_slices(data, str(self.stepper))
        archs = {piece.arch for piece in slices}
        oldest = [piece.min_macos for piece in slices]
        found: dict[str, set[str]] = {}
        for fmu, member, binary in self._binaries():
            if is_macho(binary):
                for piece in macho_slices(binary, f"{fmu}:{member}"):
                    if piece.arch in archs:
                        found.setdefault(fmu, set()).add(piece.arch)
                        oldest.append(piece.min_macos)
        self._require({fmu for fmu, have in found.items() if have == archs}, f"macOS {'+'.join(sorted(archs))}")
        major, minor = max(oldest)
        if major >= 11 and minor:  # from macOS 11 on, installers match major versions only (macosx_<major>_0)
            major, minor = major + 1, 0
        arch = "universal2" if archs == {"x86_64", "arm64"} else archs.pop()
        return f"macosx_{major}_{minor}_{arch}"

    def _require(self, have: set[str], platform_name: str) -> None:
        missing = sorted(str(fmu) for fmu in self.fmus if str(fmu) not in have)
        if missing:
            raise WheelFilesError(
                f"{self.stepper} is a {platform_name} library, but {len(missing)} of {len(self.fmus)} FMUs have no "
                f"{platform_name} binary: {', '.join(missing)} (build them for every platform: "
                "`make fmus-all-platforms`, docs/portability.md)")

    def _binaries(self) -> Iterator[tuple[str, str, bytes]]:
        """Every file under binaries/ in every FMU: (the FMU's path, the file's name in it, its bytes)."""
        for fmu in self.fmus:
            with zipfile.ZipFile(fmu) as archive:
                for name in archive.namelist():
                    if name.startswith("binaries/") and not name.endswith("/"):
                        yield str(fmu), name, archive.read(name)


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

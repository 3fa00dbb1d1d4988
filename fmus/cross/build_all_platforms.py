"""Cross-build every FMU's binary and the stepper library for every platform from this one Linux machine.

    python fmus/cross/build_all_platforms.py [--fmu-dir build/fmus] [--out build/fmus-all] [--jobs 2]
                                             [--platform KEY ...] [--fmu NAME ...] [--no-stepper]
    python fmus/cross/build_all_platforms.py --check-msvc [--fmu-dir build/fmus]

Reads the FMUs that `cmake --build build` made (build/fmus/*.fmu, left unchanged), compiles each one's `sources/`
(the same files an importer's `fmpy compile` rebuilds from) with zig's `cc` (PyPI package `ziglang`) for the
platforms of PLATFORMS, and writes each FMU again into --out with every binary in `binaries/<platform>/`; the
stepper library goes to <out>/stepper/<FMI 3 platform tuple>/. The Linux x86_64 binary is linked against glibc 2.17
(it replaces the native build's, which needs the build machine's glibc). FMI 2 names only linux64, win64 and
darwin64: its darwin64 binary is a universal Mach-O (x86_64 and arm64 slices), and its aarch64 Linux binary is
in binaries/aarch64-linux/ (the FMI 3 tuple; FMI 2 has no name for it). --check-msvc instead compiles every
sources/ as MSVC C (clang's emulation of it; no binaries). docs/portability.md has the details.
"""
from __future__ import annotations

import argparse
import functools
import hashlib
import importlib.util
import os
import re
import shutil
import struct
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

# The warnings the native build uses (CMakeLists.txt FMU_WARNINGS), errors here too: every target compiles clean.
WARNINGS = ["-Wall", "-Wextra", "-Wpedantic", "-Werror", "-Wshadow", "-Wstrict-prototypes", "-Wmissing-prototypes",
            "-Wconversion", "-Wno-sign-conversion"]
# C99 as the native build; no FMA contraction (gcc's default under -std=c99), so that aarch64, where clang would
# fuse a*b+c, computes what x86_64 computes.
COMMON_FLAGS = ["-std=c99", "-O2", "-DNDEBUG", "-ffp-contract=off", "-fvisibility=hidden", "-fPIC", "-g0"]


@dataclass(frozen=True)
class Platform:
    key: str            # --platform name
    zig_target: str     # zig cc -target
    fmi3: str           # FMI 3 platform tuple (binaries/<fmi3>/)
    fmi2: str           # FMI 2 folder (binaries/<fmi2>/); darwin64 holds the universal binary of both macOS targets
    extension: str      # shared library suffix
    link_flags: tuple[str, ...] = ()


PLATFORMS: tuple[Platform, ...] = (
    Platform("x86_64-linux", "x86_64-linux-gnu.2.17", "x86_64-linux", "linux64", ".so",
             ("-lm", "-Wl,--no-undefined")),
    Platform("x86_64-windows", "x86_64-windows-gnu", "x86_64-windows", "win64", ".dll"),
    Platform("aarch64-linux", "aarch64-linux-gnu.2.17", "aarch64-linux", "aarch64-linux", ".so",
             ("-lm", "-Wl,--no-undefined")),
    # macOS 11, the first on Apple Silicon, as the oldest supported (zig's default is its newest SDK's version)
    Platform("x86_64-darwin", "x86_64-macos.11.0", "x86_64-darwin", "darwin64", ".dylib"),
    Platform("aarch64-darwin", "aarch64-macos.11.0", "aarch64-darwin", "darwin64", ".dylib"),
)
PLATFORM_KEYS = tuple(p.key for p in PLATFORMS)


class CrossBuildError(RuntimeError):
    pass


def zig_command() -> list[str]:
    """`zig` from $ZIG, else the ziglang package of this Python (`python -m ziglang`)."""
    if os.environ.get("ZIG"):
        return [os.environ["ZIG"]]
    if importlib.util.find_spec("ziglang") is None:
        raise CrossBuildError("zig not found: `pip install ziglang` into this Python, or set ZIG=/path/to/zig")
    return [sys.executable, "-m", "ziglang"]


def run_zig(arguments: list[str], label: str, platform: Platform) -> None:
    result = subprocess.run([*zig_command(), "cc", "-target", platform.zig_target, *arguments],
                            capture_output=True, text=True)
    if result.returncode != 0:
        raise CrossBuildError(f"{label} for {platform.zig_target} did not compile:\n{result.stderr.strip()}")


def object_key(source: Path, header_dirs: list[Path], platform: Platform, flags: list[str]) -> str:
    """The cache key of one object: target, flags, the C file and every header it may include. The FMI standard's
    headers (fmi2*.h, fmi3*.h) count only for a file that includes one itself (the other headers include none),
    so the model's code compiles once for both FMI versions."""
    digest = hashlib.sha256("\0".join([platform.zig_target, *flags]).encode())
    text = source.read_bytes()
    digest.update(text)
    standard = b'#include "fmi' in text
    for directory in header_dirs:
        for header in sorted(directory.glob("*.h")):
            if standard or not STANDARD_HEADER.match(header.name):
                digest.update(header.name.encode() + b"\0" + header.read_bytes())
    return digest.hexdigest()[:32]


STANDARD_HEADER = re.compile(r"fmi[23][A-Z]\w*\.h$")


def compile_library(sources: list[Path], include_dirs: list[Path], system_dirs: list[Path], platform: Platform,
                    output: Path, label: str, objects: Path) -> None:
    """One shared library from C sources with zig cc for the platform; a failure names the library and target.
    Objects are kept in `objects` by content (object_key). system_dirs: the FMI standard's headers, not ours to fix
    (fmi3FunctionTypes.h has non-prototype declarations), included as system headers as in the native build."""
    flags = [*COMMON_FLAGS, *WARNINGS, *[f"-I{d}" for d in include_dirs], *[f"-isystem{d}" for d in system_dirs]]
    key_flags = [*COMMON_FLAGS, *WARNINGS]
    objects.mkdir(parents=True, exist_ok=True)
    built = []
    for source in sources:
        obj = objects / f"{source.stem}-{object_key(source, include_dirs + system_dirs, platform, key_flags)}.o"
        if not obj.exists():
            partial = obj.with_suffix(f".{os.getpid()}.{threading.get_ident()}.part")
            run_zig([*flags, "-c", str(source), "-o", str(partial)], f"{label}: {source.name}", platform)
            partial.replace(obj)
        built.append(obj)
    output.parent.mkdir(parents=True, exist_ok=True)
    run_zig(["-shared", *map(str, built), *platform.link_flags, "-o", str(output)], label, platform)
    for leftover in output.parent.glob("*.lib"):  # the DLL's import library
        leftover.unlink()


# MSVC's C as clang emulates it (-target x86_64-windows-msvc: _MSC_VER defined, no __GNUC__), compile-only: zig
# ships no MSVC runtime or Windows SDK, so mingw-w64's headers stand in for the SDK's and nothing is linked. It
# compiles the non-GCC branch of every __GNUC__ guard (which the gcc and clang builds never see) and rejects what
# cl.exe rejects among what gcc accepts: VLAs (optional in C11, absent in MSVC) and INFINITY/NAN in static
# initializers (not constants in mingw-w64's non-GCC math.h, nor in the UCRT of the Windows SDK 10.0.26100 with
# MSVC 19.42: error C2099). It is not cl.exe: clang still accepts GNU attributes and builtins outside the guards,
# and cl.exe's own warnings are not checked.
MSVC_TARGET = "x86_64-windows-msvc"
MSVC_FLAGS = ["-std=c11", "-nostdlib", "-O2", "-g0", "-Werror=vla", *WARNINGS]
# mingw-w64's stdlib.h puts __declspec(noreturn)/__declspec(deprecated) after the declarator when _MSC_VER is set,
# which clang (and cl.exe) refuse; the real SDK puts them first. Empty, they change nothing that is checked here.
MSVC_HEADER_SHIM = """#include <_mingw.h>
#undef __MINGW_ATTRIB_NORETURN
#define __MINGW_ATTRIB_NORETURN
#undef __MINGW_ATTRIB_DEPRECATED
#define __MINGW_ATTRIB_DEPRECATED
"""


@functools.cache
def zig_lib_dir() -> Path:
    """zig's lib/ folder (its libc headers), from `zig env` (asked once per process)."""
    result = subprocess.run([*zig_command(), "env"], capture_output=True, text=True)
    found = re.search(r'"?\.?lib_dir"?\s*[=:]\s*"([^"]+)"', result.stdout)
    if result.returncode != 0 or not found:
        raise CrossBuildError(f"`zig env` did not name zig's lib_dir:\n{result.stdout}{result.stderr}")
    return Path(found.group(1)).resolve()


def check_msvc(sources: list[Path], include_dirs: list[Path], system_dirs: list[Path], work: Path,
               label: str) -> None:
    """Compile C sources in clang's MSVC mode (MSVC_TARGET); a failure names the file and clang's message."""
    work.mkdir(parents=True, exist_ok=True)
    shim = work / "msvc_sdk_shim.h"
    shim.write_text(MSVC_HEADER_SHIM)
    windows_headers = zig_lib_dir() / "libc" / "include" / "any-windows-any"
    flags = [*MSVC_FLAGS, "-include", str(shim), *[f"-I{d}" for d in include_dirs],
             *[f"-isystem{d}" for d in [*system_dirs, windows_headers]]]
    for source in sources:
        result = subprocess.run([*zig_command(), "cc", "-target", MSVC_TARGET, *flags, "-c", str(source),
                                 "-o", str(work / f"{source.stem}.obj")], capture_output=True, text=True)
        if result.returncode != 0:
            raise CrossBuildError(f"{label}: {source.name} does not compile as MSVC C ({MSVC_TARGET}):\n"
                                  f"{result.stderr.strip()}")


# Mach-O CPU types of the universal (fat) header: x86_64 and arm64 (mach/machine.h).
MACHO_CPU = {0x01000007: "x86_64", 0x0100000C: "arm64"}


def universal_macho(slices: list[Path], output: Path) -> None:
    """A universal (fat) Mach-O of thin Mach-O slices, as `lipo -create` writes it (slices aligned to 2^14)."""
    align = 14
    header = struct.pack(">II", 0xCAFEBABE, len(slices))
    offset = (8 + 20 * len(slices) + (1 << align) - 1) & ~((1 << align) - 1)
    entries, bodies = b"", []
    for path in slices:
        data = path.read_bytes()
        magic, cputype, cpusubtype = struct.unpack("<IiI", data[:12])
        if magic != 0xFEEDFACF or cputype not in MACHO_CPU:
            raise CrossBuildError(f"{path}: not a 64-bit x86_64/arm64 Mach-O (magic {magic:#x}, cpu {cputype:#x})")
        entries += struct.pack(">iIIII", cputype, cpusubtype & 0x00FFFFFF, offset, len(data), align)
        bodies.append((offset, data))
        offset = (offset + len(data) + (1 << align) - 1) & ~((1 << align) - 1)
    blob = bytearray(header + entries)
    for start, data in bodies:
        blob += b"\0" * (start - len(blob)) + data
    output.write_bytes(bytes(blob))


@dataclass(frozen=True)
class FmuSource:
    path: Path          # the .fmu built by cmake
    identifier: str     # modelIdentifier (binary name)
    fmi_version: int    # 2 or 3


def read_fmu(path: Path) -> FmuSource:
    with zipfile.ZipFile(path) as archive:
        root = ET.fromstring(archive.read("modelDescription.xml"))
    cosim = root.find("CoSimulation")
    if cosim is None or not cosim.get("modelIdentifier"):
        raise CrossBuildError(f"{path}: modelDescription.xml has no CoSimulation modelIdentifier")
    version = int(root.get("fmiVersion", "0").split(".")[0])
    if version not in (2, 3):
        raise CrossBuildError(f"{path}: modelDescription.xml fmiVersion '{root.get('fmiVersion')}' is not 2 or 3")
    return FmuSource(path, cosim.get("modelIdentifier", ""), version)


def extract_sources(fmu: FmuSource, work: Path) -> tuple[list[Path], Path, Path]:
    """The FMU's sources/ into work/sources, the FMI standard's headers apart into work/fmi_headers (where "..."
    includes do not find them before -isystem): (C files, sources folder, standard headers folder)."""
    shutil.rmtree(work, ignore_errors=True)
    with zipfile.ZipFile(fmu.path) as archive:
        members = [m for m in archive.namelist() if m.startswith("sources/")]
        if not any(m.endswith(".c") for m in members):
            raise CrossBuildError(f"{fmu.path}: no C files in sources/")
        archive.extractall(work, members)
    standard = work / "fmi_headers"
    standard.mkdir()
    for header in (work / "sources").glob("fmi*.h"):
        if STANDARD_HEADER.match(header.name):
            header.rename(standard / header.name)
    return sorted((work / "sources").glob("*.c")), work / "sources", standard


def build_fmu_binary(fmu: FmuSource, platform: Platform, work: Path, objects: Path) -> Path:
    """One platform's binary of one FMU from its sources/ (extracted by extract_sources into work)."""
    sources = sorted((work / "sources").glob("*.c"))
    output = work / platform.key / (fmu.identifier + platform.extension)
    compile_library(sources, [work / "sources"], [work / "fmi_headers"], platform, output,
                    f"{fmu.path.name} ({fmu.identifier})", objects)
    return output


def fmu_binary_entries(fmu: FmuSource, built: dict[str, Path], work: Path) -> dict[str, Path]:
    """archive name -> file of the binaries/ folders of an FMU of fmu.fmi_version."""
    entries: dict[str, Path] = {}
    by_key = {p.key: p for p in PLATFORMS}
    darwin = [built[k] for k in ("x86_64-darwin", "aarch64-darwin") if k in built]
    for key, library in built.items():
        platform = by_key[key]
        if fmu.fmi_version == 3:
            entries[f"binaries/{platform.fmi3}/{library.name}"] = library
        elif platform.fmi2 != "darwin64":
            entries[f"binaries/{platform.fmi2}/{library.name}"] = library
    if fmu.fmi_version == 2 and darwin:
        universal = work / "darwin64" / (fmu.identifier + ".dylib")
        universal.parent.mkdir(parents=True, exist_ok=True)
        universal_macho(darwin, universal)
        entries[f"binaries/darwin64/{universal.name}"] = universal
    return entries


def write_fmu(fmu: FmuSource, entries: dict[str, Path], output: Path) -> None:
    """The FMU again, its binaries/ replaced by entries (everything else copied as it is)."""
    output.parent.mkdir(parents=True, exist_ok=True)
    partial = output.with_suffix(".fmu.part")
    with zipfile.ZipFile(fmu.path) as source, zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as target:
        for info in source.infolist():
            if not info.filename.startswith("binaries/"):
                target.writestr(info, source.read(info))
        for name in sorted(entries):
            target.write(entries[name], name)
    partial.replace(output)


STEPPER_LABEL = "the stepper library (fmus/stepper/stepper.c)"


def stepper_sources() -> tuple[list[Path], list[Path], list[Path]]:
    """The stepper library's C files, include folders and system include folders (the FMI standard's headers)."""
    stepper = REPO / "fmus" / "stepper"
    third_party = REPO / "fmus" / "third_party"
    return [stepper / "stepper.c"], [stepper], [third_party / "fmi2", third_party / "fmi3"]


def build_stepper(platform: Platform, out_dir: Path, objects: Path) -> str:
    prefix = "" if platform.extension == ".dll" else "lib"
    output = out_dir / "stepper" / platform.fmi3 / f"{prefix}milling_stepper{platform.extension}"
    compile_library(*stepper_sources(), platform, output, STEPPER_LABEL, objects)
    return str(output.relative_to(out_dir))


def check_all_msvc(sources: list[FmuSource], work: dict[Path, Path], no_stepper: bool, stepper_work: Path,
                   jobs: int) -> None:
    """check_msvc on every FMU's extracted sources/ (and the stepper library's source), `jobs` at once."""
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        checks = {f.path.name: pool.submit(check_msvc, sorted((work[f.path] / "sources").glob("*.c")),
                                           [work[f.path] / "sources"], [work[f.path] / "fmi_headers"],
                                           work[f.path] / "msvc", f"{f.path.name} ({f.identifier})")
                  for f in sources}
        if not no_stepper:
            checks["stepper"] = pool.submit(check_msvc, *stepper_sources(), stepper_work, STEPPER_LABEL)
        for name, check in checks.items():
            check.result()
            print(f"{name}: MSVC C ok", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus",
                        help="the FMUs built by cmake (default build/fmus)")
    parser.add_argument("--out", type=Path, default=REPO / "build" / "fmus-all",
                        help="where the all-platform FMUs go (default build/fmus-all)")
    parser.add_argument("--platform", action="append", choices=PLATFORM_KEYS,
                        help="only these platforms (repeatable; default all)")
    parser.add_argument("--fmu", action="append", metavar="FILE",
                        help="only these FMU files of --fmu-dir, e.g. SpindlePower_fmi2.fmu (repeatable)")
    parser.add_argument("--no-stepper", action="store_true", help="do not build the stepper library")
    parser.add_argument("--objects", type=Path, help="compiled objects, reused by content (default OUT/.objects)")
    parser.add_argument("--jobs", "-j", type=int, default=2, help="FMUs built at once (default 2)")
    parser.add_argument("--check-msvc", action="store_true",
                        help="only compile every FMU's sources/ and the stepper as MSVC C (clang's emulation, "
                             "mingw-w64 headers; no binaries written) and report")
    args = parser.parse_args(argv)

    platforms = [p for p in PLATFORMS if not args.platform or p.key in args.platform]
    if args.fmu:
        fmus = [args.fmu_dir / name for name in args.fmu]
        missing = [str(p) for p in fmus if not p.is_file()]
    else:
        fmus = sorted(args.fmu_dir.glob("*.fmu"))
        missing = [] if fmus else [f"{args.fmu_dir}/*.fmu"]
    if missing:
        print(f"error: no such FMU: {', '.join(missing)} (build them first: cmake --build build)", file=sys.stderr)
        return 2
    start = time.perf_counter()
    objects = args.objects or args.out / ".objects"  # objects by content: an unchanged file is not compiled again
    try:
        zig_command()
        sources = [read_fmu(path) for path in fmus]
        # FMI 3 first, FMI 2 after: the two versions of a model share most objects, built once
        sources.sort(key=lambda f: (f.fmi_version != 3, f.path.name))
        work = {f.path: args.out / ".work" / f.path.stem for f in sources}
        for fmu in sources:
            extract_sources(fmu, work[fmu.path])
        if args.check_msvc:
            check_all_msvc(sources, work, args.no_stepper, args.out / ".work" / "stepper-msvc", args.jobs)
            shutil.rmtree(args.out / ".work", ignore_errors=True)
            print(f"{len(fmus)} FMUs{'' if args.no_stepper else ' and the stepper'} compile as MSVC C "
                  f"({MSVC_TARGET}) in {time.perf_counter() - start:.1f} s")
            return 0
        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            binaries = {(f.path, p.key): pool.submit(build_fmu_binary, f, p, work[f.path], objects)
                        for f in sources for p in platforms}
            steppers = [] if args.no_stepper else [pool.submit(build_stepper, p, args.out, objects)
                                                   for p in platforms]
            for fmu in sources:
                built = {p.key: binaries[(fmu.path, p.key)].result() for p in platforms}
                entries = fmu_binary_entries(fmu, built, work[fmu.path])
                write_fmu(fmu, entries, args.out / fmu.path.name)
                print(f"{fmu.path.name}: {', '.join(sorted(entries))}", flush=True)
            for job in steppers:
                print(job.result(), flush=True)
    except CrossBuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    shutil.rmtree(args.out / ".work", ignore_errors=True)
    print(f"{len(fmus)} FMUs for {len(platforms)} platforms in {time.perf_counter() - start:.1f} s -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

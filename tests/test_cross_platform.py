"""The FMUs for every platform, cross-built from Linux with zig's cc (fmus/cross/build_all_platforms.py,
docs/portability.md): each binary has its platform's format (ELF, PE, Mach-O headers parsed here) and exports
every FMI function; the Linux x86_64 binaries need no glibc symbol version above 2.17 (objdump -T); the Windows
DLLs, driven under wine by a small C importer cross-built the same way (fmus/cross/fmu_driver.c), give the Linux
binaries' results to 1e-12 on every FMU. Skipped with the reason when zig (PyPI ziglang) or wine is missing.
"""
from __future__ import annotations

import importlib.util
import math
import os
import re
import shutil
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import REPO, expected_fmus, fmu_dir, split_fmu_name

SCRIPT = REPO / "fmus" / "cross" / "build_all_platforms.py"
DRIVER = REPO / "fmus" / "cross" / "fmu_driver.c"
THIRD_PARTY = REPO / "fmus" / "third_party"
GLIBC_LIMIT = (2, 17)
TOLERANCE = 1e-12

# every FMU for the platforms the glibc and wine checks use; these FMUs also for every platform
ALL_PLATFORM_FMUS = ("SpindlePower.fmu", "SpindlePower_fmi2.fmu")
PLATFORMS_FMI3 = {"x86_64-linux": ("ELF", "x86_64"), "aarch64-linux": ("ELF", "aarch64"),
                  "x86_64-windows": ("PE", "x86_64"), "x86_64-darwin": ("Mach-O", "x86_64"),
                  "aarch64-darwin": ("Mach-O", "arm64")}
PLATFORMS_FMI2 = {"linux64": [("ELF", "x86_64")], "aarch64-linux": [("ELF", "aarch64")],
                  "win64": [("PE", "x86_64")], "darwin64": [("Mach-O", "x86_64"), ("Mach-O", "arm64")]}
EXTENSIONS = {"ELF": ".so", "PE": ".dll", "Mach-O": ".dylib"}


def zig_missing() -> str | None:
    if os.environ.get("ZIG") or importlib.util.find_spec("ziglang") is not None:
        return None
    return "zig is not installed: `pip install ziglang` (PyPI) into this Python, or set ZIG"


def run_script(fmus: Path, *args: str) -> None:
    # the objects of `make fmus-all-platforms` (by content: a changed source is compiled again)
    objects = fmu_dir().parent / "fmus-all" / ".objects"
    result = subprocess.run([sys.executable, str(SCRIPT), "--fmu-dir", str(fmus), "--objects", str(objects), *args],
                            capture_output=True, text=True)
    assert result.returncode == 0, f"build_all_platforms.py {' '.join(args)} failed:\n{result.stderr}"


@pytest.fixture(scope="module")
def cross(tmp_path_factory) -> Path:
    """Every FMU for Linux x86_64 and Windows x86_64, ALL_PLATFORM_FMUS and the stepper for all five platforms."""
    if zig_missing():
        pytest.skip(zig_missing())
    built = tmp_path_factory.mktemp("fmus")  # a copy: what the other tests compare with stays as it was built
    for path in expected_fmus():
        assert path.is_file(), f"{path} was not built: cmake --build build first"
        shutil.copy(path, built / path.name)
    out = tmp_path_factory.mktemp("fmus-all")
    run_script(built, "--out", str(out), "--no-stepper", "--platform", "x86_64-linux", "--platform", "x86_64-windows")
    every = tmp_path_factory.mktemp("fmus-all-platforms")
    fmus = [arg for name in ALL_PLATFORM_FMUS for arg in ("--fmu", name)]
    run_script(built, "--out", str(every), *fmus)
    for name in ALL_PLATFORM_FMUS:
        shutil.copy(every / name, out / name)
    shutil.copytree(every / "stepper", out / "stepper")
    shutil.copytree(built, out / "original")
    return out


# ---- the formats, parsed from the headers ----

@dataclass(frozen=True)
class Binary:
    kind: str            # ELF, PE, Mach-O
    machine: str         # x86_64, aarch64, arm64
    exports: frozenset[str]


def read_cstring(data: bytes, offset: int) -> str:
    return data[offset:data.index(b"\0", offset)].decode()


def parse_elf(data: bytes) -> Binary:
    assert data[4] == 2 and data[5] == 1, "not a 64-bit little-endian ELF"
    e_type, e_machine = struct.unpack_from("<HH", data, 16)
    assert e_type == 3, f"ELF type {e_type} is not a shared object (3)"
    e_shoff, = struct.unpack_from("<Q", data, 40)
    e_shentsize, e_shnum = struct.unpack_from("<HH", data, 58)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, e_shoff + i * e_shentsize) for i in range(e_shnum)]
    exports = set()
    for _name, sh_type, _flags, _addr, offset, size, link, _info, _align, entsize in sections:
        if sh_type != 11:  # SHT_DYNSYM
            continue
        strtab = sections[link][4]
        for k in range(size // entsize):
            st_name, st_info, st_other, st_shndx = struct.unpack_from("<IBBH", data, offset + k * entsize)
            if st_shndx != 0 and st_info >> 4 in (1, 2) and st_other & 3 == 0:  # defined, global/weak, default
                exports.add(read_cstring(data, strtab + st_name))
    return Binary("ELF", {62: "x86_64", 183: "aarch64"}.get(e_machine, str(e_machine)), frozenset(exports))


def parse_pe(data: bytes) -> Binary:
    assert data[:2] == b"MZ", "no MZ header"
    pe, = struct.unpack_from("<I", data, 0x3C)
    assert data[pe:pe + 4] == b"PE\0\0", "no PE signature"
    machine, n_sections, _, _, _, opt_size, characteristics = struct.unpack_from("<HHIIIHH", data, pe + 4)
    assert characteristics & 0x2000, "not a DLL (IMAGE_FILE_DLL)"
    opt = pe + 24
    assert struct.unpack_from("<H", data, opt)[0] == 0x20B, "not PE32+"
    export_rva, = struct.unpack_from("<I", data, opt + 112)  # data directory 0 of a PE32+ optional header
    sections = [struct.unpack_from("<8sIIII", data, opt + opt_size + 40 * i) for i in range(n_sections)]

    def offset(rva: int) -> int:
        for _name, vsize, vaddr, raw_size, raw_ptr in sections:
            if vaddr <= rva < vaddr + max(vsize, raw_size):
                return rva - vaddr + raw_ptr
        raise AssertionError(f"RVA {rva:#x} is in no section")

    exports = set()
    if export_rva:
        n_names, = struct.unpack_from("<I", data, offset(export_rva) + 24)
        names_rva, = struct.unpack_from("<I", data, offset(export_rva) + 32)
        for i in range(n_names):
            exports.add(read_cstring(data, offset(struct.unpack_from("<I", data, offset(names_rva) + 4 * i)[0])))
    return Binary("PE", {0x8664: "x86_64", 0xAA64: "aarch64"}.get(machine, hex(machine)), frozenset(exports))


def parse_macho(data: bytes) -> Binary:
    magic, cputype, _sub, filetype, ncmds = struct.unpack_from("<IiIII", data, 0)
    assert magic == 0xFEEDFACF, f"not a 64-bit Mach-O (magic {magic:#x})"
    assert filetype == 6, f"Mach-O file type {filetype} is not a dylib (6)"
    exports, at = set(), 32
    for _ in range(ncmds):
        cmd, size = struct.unpack_from("<II", data, at)
        if cmd == 2:  # LC_SYMTAB
            symoff, nsyms, stroff, _ = struct.unpack_from("<IIII", data, at + 8)
            for k in range(nsyms):
                n_strx, n_type, _sect, _desc, _value = struct.unpack_from("<IBBHQ", data, symoff + 16 * k)
                if n_type & 0x01 and not n_type & 0x10 and n_type & 0x0E == 0x0E:  # N_EXT, not N_PEXT, N_SECT
                    exports.add(read_cstring(data, stroff + n_strx).removeprefix("_"))
        at += size
    return Binary("Mach-O", {0x01000007: "x86_64", 0x0100000C: "arm64"}.get(cputype, hex(cputype)),
                  frozenset(exports))


def parse_binaries(data: bytes) -> list[Binary]:
    """One Binary per architecture (a universal Mach-O has several)."""
    if data[:4] == b"\x7fELF":
        return [parse_elf(data)]
    if data[:2] == b"MZ":
        return [parse_pe(data)]
    if data[:4] == b"\xca\xfe\xba\xbe":
        count, = struct.unpack_from(">I", data, 4)
        slices = [struct.unpack_from(">iIIII", data, 8 + 20 * i) for i in range(count)]
        return [parse_macho(data[off:off + size]) for _cpu, _sub, off, size, _align in slices]
    return [parse_macho(data)]


def fmi_functions(version: int) -> set[str]:
    """Every function the FMI standard's header declares for export (FMI2_Export fmi2X...; FMI3_Export ...)."""
    header = (THIRD_PARTY / f"fmi{version}" / f"fmi{version}Functions.h").read_text()
    return set(re.findall(rf"FMI{version}_Export\s+fmi{version}\w+TYPE\s+(fmi{version}\w+)\s*;", header))


def model_identifier(archive: zipfile.ZipFile) -> str:
    return ET.fromstring(archive.read("modelDescription.xml")).find("CoSimulation").get("modelIdentifier")


# ---- formats and exports ----

def test_fmi_function_lists_are_read_from_the_standard_headers():
    assert {"fmi2Instantiate", "fmi2DoStep", "fmi2GetReal"} <= fmi_functions(2) and len(fmi_functions(2)) == 44
    assert {"fmi3InstantiateCoSimulation", "fmi3DoStep", "fmi3GetFloat64"} <= fmi_functions(3)


@pytest.mark.parametrize("name", ALL_PLATFORM_FMUS)
def test_every_platform_binary_has_its_format_and_exports_fmi(cross, name):
    _identifier, version = split_fmu_name(name)
    expected = PLATFORMS_FMI3 if version == 3 else PLATFORMS_FMI2
    with zipfile.ZipFile(cross / name) as archive:
        identifier = model_identifier(archive)
        folders = {n.split("/")[1] for n in archive.namelist() if n.startswith("binaries/") and n.count("/") == 2}
        assert folders == set(expected), f"{name}: binaries/ holds {sorted(folders)}"
        for folder, architectures in expected.items():
            arch_list = architectures if isinstance(architectures, list) else [architectures]
            member = f"binaries/{folder}/{identifier}{EXTENSIONS[arch_list[0][0]]}"
            binaries = parse_binaries(archive.read(member))
            assert [(b.kind, b.machine) for b in binaries] == arch_list, member
            for binary in binaries:
                missing = fmi_functions(version) - binary.exports
                assert not missing, f"{name}: {member} ({binary.machine}) does not export {sorted(missing)}"
        assert any(n.startswith("sources/") for n in archive.namelist()), f"{name}: sources/ was not kept"


def test_every_fmu_keeps_everything_but_the_binaries(cross):
    for path in expected_fmus():
        with zipfile.ZipFile(cross / "original" / path.name) as original, zipfile.ZipFile(cross / path.name) as merged:
            kept = {n: original.read(n) for n in original.namelist() if not n.startswith("binaries/")}
            assert {n: merged.read(n) for n in kept} == kept, path.name


@pytest.mark.parametrize("platform", sorted(PLATFORMS_FMI3))
def test_stepper_library_for_every_platform(cross, platform):
    kind, machine = PLATFORMS_FMI3[platform]
    prefix = "" if kind == "PE" else "lib"
    path = cross / "stepper" / platform / f"{prefix}milling_stepper{EXTENSIONS[kind]}"
    binaries = parse_binaries(path.read_bytes())
    assert [(b.kind, b.machine) for b in binaries] == [(kind, machine)]
    assert {"stp_run", "stp_abi_version", "stp_struct_size"} <= binaries[0].exports, sorted(binaries[0].exports)


def test_universal_darwin64_slices_are_aligned_and_whole(cross):
    """FMI 2's darwin64 binary (universal_macho): each slice page-aligned as its header says, none overlapping,
    the file ending with the last (the slices' formats and exports: the test above)."""
    with zipfile.ZipFile(cross / "SpindlePower_fmi2.fmu") as archive:
        fat = archive.read("binaries/darwin64/SpindlePower.dylib")
    count, = struct.unpack_from(">I", fat, 4)
    slices = sorted(struct.unpack_from(">iIIII", fat, 8 + 20 * i)[2:] for i in range(count))
    assert count == 2
    assert all(offset % (1 << align) == 0 for offset, _size, align in slices)
    assert slices[0][0] >= 8 + 20 * count and slices[0][0] + slices[0][1] <= slices[1][0]
    assert slices[1][0] + slices[1][1] == len(fat)


# ---- ForceNet's kernel ----

@pytest.mark.parametrize("name", ["ForceNet.fmu", "ForceNet_fmi2.fmu"])
def test_the_cross_built_forcenet_picks_its_kernel_by_the_cpu_and_matches_the_native_build(cross, name):
    """The cross build compiles ForceNet's AVX2 kernel too (its own cpuid probe: zig links no libgcc, whose
    __cpu_model __builtin_cpu_supports reads). Its Linux x86_64 binary, loaded by fmpy here, names at instantiation
    the kernel this CPU's features pick, the native build's choice, and steps a cut to the native build's outputs bit
    for bit (the kernels compute the same sums in the same order)."""
    from fmu_helpers import Slave
    outputs = ("Fx", "Fy", "Fz", "torque")
    results, kernels = [], []
    for path in (cross / name, cross / "original" / name):
        with Slave(path) as slave:
            slave.instantiate(logging_on=True)
            kernels.append([m.message for m in slave.messages if "network kernel" in m.message])
            slave.initialize({"axial_depth": 0.002, "entry_angle": 0.0, "exit_angle": math.pi,
                              "spindle_speed": 1000.0, "feed_velocity_x": 0.01})
            rows = []
            for _ in range(200):
                slave.step(1e-5)
                rows.append(slave.get(outputs))
            results.append(np.array(rows))
    assert len(kernels[0]) == 1 and kernels[0] == kernels[1], kernels
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():  # the kernel /proc/cpuinfo's flags (the CPU's and the OS's support) call for
        avx2 = re.search(r"^flags\s*:.*\bavx2\b", cpuinfo.read_text(), re.MULTILINE) is not None
        assert kernels[0][0].endswith("network kernel AVX2" if avx2 else "network kernel baseline"), kernels
    assert np.any(results[1] != 0.0)
    assert np.array_equal(results[0], results[1])


# ---- wheels for every platform ----

def _stepper(cross: Path, platform: str) -> Path:
    kind = PLATFORMS_FMI3[platform][0]
    return cross / "stepper" / platform / f"{'' if kind == 'PE' else 'lib'}milling_stepper{EXTENSIONS[kind]}"


def test_the_wheel_tag_follows_the_stepper_library_s_platform(cross):
    """buildtools/wheel_files.py reads the tag from the binaries: manylinux for ELF, win_amd64 for PE, macosx for
    Mach-O with the oldest macOS the slices name (11.0, the cross build's floor)."""
    sys.path.insert(0, str(REPO))  # buildtools/ (the build helpers: not installed)
    from buildtools.native import macho_slices
    from buildtools.wheel_files import WheelFiles
    every = tuple(sorted(cross.glob("*.fmu")))
    only = tuple(cross / name for name in ALL_PLATFORM_FMUS)
    assert WheelFiles(every, _stepper(cross, "x86_64-linux")).platform_tag() == "manylinux_2_17_x86_64"
    assert WheelFiles(every, _stepper(cross, "x86_64-windows")).platform_tag() == "win_amd64"
    assert WheelFiles(only, _stepper(cross, "aarch64-linux")).platform_tag() == "manylinux_2_17_aarch64"
    assert WheelFiles(only, _stepper(cross, "x86_64-darwin")).platform_tag() == "macosx_11_0_x86_64"
    assert WheelFiles(only, _stepper(cross, "aarch64-darwin")).platform_tag() == "macosx_11_0_arm64"
    with zipfile.ZipFile(cross / "SpindlePower_fmi2.fmu") as archive:
        fat = archive.read("binaries/darwin64/SpindlePower.dylib")
    assert {(p.arch, p.min_macos) for p in macho_slices(fat, "darwin64")} == {("x86_64", (11, 0)), ("arm64", (11, 0))}


@pytest.mark.parametrize("platform", ["aarch64-linux", "x86_64-darwin", "aarch64-darwin"])
def test_a_wheel_whose_fmus_lack_the_stepper_s_platform_is_refused(cross, platform):
    """Most FMUs of the fixture are built for Linux x86_64 and Windows only: a wheel for another platform would
    install FMUs that do not load there. The message names the platform and the FMUs."""
    sys.path.insert(0, str(REPO))
    from buildtools.wheel_files import WheelFiles, WheelFilesError
    with pytest.raises(WheelFilesError, match=r"14 of 16 FMUs have no (Linux aarch64|macOS (x86_64|arm64)) "
                                              r"binary: .*CuttingForce\.fmu"):
        WheelFiles(tuple(sorted(cross.glob("*.fmu"))), _stepper(cross, platform)).platform_tag()


def test_the_windows_wheel_carries_the_dll_and_every_fmu(cross, tmp_path):
    """`pip wheel` with the cross-built FMUs and the Windows stepper library (docs/packaging.md): a win_amd64 wheel
    holding milling_stepper.dll, which the fast path looks for on Windows, and every FMU with its Windows binary.
    It is not installed here: that needs a Windows Python."""
    from test_wheel import FMUS_ENV, STEPPER_ENV, copy_tracked

    from milling_twin.orchestrator.fastpath import LIBRARY_NAMES
    source = tmp_path / "src"
    copy_tracked(source)
    fmus = tmp_path / "fmus"
    fmus.mkdir()
    for path in cross.glob("*.fmu"):
        shutil.copy(path, fmus / path.name)
    env = {**os.environ, FMUS_ENV: str(fmus), STEPPER_ENV: str(_stepper(cross, "x86_64-windows"))}
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(tmp_path / "dist"),
                            str(source)], capture_output=True, text=True, env=env, timeout=600)
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("milling_twin-*.whl")
    assert wheel.name.endswith("-py3-none-win_amd64.whl"), wheel.name
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        assert f"milling_twin/stepper/{LIBRARY_NAMES['win32']}" in names
        assert {f"milling_twin/fmus/{p.name}" for p in fmus.glob("*.fmu")} <= names
        inner = archive.read("milling_twin/fmus/CuttingForce.fmu")
    (tmp_path / "CuttingForce.fmu").write_bytes(inner)
    with zipfile.ZipFile(tmp_path / "CuttingForce.fmu") as fmu:
        assert "binaries/x86_64-windows/CuttingForce.dll" in fmu.namelist()


# ---- glibc 2.17 ----

def glibc_versions(library: Path) -> set[tuple[int, ...]]:
    result = subprocess.run(["objdump", "-T", str(library)], capture_output=True, text=True, check=True)
    return {tuple(int(p) for p in v.split(".")) for v in re.findall(r"GLIBC_([0-9.]+[0-9])", result.stdout)}


def test_linux_binaries_need_glibc_2_17_at_most(cross, tmp_path):
    if shutil.which("objdump") is None:
        pytest.skip("objdump (binutils) is not installed")
    libraries = [cross / "stepper" / "x86_64-linux" / "libmilling_stepper.so"]
    for path in expected_fmus():
        with zipfile.ZipFile(cross / path.name) as archive:
            identifier = model_identifier(archive)
            folder = "x86_64-linux" if split_fmu_name(path)[1] == 3 else "linux64"
            target = tmp_path / path.stem / f"{identifier}.so"
            target.parent.mkdir()
            target.write_bytes(archive.read(f"binaries/{folder}/{identifier}.so"))
            libraries.append(target)
    for name in ALL_PLATFORM_FMUS:  # built for aarch64 too
        with zipfile.ZipFile(cross / name) as archive:
            identifier = model_identifier(archive)
            target = tmp_path / f"aarch64-{name}" / f"{identifier}.so"
            target.parent.mkdir()
            target.write_bytes(archive.read(f"binaries/aarch64-linux/{identifier}.so"))
            libraries.append(target)
    libraries.append(cross / "stepper" / "aarch64-linux" / "libmilling_stepper.so")
    for library in libraries:
        versions = glibc_versions(library)
        assert versions, f"objdump -T {library} shows no GLIBC_ version: is it dynamically linked?"
        assert max(versions) <= GLIBC_LIMIT, f"{library} needs GLIBC_{'.'.join(map(str, max(versions)))}"


# ---- the Windows DLLs under wine against the Linux binaries ----

# per model: the inputs (name: value at t=0, rate per second), step size, steps: each FMU does its real work
# (the Interpolator runs its default program, the Workpiece is cut, the forces and vibration respond)
RUNS = {
    "CuttingForce": ({"spindle_speed": (628.3, 0.0), "feed_velocity_x": (0.01, 0.0), "feed_velocity_y": (0.002, 0.0),
                      "axial_depth": (0.002, 0.0), "entry_angle": (0.3, 0.0), "exit_angle": (2.8, 0.0),
                      "displacement_x": (0.0, 1e-3), "displacement_y": (0.0, -2e-3)}, 1e-4, 600),
    "ForceNet": ({"spindle_speed": (628.3, 0.0), "feed_velocity_x": (0.01, 0.0), "feed_velocity_y": (0.002, 0.0),
                  "axial_depth": (0.002, 0.0), "entry_angle": (0.3, 0.0), "exit_angle": (2.8, 0.0),
                  "displacement_x": (0.0, 1e-3), "displacement_y": (0.0, -2e-3)}, 1e-4, 600),
    "Interpolator": ({"feed_override": (0.8, 0.4)}, 1e-3, 1500),
    "MeasuringChain": ({"force_x": (100.0, 2e4), "force_y": (-50.0, 1e4), "force_z": (20.0, -5e3)}, 1e-5, 2000),
    "MrrEstimator": ({"feed_velocity_x": (0.01, 0.01), "feed_velocity_y": (0.0, 0.004)}, 1e-3, 300),
    "SpindlePower": ({"spindle_speed": (100.0, 2000.0), "spindle_speed_command": (628.3, 0.0), "mrr": (1e-7, 1e-6),
                      "cutting_power": (50.0, 800.0)}, 1e-3, 500),
    "ToolVibration": ({"force_x": (100.0, 2e4), "force_y": (-50.0, 1e4)}, 1e-5, 2000),
    "Workpiece": ({"tool_x": (-0.006, 0.05), "tool_y": (0.03, 0.0), "tool_z": (0.027, 0.0),
                   "spindle_speed": (628.3, 0.0)}, 1e-3, 400),
}


def wine_command() -> list[str] | None:
    for candidate in (os.environ.get("WINE"), shutil.which("wine64"), shutil.which("wine"), "/usr/lib/wine/wine64"):
        if candidate and Path(candidate).is_file():
            return [candidate]
    return None


def compile_driver(target: str, output: Path) -> Path:
    zig = [os.environ["ZIG"]] if os.environ.get("ZIG") else [sys.executable, "-m", "ziglang"]
    command = [*zig, "cc", "-target", target, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-Wconversion",
               "-Wno-sign-conversion", "-isystem", str(THIRD_PARTY / "fmi2"), "-isystem", str(THIRD_PARTY / "fmi3"),
               str(DRIVER), "-o", str(output)]
    if "linux" in target:
        command.append("-ldl")
    result = subprocess.run(command, capture_output=True, text=True)
    assert result.returncode == 0, f"fmus/cross/fmu_driver.c for {target}:\n{result.stderr}"
    return output


def driver_arguments(archive: zipfile.ZipFile, version: int) -> tuple[str, list[str], list[str]]:
    """(token, inputs VR=A:B, scalar Real/Float64 outputs) of the FMU as RUNS sets it."""
    root = ET.fromstring(archive.read("modelDescription.xml"))
    identifier = model_identifier(archive)
    inputs, step, steps = RUNS[identifier]
    refs, outputs = {}, []
    if version == 2:
        token = root.get("guid")
        for v in root.iter("ScalarVariable"):
            if v.find("Real") is not None:
                refs[v.get("name")] = v.get("valueReference")
                if v.get("causality") == "output":
                    outputs.append(v.get("valueReference"))
    else:
        token = root.get("instantiationToken")
        for v in root.find("ModelVariables"):
            if v.tag == "Float64" and v.find("Dimension") is None:
                refs[v.get("name")] = v.get("valueReference")
                if v.get("causality") == "output":
                    outputs.append(v.get("valueReference"))
    settings = [f"{refs[name]}={a!r}:{b!r}" for name, (a, b) in inputs.items()]
    return token, settings, outputs


def windows_path(path: Path) -> str:
    return "Z:" + str(path).replace("/", "\\")


def simulate(command: list[str], env: dict[str, str]) -> list[list[float]]:
    result = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, f"{' '.join(command)}:\n{result.stderr[-3000:]}"
    return [[float(x) for x in line.split()] for line in result.stdout.splitlines()]


def test_windows_dlls_under_wine_match_the_linux_binaries(cross, tmp_path):
    wine = wine_command()
    if wine is None:
        pytest.skip("wine is not installed (apt-get install --no-install-recommends wine64, ~700 MB): "
                    "docs/portability.md")
    driver_exe = compile_driver("x86_64-windows-gnu", tmp_path / "fmu_driver.exe")
    driver_linux = compile_driver("x86_64-linux-gnu.2.17", tmp_path / "fmu_driver")
    env = {**os.environ, "WINEDEBUG": "-all"}
    worst = {}
    for path in expected_fmus():
        _identifier, version = split_fmu_name(path)
        unpacked = tmp_path / path.stem
        with zipfile.ZipFile(cross / path.name) as archive:
            archive.extractall(unpacked)
            identifier = model_identifier(archive)
            token, settings, outputs = driver_arguments(archive, version)
        _inputs, step, steps = RUNS[identifier]
        resources = unpacked / "resources"
        resources.mkdir(exist_ok=True)
        linux_folder, windows_folder = ("x86_64-linux", "x86_64-windows") if version == 3 else ("linux64", "win64")
        if version == 2:
            linux_location = resources.as_uri()
            windows_location = "file:///" + windows_path(resources).replace("\\", "/")
        else:
            linux_location, windows_location = f"{resources}/", windows_path(resources) + "\\"
        tail = [str(step), str(steps), *settings, "--", *outputs]
        linux = simulate([str(driver_linux), str(unpacked / "binaries" / linux_folder / f"{identifier}.so"),
                          str(version), token, linux_location, *tail], env)
        windows = simulate([*wine, str(driver_exe),
                            windows_path(unpacked / "binaries" / windows_folder / f"{identifier}.dll"),
                            str(version), token, windows_location, *tail], env)
        assert len(linux) == len(windows) == steps, path.name
        difference = 0.0
        for k, (a_row, b_row) in enumerate(zip(linux, windows)):
            for j, (a, b) in enumerate(zip(a_row, b_row)):
                gap = abs(a - b) / max(1.0, abs(a))
                assert gap <= TOLERANCE, f"{path.name}: step {k}, column {j}: Linux {a!r}, Windows {b!r}"
                difference = max(difference, gap)
        assert any(any(v != 0.0 for v in row_[1:]) for row_ in linux), f"{path.name}: every output stayed 0"
        worst[path.name] = difference
    print("largest relative Linux/Windows difference per FMU:", worst)


# ---- MSVC's C (clang's emulation with mingw-w64's headers, compile-only: docs/portability.md) ----

def load_script():
    spec = importlib.util.spec_from_file_location("build_all_platforms", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, module)  # its dataclasses look their module up there
    spec.loader.exec_module(sys.modules[spec.name])
    return sys.modules[spec.name]


def test_every_fmu_and_the_stepper_compile_as_msvc_c(tmp_path):
    if zig_missing():
        pytest.skip(zig_missing())
    result = subprocess.run([sys.executable, str(SCRIPT), "--check-msvc", "--fmu-dir", str(fmu_dir()),
                             "--out", str(tmp_path)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    checked = {line.split(":")[0] for line in result.stdout.splitlines() if line.endswith("MSVC C ok")}
    assert checked == {p.name for p in expected_fmus()} | {"stepper"}


# What gcc and clang accept and cl.exe refuses: the check must refuse it too, naming the file.
MSVC_REFUSED = {
    "infinity_in_a_static_initializer": ("#include <math.h>\nstatic const double bound[2] = {-INFINITY, INFINITY};\n"
                                         "double upper(void);\ndouble upper(void) { return bound[1]; }\n",
                                         "not a compile-time constant"),
    "variable_length_array": ("int last(int n);\nint last(int n) {\n    int a[n];\n    a[n - 1] = n;\n"
                              "    return a[n - 1];\n}\n", "variable length array"),
    "gcc_branch_not_taken": ("#ifndef __GNUC__\n#error the non-GCC branch\n#endif\nint one(void);\n"
                             "int one(void) { return 1; }\n", "the non-GCC branch"),
}


@pytest.mark.parametrize("case", sorted(MSVC_REFUSED))
def test_the_msvc_check_refuses_what_cl_refuses(case, tmp_path):
    if zig_missing():
        pytest.skip(zig_missing())
    code, message = MSVC_REFUSED[case]
    source = tmp_path / f"{case}.c"
    source.write_text(code)
    script = load_script()
    with pytest.raises(script.CrossBuildError, match=rf"{case}\.c does not compile as MSVC C[\s\S]*{message}"):
        script.check_msvc([source], [], [], tmp_path / "work", "check")

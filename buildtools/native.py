"""What a Windows DLL or a macOS dylib is built for, read from the file itself (no binutils, no lipo): the PE
machine, and each Mach-O slice's architecture and minimum macOS version (LC_BUILD_VERSION, or the older
LC_VERSION_MIN_MACOSX). The wheel's platform tag follows them (buildtools/wheel_files.py); ELF files are read by
buildtools/elf.py."""
from __future__ import annotations

import struct
from dataclasses import dataclass

# PE machine -> the architecture's name (and its wheel tag)
PE_MACHINES = {0x8664: "x86_64", 0xAA64: "aarch64"}
# Mach-O cputype -> the architecture's name in macOS wheel tags
MACHO_CPUS = {0x01000007: "x86_64", 0x0100000C: "arm64"}
_MH_MAGIC_64, _FAT_MAGIC = 0xFEEDFACF, 0xCAFEBABE
_LC_VERSION_MIN_MACOSX, _LC_BUILD_VERSION, _PLATFORM_MACOS = 0x24, 0x32, 1


class NativeError(ValueError):
    """Not a PE or Mach-O file this reader handles; the message names the file."""


@dataclass(frozen=True)
class MachOSlice:
    """One architecture of a (possibly universal) Mach-O file and the oldest macOS it runs on."""

    arch: str                    # x86_64, arm64
    min_macos: tuple[int, int]   # (major, minor)


def is_pe(data: bytes) -> bool:
    return data[:2] == b"MZ"


def is_macho(data: bytes) -> bool:
    if len(data) < 4:
        return False
    return struct.unpack_from(">I", data)[0] == _FAT_MAGIC or struct.unpack_from("<I", data)[0] == _MH_MAGIC_64


def pe_machine(data: bytes, name: str) -> str:
    """The architecture of the PE file ``data`` (``name`` for messages)."""
    if not is_pe(data) or len(data) < 0x40:
        raise NativeError(f"{name}: not a PE file (no MZ header)")
    pe, = struct.unpack_from("<I", data, 0x3C)
    if data[pe:pe + 4] != b"PE\0\0":
        raise NativeError(f"{name}: no PE signature at {pe:#x}")
    machine, = struct.unpack_from("<H", data, pe + 4)
    if machine not in PE_MACHINES:
        raise NativeError(f"{name}: PE machine {machine:#x} is none of {[hex(m) for m in PE_MACHINES]}")
    return PE_MACHINES[machine]


def _version(packed: int) -> tuple[int, int]:
    return packed >> 16, (packed >> 8) & 0xFF  # xxxx.yy.zz nibbles


def _thin_slice(data: bytes, name: str) -> MachOSlice:
    if len(data) < 32 or struct.unpack_from("<I", data)[0] != _MH_MAGIC_64:
        raise NativeError(f"{name}: not a 64-bit little-endian Mach-O file")
    _, cputype, _, _, ncmds = struct.unpack_from("<IiIII", data, 0)
    if cputype not in MACHO_CPUS:
        raise NativeError(f"{name}: Mach-O cputype {cputype:#x} is none of {[hex(c) for c in MACHO_CPUS]}")
    at, found = 32, None
    for _ in range(ncmds):
        cmd, size = struct.unpack_from("<II", data, at)
        if cmd == _LC_BUILD_VERSION:
            platform, minos = struct.unpack_from("<II", data, at + 8)
            if platform == _PLATFORM_MACOS:
                found = _version(minos)
        elif cmd == _LC_VERSION_MIN_MACOSX:
            found = _version(struct.unpack_from("<I", data, at + 8)[0])
        at += size
    if found is None:
        raise NativeError(f"{name}: Mach-O {MACHO_CPUS[cputype]} slice names no minimum macOS version "
                          "(no LC_BUILD_VERSION for macOS, no LC_VERSION_MIN_MACOSX)")
    return MachOSlice(MACHO_CPUS[cputype], found)


def macho_slices(data: bytes, name: str) -> list[MachOSlice]:
    """Each architecture of the Mach-O file ``data`` (one, or several for a universal file)."""
    if len(data) >= 8 and struct.unpack_from(">I", data)[0] == _FAT_MAGIC:
        count, = struct.unpack_from(">I", data, 4)
        slices = [struct.unpack_from(">iIIII", data, 8 + 20 * i) for i in range(count)]
        return [_thin_slice(data[offset:offset + size], f"{name} (slice {i})")
                for i, (_cpu, _sub, offset, size, _align) in enumerate(slices)]
    return [_thin_slice(data, name)]

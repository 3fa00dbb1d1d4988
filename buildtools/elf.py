"""What a Linux shared library needs from the C library: its machine and the GLIBC_x.y symbol versions it
references (the ``.gnu.version_r`` section, what ``objdump -T`` shows), read from the ELF file itself so that
building the wheel needs no binutils."""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass

SHT_GNU_VERNEED = 0x6FFFFFFE
# e_machine -> the architecture's name in wheel platform tags
MACHINES = {62: "x86_64", 183: "aarch64"}
_GLIBC = re.compile(r"^GLIBC_(\d+)\.(\d+)(?:\.\d+)?$")


class ElfError(ValueError):
    """Not an ELF file this reader handles; the message names the file."""


@dataclass(frozen=True)
class ElfNeeds:
    """A shared library's architecture (``x86_64``, ``aarch64``) and the newest glibc version it references."""

    machine: str
    glibc: tuple[int, int] | None  # None: no versioned glibc symbol


def is_elf(data: bytes) -> bool:
    return data[:4] == b"\x7fELF"


def elf_needs(data: bytes, name: str) -> ElfNeeds:
    """The machine and newest GLIBC_x.y version needed by the 64-bit little-endian ELF file ``data`` (``name``
    for messages)."""
    if not is_elf(data):
        raise ElfError(f"{name}: not an ELF file")
    if data[4] != 2 or data[5] != 1:
        raise ElfError(f"{name}: only 64-bit little-endian ELF files are read (class {data[4]}, data {data[5]})")
    (machine,) = struct.unpack_from("<H", data, 18)
    if machine not in MACHINES:
        raise ElfError(f"{name}: ELF machine {machine} is none of {sorted(MACHINES)}")
    shoff, = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize) for i in range(shnum)]
    versions: list[tuple[int, int]] = []
    for _, sh_type, _, _, offset, _, link, count, _, _ in sections:
        if sh_type != SHT_GNU_VERNEED:
            continue
        strtab = sections[link][4]
        entry = offset
        for _ in range(count):  # Elf64_Verneed: version, cnt, file, aux, next
            _, n_aux, _, aux, next_entry = struct.unpack_from("<HHIII", data, entry)
            at = entry + aux
            for _ in range(n_aux):  # Elf64_Vernaux: hash, flags, other, name, next
                _, _, _, name_offset, next_aux = struct.unpack_from("<IHHII", data, at)
                start = strtab + name_offset
                text = data[start:data.index(b"\0", start)].decode("ascii", "replace")
                match = _GLIBC.match(text)
                if match:
                    versions.append((int(match.group(1)), int(match.group(2))))
                at += next_aux
            entry += next_entry
    return ElfNeeds(MACHINES[machine], max(versions) if versions else None)

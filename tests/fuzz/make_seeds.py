"""Writes the committed seed corpora of the fuzz targets that are generated rather than copied
(tests/fuzz/README.md):

    python tests/fuzz/make_seeds.py            (from the repository root; rewrites the seed_* files)

- corpus/forcenet/: weights files of models/force_net.py (the default network and small random networks of
  several shapes, encoded by its encode_weights) with damaged variants, and resource locations;
- corpus/fmi/: FMI call sequences in the byte language of fuzz_fmi.c (shared by every FMU and FMI version).

Inputs found by the fuzzer (reproducers of fixed defects, libFuzzer's minimized corpus) sit beside them under
other names and are not touched.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]

from milling_twin.models import force_net

CORPUS = Path(__file__).resolve().parent / "corpus"


def small_network(kernel: int, width: int, blocks: int, seed: int) -> force_net.Weights:
    rng = np.random.default_rng(seed)
    shapes = force_net.Weights.expected_shapes(kernel, width, blocks)
    layers = tuple((rng.normal(0.0, 0.5, shape), rng.normal(0.0, 0.1, shape[0])) for shape in shapes)
    return force_net.Weights(layers=layers)


def forcenet_seeds() -> dict[str, bytes]:
    seeds = {"default.bin": force_net.encode_weights(force_net.default_weights())}
    for kernel, width, blocks in ((1, 1, 0), (2, 3, 1), (8, 8, 2), (5, 16, 0)):
        seeds[f"k{kernel}_w{width}_b{blocks}.bin"] = force_net.encode_weights(
            small_network(kernel, width, blocks, seed=kernel * 100 + width * 10 + blocks))
    good = seeds["k2_w3_b1.bin"]
    seeds["truncated.bin"] = good[:-17]
    seeds["trailing.bin"] = good + b"\0" * 8
    seeds["bad_magic.bin"] = b"FORCENEX" + good[8:]
    seeds["version2.bin"] = good[:8] + struct.pack("<I", 2) + good[12:]
    seeds["nan_scale.bin"] = good[:32] + struct.pack("<d", float("nan")) + good[40:]
    seeds["huge_width.bin"] = good[:20] + struct.pack("<I", 0xFFFFFFFF) + good[24:]
    seeds["header_only.bin"] = good[:64]
    for name, location in (("uri_triple_slash", "file:///opt/fmu/resources/"), ("uri_localhost", "file://localhost/a%20b/res"),
                           ("uri_one_slash", "file:/x/resources"), ("uri_remote_host", "file://server/share/"),
                           ("uri_bad_escape", "file:///a%2"), ("native_path", "/tmp/fmu/resources"),
                           ("empty", ""), ("long", "file:///" + "d/" * 2100)):
        seeds[f"{name}.txt"] = location.encode()
    return seeds


# ---- FMI call programs (the byte language of fuzz_fmi.c: an opcode byte, then its arguments) ----

(INSTANTIATE, ENTER_INIT, EXIT_INIT, SET_REAL, GET_REAL, SET_INT, GET_INT, SET_BOOL, GET_BOOL, SET_STRING,
 GET_STRING, DO_STEP, RUN, GET_STATE, SET_STATE, FREE_STATE, SERIALIZE, RESET, TERMINATE, DEBUG_LOGGING,
 UNSUPPORTED, STATUS, FREE_ALL, NULL_INSTANCE) = range(24)

MID = bytes([16, 128])      # pick_value: inside the bounds, half way
LOW = bytes([16, 0])        # pick_value: the lower bound
ZERO = bytes([5, 0])        # pick_value: 0.0
NAN_ = bytes([0, 0])        # pick_value: NaN
HUGE = bytes([3, 0])        # pick_value: DBL_MAX
PAST = bytes([10, 0])       # pick_value: just above the upper bound


def instantiate(variant: int = 0, which: int = 8, text: bytes = b"") -> bytes:
    extra = bytes([len(text)]) + text if which in (2, 4) else b""
    return bytes([variant, which]) + extra


def enter(start: bytes = ZERO, stop: bytes = bytes([16, 255]), stop_defined: int = 0, setup: int = 1) -> bytes:
    return bytes([ENTER_INIT]) + start + stop + bytes([stop_defined, setup])


def run(steps: int = 64, exponent: int = 0) -> bytes:
    return bytes([RUN, steps - 1, exponent])


def set_real(pairs: list[tuple[int, bytes]], mode: int = 0) -> bytes:
    return bytes([SET_REAL, len(pairs), mode]) + b"".join(bytes([vr]) + value for vr, value in pairs)


def get_real(vrs: list[int]) -> bytes:
    return bytes([GET_REAL, len(vrs)]) + bytes(vrs)


def serialize(source: int, target: int, damage: int = 0, where: int = 0) -> bytes:
    return bytes([SERIALIZE, source, target, damage]) + struct.pack(">I", where)


def set_string(vr: int, case: int, text: bytes = b"") -> bytes:
    extra = bytes([len(text)]) + text if case in (4, 5) else b""
    return bytes([SET_STRING, 1, case, vr]) + extra


PROGRAM = b"G21 G90 G17\nG1 X1 Y0 F600\nG2 X2 Y1 I0 J1\nG1 X0 Y0\nM30\n"


def fmi_seeds() -> dict[str, bytes]:
    init = enter() + bytes([EXIT_INIT])
    seeds = {
        "lifecycle": instantiate() + init + run() + run() + get_real([0]) + bytes([TERMINATE, RESET])
                     + init + run(32, 2) + bytes([FREE_ALL]),
        "states": instantiate() + init + run(10) + bytes([GET_STATE, 0]) + run(20) + bytes([GET_STATE, 1])
                  + bytes([SET_STATE, 0]) + serialize(0, 2) + bytes([SET_STATE, 2]) + serialize(1, 1)
                  + bytes([SET_STATE, 1, FREE_STATE, 0]) + run(5) + serialize(1, 2, 5, 1234) + bytes([SET_STATE, 2]),
        "damaged_states": instantiate() + init + run(3) + bytes([GET_STATE, 0]) + serialize(0, 1, 1)
                          + bytes([RESET, GET_STATE, 0]) + serialize(0, 1, 66, 40) + bytes([SET_STATE, 0]),
        "wrong_order": instantiate() + bytes([DO_STEP, 3, 9, EXIT_INIT, TERMINATE, RESET]) + init
                       + bytes([ENTER_INIT]) + ZERO + ZERO + bytes([0, 0]) + bytes([GET_STATE, 0, RESET, SET_STATE, 0]),
        "bad_values": instantiate() + set_real([(k, NAN_) for k in range(1, 6)]) + bytes([RESET])
                      + set_real([(k, HUGE) for k in range(1, 6)]) + bytes([RESET]) + set_real([(3, PAST)])
                      + bytes([RESET]) + init + bytes([DO_STEP, 3, 1, DO_STEP, 0, 2, DO_STEP, 1, 9]),
        "experiments": instantiate() + enter(NAN_) + bytes([RESET]) + enter(ZERO, bytes([14, 0]), 1)
                       + bytes([RESET]) + enter(HUGE, MID, 0) + bytes([EXIT_INIT]) + bytes([DO_STEP, 3, 4])
                       + bytes([RESET]) + enter(ZERO, bytes([16, 1]), 1) + bytes([EXIT_INIT]) + run(64, 0),
        "types": instantiate() + bytes([SET_INT, 2, 0, 1, 100, 2, 45, GET_INT, 1, 0, 1, SET_BOOL, 2, 0, 1, 1, 2, 0])
                 + init + bytes([GET_BOOL, 3, 0, 1, 2, 3, GET_STRING, 2, 0, 1, 0, 2]) + run(8),
        "strings": instantiate() + set_string(1, 4, PROGRAM) + init + run(64, 1) + set_string(2, 5, b"x" * 40)
                   + set_string(1, 0) + bytes([RESET]) + set_string(1, 2) + init,
        "logging": instantiate(2) + bytes([DEBUG_LOGGING, 2, 1, 0, 3, DEBUG_LOGGING, 1, 1, 4]) + init
                   + bytes([UNSUPPORTED, 0, RESET, UNSUPPORTED, 1, STATUS, NULL_INSTANCE]),
        "instantiation": b"".join(bytes([INSTANTIATE]) + instantiate(v, w, b"file:///tmp/x%20y/" if w == 2 else b"{0}")
                                  for v in range(4) for w in range(12))[1:] + init,
    }
    for offset in range(0, 40, 8):  # every variable set mid-range, then a simulation
        seeds[f"set_mid_{offset}"] = instantiate() + set_real([(k, MID) for k in range(offset, offset + 6)]) + init \
            + run(64, 1) + set_real([(k, LOW) for k in range(offset, offset + 6)]) + run(16, 1)
    return seeds


def write(folder: Path, seeds: dict[str, bytes]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("seed_*"):
        old.unlink()
    for name, data in seeds.items():
        (folder / f"seed_{name}").write_bytes(data)
    print(f"{folder.relative_to(REPO)}: {len(seeds)} seeds")


def main() -> None:
    write(CORPUS / "forcenet", forcenet_seeds())
    write(CORPUS / "fmi", fmi_seeds())


if __name__ == "__main__":
    main()

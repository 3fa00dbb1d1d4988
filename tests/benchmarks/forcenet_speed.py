"""One full evaluation of the tool by the force net: the FMU's C code against torch on the CPU.

    .venv/bin/python tests/benchmarks/forcenet_speed.py [--evaluations 20000] [--weights FILE]

C: fmus/forcenet/forcenet.c, the FMU's source, compiled with the FMU's flags (-std=c99 -O2 -g, the build type
RelWithDebInfo, no -march) into fmus/forcenet/tools/forcenet_run.c, which times ``forcenet_tool`` (all flutes:
the elements in contact found, the network on them, forces and moments summed) one call at a time over angles
spread across a revolution; the median is reported. Twice: as the FMU runs (the matrix products' kernel picked
by the CPU: AVX2 where available) and with the x86-64 baseline kernel forced (-DFORCENET_KERNEL=1, what a CPU
without AVX2 runs); both give bit-identical forces (the checksums printed). Torch (the ``train`` extra; single
thread, as it trains): the same network (BatchNorm folded, eval mode, no autograd) on the same batch of elements
in contact, float32 and float64, network alone and network plus projection and sum, median of single calls.
Cases: the slot-milling scenario (25 mm, 2 flutes, 30 deg helix, 3 mm deep, full slot: 16 elements in contact)
and a deeper 4-flute slot (32). The machine is shared: each C timing is the best of ``--rounds`` medians,
rounds alternating between the builds, torch in the same run; compare ratios.
"""
from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
FORCENET = REPO / "fmus" / "forcenet"
C_FLAGS = ["-std=c99", "-O2", "-g", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-Wconversion", "-Wno-sign-conversion"]
CASES = {  # name -> (n_flutes, diameter m, helix rad, omega rad/s, feed m/s, depth m, entry, exit)
    "slot milling scenario (2 flutes, 25 mm, ap 3 mm)": (2, 0.025, math.radians(30), 6000 * math.pi / 30, 0.015,
                                                         0.003, 0.0, math.pi),
    "4 flutes, 10 mm, ap 10 mm, full slot": (4, 0.010, math.radians(30), 10000 * math.pi / 30, 0.04, 0.010, 0.0,
                                             math.pi),
}


def compile_driver(folder: Path, kernel: int = 0) -> Path:
    """The driver; ``kernel`` 0: picked by the CPU (as in the FMU), 1: the x86-64 baseline forced."""
    out = folder / f"forcenet_run_{kernel}"
    compiler = shutil.which("cc") or "gcc"
    subprocess.run([compiler, *C_FLAGS, f"-DFORCENET_KERNEL={kernel}", "-I", str(FORCENET),
                    str(FORCENET / "tools" / "forcenet_run.c"), str(FORCENET / "forcenet.c"), "-o", str(out), "-lm"],
                   check=True)
    return out


def c_benchmark(driver: Path, weights: Path, case: tuple, evaluations: int) -> dict:
    n, d, helix, omega, feed, ap, entry, exit_ = case
    args = [str(driver), "bench", str(weights), str(n), repr(d), repr(helix), repr(omega), repr(feed), repr(ap),
            repr(entry), repr(exit_), str(evaluations)]
    words = subprocess.run(args, check=True, capture_output=True, text=True).stdout.split()
    values = dict(zip(words[::2], map(float, words[1::2])))
    return {"median_us": values["median_ns"] / 1e3, "min_us": values["min_ns"] / 1e3, "elements": values["elements"],
            "checksum": values["checksum"]}


def best_of(driver: Path, weights: Path, case: tuple, evaluations: int, rounds: int, other: Path) -> tuple[dict, dict]:
    """(driver, other): the run with the lowest median of ``rounds`` each, alternating."""
    runs: dict[Path, list[dict]] = {driver: [], other: []}
    for _ in range(rounds):
        for d in (driver, other):
            runs[d].append(c_benchmark(d, weights, case, evaluations))
    return tuple(min(runs[d], key=lambda r: r["median_us"]) for d in (driver, other))


def torch_benchmark(weights, case: tuple, calls: int) -> dict:
    import torch

    from milling_twin.models import force_net as fn
    from milling_twin.training import force_net as fnt

    torch.set_num_threads(1)
    n, d, helix, omega, feed, ap, entry, exit_ = case
    values = {"n_flutes": np.array([float(n)]), "tool_diameter": np.array([d]), "helix_angle": np.array([helix]),
              "spindle_speed": np.array([omega]), "feed_velocity_x": np.array([feed]), "feed_velocity_y": np.zeros(1),
              "axial_depth": np.array([ap]), "entry_angle": np.array([entry]), "exit_angle": np.array([exit_])}
    arrays = fn.element_arrays(values, np.array([1.0]))
    result = {"elements": int(arrays["mask"].sum())}
    for dtype in (torch.float32, torch.float64):
        net = fnt.network_for(weights, dtype)
        features, project, sample, samples = fnt._tensors(arrays, net)
        for what, call in (("network", lambda: net(features)),
                           ("tool", lambda: fnt.tool_forces(net, features, project, sample, samples))):
            times = []
            with torch.no_grad():
                for _ in range(calls):
                    start = time.perf_counter_ns()
                    call()
                    times.append(time.perf_counter_ns() - start)
            result[f"{what}_{str(dtype).removeprefix('torch.')}_median_us"] = float(np.median(times)) / 1e3
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--evaluations", type=int, default=20000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--weights", type=Path, default=FORCENET / "resources" / "weights.bin")
    args = parser.parse_args()
    from milling_twin.models import force_net as fn

    weights = fn.read_weights(args.weights)
    avx2 = "avx2" in Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").is_file() else False
    print(f"network K = {weights.kernel}, W = {weights.width}, B = {weights.blocks} ({args.weights}); "
          f"the FMU's kernel here: {'AVX2' if avx2 else 'baseline'}")
    with tempfile.TemporaryDirectory() as tmp:
        driver, baseline = compile_driver(Path(tmp)), compile_driver(Path(tmp), kernel=1)
        for name, case in CASES.items():
            c, b = best_of(driver, args.weights, case, args.evaluations, args.rounds, baseline)
            assert c["checksum"] == b["checksum"], "the kernels disagree"
            line = (f"{name}: {c['elements']:.0f} elements in contact; C {c['median_us']:.1f} us median "
                    f"(min {c['min_us']:.1f}), baseline kernel {b['median_us']:.1f} us")
            try:
                t = torch_benchmark(weights, case, max(200, args.evaluations // 20))
                line += (f"; torch float32 {t['tool_float32_median_us']:.0f} us (network alone "
                         f"{t['network_float32_median_us']:.0f}), float64 {t['tool_float64_median_us']:.0f} us "
                         f"(network {t['network_float64_median_us']:.0f}); torch float32 / C "
                         f"{t['tool_float32_median_us'] / c['median_us']:.1f}x, / baseline "
                         f"{t['tool_float32_median_us'] / b['median_us']:.1f}x")
            except ImportError:
                line += "; torch not installed (the 'train' extra)"
            print(line)


if __name__ == "__main__":
    main()

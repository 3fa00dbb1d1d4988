"""Benchmark of the interpolator on part programs of 10^4..10^6 lines: the time to initialise (parse, build the
path, plan the first look-ahead window), the time to stream the program (every interpolation period, with the
window's re-plans), the longest single engine call and the peak memory. A script, not a timed test:

    .venv/bin/python tests/benchmarks/interpolator_large_programs.py [--lines 1000000] [--until 600]
        [--lookahead 1000] [--kinds finishing zigzag staircase]

Programs (generated, deterministic):
- finishing: a 3D finishing raster over a free-form surface z(x, y) (two crossed sines): rows along X 0.2 mm
  apart, boustrophedon, G1 moves of 0.05-0.5 mm (lengths from a fixed pseudo-random sequence) at F3000;
- zigzag: sharp corners only: X alternating 0 and 1 mm, Y advancing 0.05 mm per move, at F1200 (every corner a
  near reversal: the path slows to the junction speed at each);
- staircase: right-angle corners only, 1 mm steps in X and Y in turn, at F1200 (the hardest of these for the
  whole-program plan: 4.6 s at 8,000 lines).

Runs the standalone driver build/tools/interp_run (the FMU's C engine) with --timing; --until stops the stream
after that many seconds of machine time (the real-time factor is machine time over the stream's wall time).
Peak memory: the driver's own peak resident set (VmHWM, Linux; getrusage would count the image of the process that
started it, before exec). Then the same program through the FMI 3 FMU in fmpy, in a Python process of its own
(--fmu, default build/fmus/Interpolator.fmu; --fmu '' skips it): exitInitializationMode's time, doStep of 1 s of
machine time to --until, and the process's peak, Python and fmpy included (their own peak before the FMU is
instantiated is printed beside it).
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from milling_twin.models.interpolator.definition import LOOKAHEAD_BLOCKS

REPO = Path(__file__).resolve().parents[2]
DRIVER = Path(os.environ.get("MILLING_TWIN_INTERP_RUN", REPO / "build" / "tools" / "interp_run"))
HEADER = "G21 G90 G17 G54\nS6000 M3\nG0 X0 Y0 Z5\n"


def surface(x: float, y: float) -> float:
    """The free-form surface of the finishing program, mm."""
    return 2.0 * math.sin(x / 7.0) * math.cos(y / 11.0) + 0.5 * math.sin(x / 2.3 + y / 3.1)


def finishing_program(lines: int, width: float = 100.0, stepover: float = 0.2) -> str:
    """A raster finishing program of `lines` lines (header and end included) over `surface`."""
    out = [HEADER, f"G1 Z{surface(0.0, 0.0):.4f} F3000\n"]
    count = 4
    x, y, forward, seed = 0.0, 0.0, True, 0.0
    while count < lines - 2:
        seed = (seed * 9301.0 + 49297.0) % 233280.0
        step = 0.05 + 0.45 * seed / 233280.0
        end = width if forward else 0.0
        if (end - x) * (1.0 if forward else -1.0) <= step:
            x = end
            out.append(f"X{x:.4f} Z{surface(x, y):.4f}\n")
            y += stepover
            out.append(f"Y{y:.4f} Z{surface(x, y):.4f}\n")
            count += 2
            forward = not forward
            continue
        x += step if forward else -step
        out.append(f"X{x:.4f} Z{surface(x, y):.4f}\n")
        count += 1
    out.append("G0 Z5\nM30\n")
    return "".join(out)


def zigzag_program(lines: int) -> str:
    """A program of `lines` lines whose moves all end in a sharp corner (a near reversal)."""
    out = [HEADER, "G1 Z0 F1200\n"]
    out += [f"X{(k % 2):d} Y{0.05 * (k + 1):.4f}\n" for k in range(lines - 6)]
    out.append("G0 Z5\nM30\n")
    return "".join(out)


def staircase_program(lines: int) -> str:
    """A program of `lines` lines whose moves all end in a right-angle corner (1 mm steps in X and Y in turn)."""
    out = [HEADER, "G1 Z0 F1200\n"]
    out += [f"X{(k + 1) // 2} Y{k // 2}\n" for k in range(1, lines - 5)]
    out.append("G0 Z5\nM30\n")
    return "".join(out)


PROGRAMS = {"finishing": finishing_program, "zigzag": zigzag_program, "staircase": staircase_program}


@dataclass
class Measured:
    kind: str
    lines: int
    moves: int
    parse_and_path: float
    heap: float
    first_plan: float
    machine_time: float
    stream: float
    longest_tick: float
    peak_mb: float

    @property
    def initialisation(self) -> float:
        return self.parse_and_path + self.heap + self.first_plan


def run_driver(program: Path, lookahead: int, until: float) -> str:
    """interp_run --timing on `program`: its output."""
    command = [str(DRIVER), "--timing", "--param", f"lookahead_blocks={lookahead}"]
    if until > 0:
        command += ["--until", str(until)]
    done = subprocess.run(command + [str(program)], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{program}: interp_run failed ({done.returncode}): {done.stderr.strip()}")
    return done.stdout


def parse_output(kind: str, lines: int, stdout: str) -> Measured:
    first, second = stdout.splitlines()[:2]
    f, s = first.split(), second.split()
    return Measured(kind, lines, int(f[1]), float(s[2]), float(s[5]), float(s[8]), float(f[8]), float(s[11]),
                    float(s[14]), float(s[17]))


@dataclass
class MeasuredFmu:
    python_mb: float
    peak_mb: float
    initialisation: float
    real_time: float


def fmu_child(fmu: str, program: str, until: float) -> None:
    """In a process of its own: the FMU through fmpy on `program`, printing what MeasuredFmu holds."""
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave

    def peak() -> float:
        with open("/proc/self/status") as status:
            return next(float(line.split()[1]) / 1024.0 for line in status if line.startswith("VmHWM:"))

    description = read_model_description(fmu)
    refs = {v.name: v.valueReference for v in description.modelVariables}
    before = peak()
    slave = FMU3Slave(guid=description.guid, unzipDirectory=extract(fmu), instanceName="large_program",
                      modelIdentifier=description.coSimulation.modelIdentifier)
    slave.instantiate()
    slave.enterInitializationMode()
    slave.setString([refs["program"]], [program])
    start = time.perf_counter()
    slave.exitInitializationMode()
    initialised = time.perf_counter()
    t = 0.0
    while t < until:
        slave.doStep(t, 1.0)
        t += 1.0
    streamed = time.perf_counter()
    print(before, peak(), initialised - start, until / max(streamed - initialised, 1e-9))
    slave.terminate()
    slave.freeInstance()


def measure_fmu(fmu: Path, program: Path, until: float) -> MeasuredFmu:
    done = subprocess.run([sys.executable, __file__, "--fmu-child", str(fmu), str(program), str(until)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{program}: the FMU run failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return MeasuredFmu(*(float(x) for x in done.stdout.split()))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--lines", type=int, nargs="+", default=[1_000_000])
    parser.add_argument("--kinds", nargs="+", choices=sorted(PROGRAMS), default=sorted(PROGRAMS))
    parser.add_argument("--lookahead", type=int, default=LOOKAHEAD_BLOCKS)
    parser.add_argument("--until", type=float, default=600.0,
                        help="machine seconds to stream (0: the whole program)")
    parser.add_argument("--fmu", default=str(REPO / "build" / "fmus" / "Interpolator.fmu"),
                        help="the FMI 3 Interpolator run through fmpy on each program too ('': not)")
    parser.add_argument("--fmu-child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.fmu_child:
        fmu_child(args.fmu_child[0], args.fmu_child[1], float(args.fmu_child[2]))
        return 0
    if not DRIVER.exists():
        raise SystemExit(f"{DRIVER}: not built (cmake --build build)")
    print(f"{'program':>10} {'lines':>9} {'init s':>7} {'(parse+path':>11} {'heap':>6} {'plan)':>6} "
          f"{'machine s':>10} {'stream s':>9} {'x real':>7} {'longest call s':>14} {'peak MB':>8}"
          + ("  | FMU in fmpy: init s, x real, peak MB (Python's own)" if args.fmu else ""))
    with tempfile.TemporaryDirectory() as tmp:
        for lines in args.lines:
            for kind in args.kinds:
                start = time.perf_counter()
                program = Path(tmp) / f"{kind}_{lines}.nc"
                program.write_text(PROGRAMS[kind](lines))
                m = parse_output(kind, lines, run_driver(program, args.lookahead, args.until))
                longest = max(m.longest_tick, m.first_plan)
                line = (f"{kind:>10} {lines:>9} {m.initialisation:>7.2f} {m.parse_and_path:>11.2f} {m.heap:>6.2f} "
                        f"{m.first_plan:>6.2f} {m.machine_time:>10.1f} {m.stream:>9.2f} "
                        f"{m.machine_time / max(m.stream, 1e-9):>7.0f} {longest:>14.3f} {m.peak_mb:>8.0f}")
                if args.fmu:
                    # the FMU takes the lookahead_blocks default; the driver's --lookahead is for the engine alone
                    f = measure_fmu(Path(args.fmu), program, args.until or m.machine_time)
                    line += f"  | {f.initialisation:.2f} {f.real_time:.0f} {f.peak_mb:.0f} ({f.python_mb:.0f})"
                program.unlink()
                print(line + f"   ({time.perf_counter() - start:.0f} s with generation)", flush=True)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())

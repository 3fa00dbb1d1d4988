"""Synthetic recordings made by the FMUs with known parameters, plus noise: the ground truth of the
recovery tests and benchmarks, and the bundled hammer-impulse recording.

* :func:`truth_outputs`: run a prepared calibration's scenario with the true parameter values (the
  FMUs, through the orchestrator) and return the fitted outputs at the recorded sample times.
* :func:`with_channels`: a copy of a recording with some channels replaced (noisy truth).
* :func:`write_power_case`: a small SpindlePower + MrrEstimator scenario on generated inputs that vary
  speed and material removal rate enough to identify all five power parameters, with its spec.
* ``python -m cases.calibration_synthetic slot [FILE]`` regenerates
  ``scenarios/calibration/data/slot_milling_synthetic.csv``: the forces on the tool (Fx, Fy, Fz, N, 10 kHz)
  that the CuttingForce FMU gives in the slot of ``scenarios/slot_milling.toml`` (900 mm/min) with the
  coefficients :data:`SLOT_TRUTH`, plus Gaussian noise of :data:`SLOT_NOISE` N (seed 11): the data of the
  generic spec ``slot_forces_synthetic.toml``, which fits the coefficients through the FMU.
* ``python -m cases.calibration_synthetic impulse [FILE]`` regenerates
  ``scenarios/calibration/data/impulse_hammer.csv``: a half-sine hammer impulse on the tool tip in x
  and the tip acceleration the ToolVibration FMU gives for a 850 Hz, 2 % damping, 1.0e6 N/m mode
  (the FMU's defaults are 922 Hz, 1.1 %, 1.34e6 N/m), with Gaussian noise of 1 % of the peak
  acceleration (seed 7).
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.recorded import RecordedData
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Scenario, load_scenario, with_values

__all__ = ["IMPULSE_TRUTH", "POWER_TRUTH", "SLOT_TRUTH", "TWO_FMU_CASE", "edited", "impulse_force",
           "load_scenario_without_data", "truth_outputs", "with_channels",
           "write_impulse_recording", "write_power_case", "write_slot_recording"]

REPO = Path(__file__).resolve().parents[2]
IMPULSE_FILE = REPO / "scenarios" / "calibration" / "data" / "impulse_hammer.csv"
IMPULSE_SCENARIO = REPO / "scenarios" / "calibration" / "impulse_vibration.toml"
IMPULSE_TRUTH = {"vib.frequency_x1": 850.0, "vib.damping_x1": 0.02, "vib.stiffness_x1": 1.0e6}
IMPULSE_NOISE = 0.01  # of the peak acceleration
IMPULSE_SEED = 7


def truth_outputs(scenario: Scenario, truth: Mapping[str, float], outputs: list[str], times: np.ndarray,
                  out_dir: Path) -> np.ndarray:
    """The scenario's FMUs with ``truth`` (SI, "instance.variable"): outputs at ``times`` (linear
    between rows; exact where the times are rows), times x outputs."""
    case = with_values(scenario, dict(truth), name=f"{scenario.name}_truth")
    result = run(case, out_dir, progress=False)
    rows = load_results(result.run_dir)
    t = rows["time"].to_numpy(dtype=float)
    return np.column_stack([np.interp(times, t, rows[o].to_numpy(dtype=float)) for o in outputs])


def with_channels(recorded: RecordedData, channels: Mapping[str, np.ndarray]) -> RecordedData:
    """A copy of ``recorded`` with channels replaced (SI values, same units)."""
    return RecordedData(recorded.path, recorded.time, {**recorded.channels, **channels}, dict(recorded.units))


def impulse_force(t: np.ndarray, peak: float = 200.0, duration: float = 1e-4, start: float = 1e-4) -> np.ndarray:
    """A half-sine hammer pulse (N)."""
    inside = (t >= start) & (t <= start + duration)
    return np.where(inside, peak * np.sin(math.pi * (t - start) / duration), 0.0)


def _write(path: Path, t: np.ndarray, force: np.ndarray, acceleration: np.ndarray) -> None:
    lines = ["time,force_x,acceleration_x"] + [f"{a:.5f},{b:.6g},{c:.6g}" for a, b, c in zip(t, force, acceleration)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_impulse_recording(path: Path = IMPULSE_FILE, fmu_dir: Path = REPO / "build" / "fmus",
                            duration: float = 0.03, step: float = 1e-5) -> Path:
    """Make the hammer-impulse recording with the ToolVibration FMU (see the module text)."""
    t = np.round(np.arange(round(duration / step) + 1) * step, 10)
    force = impulse_force(t)
    with tempfile.TemporaryDirectory() as tmp:
        draft = Path(tmp) / "data" / path.name
        _write(draft, t, force, np.zeros_like(t))
        (Path(tmp) / IMPULSE_SCENARIO.name).write_text(IMPULSE_SCENARIO.read_text(encoding="utf-8"), encoding="utf-8")
        scenario = load_scenario(Path(tmp) / IMPULSE_SCENARIO.name, fmu_dir)
        clean = truth_outputs(scenario, IMPULSE_TRUTH, ["vib.tip_acceleration_x"], t, Path(tmp) / "runs")[:, 0]
    noise = np.random.default_rng(IMPULSE_SEED).normal(0.0, IMPULSE_NOISE * np.max(np.abs(clean)), t.size)
    _write(path, t, force, clean + noise)
    return path


SLOT_FILE = REPO / "scenarios" / "calibration" / "data" / "slot_milling_synthetic.csv"
SLOT_SCENARIO = REPO / "scenarios" / "calibration" / "slot_milling_synthetic.toml"
SLOT_TRUTH = {"force.Ktc": 900e6, "force.Krc": 300e6, "force.Kac": 150e6,  # N/m2
              "force.Kte": 20e3, "force.Kre": 30e3, "force.Kae": 5e3}  # N/m
SLOT_NOISE = 5.0  # N
SLOT_SEED = 11
SLOT_CHANNELS = {"fx": "force.Fx", "fy": "force.Fy", "fz": "force.Fz"}


def _write_columns(path: Path, t: np.ndarray, columns: Mapping[str, np.ndarray]) -> None:
    lines = [",".join(["time", *columns])] + [
        ",".join([f"{a:.6f}", *(f"{v[i]:.9g}" for v in columns.values())]) for i, a in enumerate(t)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_slot_recording(path: Path = SLOT_FILE, fmu_dir: Path = REPO / "build" / "fmus", noise: float = SLOT_NOISE,
                         seed: int | None = SLOT_SEED, scenario_file: Path = SLOT_SCENARIO) -> Path:
    """Make the synthetic slot-milling force recording of ``scenario_file`` (see the module text); ``seed``
    None: noise-free."""
    text = scenario_file.read_text(encoding="utf-8")
    with tempfile.TemporaryDirectory() as tmp:
        draft_scenario = Path(tmp) / scenario_file.name
        draft_scenario.write_text(text, encoding="utf-8")
        scenario = load_scenario_without_data(draft_scenario, fmu_dir, Path(tmp))
        t = np.round(np.arange(round((scenario.stop_time - scenario.start_time) / scenario.output_interval) + 1)
                     * scenario.output_interval + scenario.start_time, 10)
        clean = truth_outputs(scenario, SLOT_TRUTH, list(SLOT_CHANNELS.values()), t, Path(tmp) / "runs")
    rng = np.random.default_rng(seed)
    noisy = clean + (rng.normal(0.0, noise, clean.shape) if seed is not None else 0.0)
    _write_columns(path, t, {c.capitalize(): noisy[:, k] for k, c in enumerate(SLOT_CHANNELS)})
    return path


def load_scenario_without_data(scenario_file: Path, fmu_dir: Path, folder: Path) -> Scenario:
    """Load a scenario whose [recorded] file does not exist yet: a zero recording on the scenario's output grid is
    written where it points (in ``folder``, a copy of the scenario file lying there)."""
    import tomllib
    doc = tomllib.loads(scenario_file.read_text(encoding="utf-8"))
    sc, rec = doc["scenario"], doc["recorded"]
    t = np.arange(round((sc["stop_time"] - sc.get("start_time", 0.0)) / sc["output_interval"]) + 1) \
        * sc["output_interval"] + sc.get("start_time", 0.0)
    columns = {ch["column"]: np.zeros_like(t) for ch in rec["channels"].values()}
    _write_columns(folder / rec["file"], t, columns)
    return load_scenario(scenario_file, fmu_dir)


POWER_TRUTH = {"power.P_standby": 350.0, "power.P_idle": 120.0, "power.c1": 0.8, "power.c2": 1500.0, "power.c3": 0.85}

# SpindlePower + MrrEstimator on a recording of speed, feeds, process and power: the tests' two-FMU case
# (tests/conftest.py, CASE_TOML; "power" is listed before "mrr" on purpose: the execution order must still be
# mrr, power) and, edited, the synthetic power calibration case (POWER_SCENARIO).
TWO_FMU_CASE = """\
[scenario]
name = "case"
output_interval = 0.1

[fmus.power]
fmu = "SpindlePower"
fmi = 3
step_size = 0.1
[fmus.power.parameters]
P_standby = 100.0
P_idle = { value = 0.2, unit = "kW" }
c1 = 0.5
c2 = 1000.0
c3 = 1.0

[fmus.mrr]
fmu = "MrrEstimator"
fmi = 3
step_size = 0.1
[fmus.mrr.parameters]
width_of_cut = { value = 5.0, unit = "mm" }
depth_of_cut = { value = 2.0, unit = "mm" }

[recorded]
file = "data.csv"
sample_period = 0.1
[recorded.channels]
speed = { column = "speed", unit = "rev/s" }
spindle_on = { column = "speed", unit = "rev/s", above = 1.0 }
vx = { column = "vx", unit = "mm/s" }
vy = { column = "vy", unit = "mm/s" }
cutting = { column = "process", match = "^Layer" }
power = { column = "power", unit = "kW" }

[[inputs]]
from = "speed"
to = "power.spindle_speed"
interpolation = "hold"

[[inputs]]
from = "spindle_on"
to = "power.spindle_on"

[[inputs]]
from = "vx"
to = "mrr.feed_velocity_x"

[[inputs]]
from = "vy"
to = "mrr.feed_velocity_y"

[[inputs]]
from = "cutting"
to = "mrr.cutting"

[[connections]]
from = "mrr.mrr"
to = "power.mrr"
delay = false

[outputs]
record = ["power.P_total", "mrr.mrr", "power.spindle_on"]

[[compare]]
simulated = "power.P_total"
recorded = "power"
"""


def edited(text: str, *edits: tuple[str, str]) -> str:
    """``text`` with (old, new) replacements, each of which must apply."""
    for old, new in edits:
        if old not in text:
            raise ValueError(f"edit does not apply: {old!r}")
        text = text.replace(old, new, 1)
    return text


POWER_SCENARIO = edited(
    TWO_FMU_CASE, ('name = "case"', 'name = "power_case"'),
    ('P_standby = 100.0\nP_idle = { value = 0.2, unit = "kW" }\nc1 = 0.5', 'P_standby = 200.0\nP_idle = 300.0\nc1 = 0.3'),
    ('file = "data.csv"', 'file = "power_case.csv"'), ('match = "^Layer"', 'match = "^cut"'),
    ('interpolation = "hold"\n', ""),
    ('record = ["power.P_total", "mrr.mrr", "power.spindle_on"]\n\n[[compare]]\nsimulated = "power.P_total"\n'
     'recorded = "power"\n', 'record = ["power.P_total"]\n'))

POWER_SPEC = """\
[calibration]
name = "power_case"
description = "synthetic power case"
scenario = "power_case.toml"
parameter_set = "power_case.params.toml"

[parameters."power.P_standby"]
min = 0.0
max = 2000.0
[parameters."power.P_idle"]
min = 0.0
max = 2000.0
[parameters."power.c1"]
min = 0.0
max = 10.0
[parameters."power.c2"]
min = 0.0
max = 20000.0
[parameters."power.c3"]
min = 0.2
max = 2.0

[[outputs]]
simulated = "power.P_total"
recorded = "power"
unit = "W"

[segments]
learning = [[0.0, 29.95]]
validation = [[30.0, 40.0]]

[inputs."power.mrr"]
floor = 1e-300

[solver]
starts = 3
"""


def write_power_case(folder: Path, rows: int = 400, fmu_dir: Path | None = None, noise: float = 5.0,
                     seed: int = 0, steady_from: int | None = None) -> Path:
    """Scenario, recording and spec of a synthetic power case in ``folder``; returns the spec's path. Speed
    steps 0 .. 60 rev/s, feeds 2 .. 40 mm/s. The recorded power is 0, or with ``fmu_dir`` what the FMUs give
    for :data:`POWER_TRUTH` plus Gaussian noise of ``noise`` W (``seed``). ``steady_from``: from this row on
    (290: the last second of learning and the validation window) the spindle turns at 30 rev/s cutting at
    1 mm/s along x, the feed varying by 1e-9 mm/s, so that the simulated power is constant to 1e-10 relative
    (figures of constant values)."""
    folder.mkdir(parents=True, exist_ok=True)
    k = np.arange(rows)
    speed = np.where(k < 20, 0.0, 5.0 + 55.0 * ((k // 25) % 6) / 5)
    feed = np.where((k % 50) < 35, 2.0 + 38.0 * ((k * 7) % 23) / 22, 0.0)
    angle = 0.05 * k
    steady = k >= (steady_from if steady_from is not None else rows)
    if steady_from is not None:
        speed = np.where(steady, 30.0, speed)
        feed = np.where(steady, 1.0 + 1e-9 * (k % 3), feed)
        angle = np.where(steady, 0.0, angle)
    cutting = (feed > 0) & (speed > 1)
    lines = ["speed,vx,vy,process,power"] + [
        f"{s:.6g},{f * math.cos(a):{'.12g' if d else '.6g'}},{f * math.sin(a):.6g},{'cut' if c else 'move'},0"
        for s, f, a, c, d in zip(speed, feed, angle, cutting, steady)]
    (folder / "power_case.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (folder / "power_case.toml").write_text(POWER_SCENARIO, encoding="utf-8")
    (folder / "power_case_spec.toml").write_text(POWER_SPEC, encoding="utf-8")
    if fmu_dir is not None:
        scenario = load_scenario(folder / "power_case.toml", fmu_dir)
        t = scenario.recorded.time
        clean = truth_outputs(scenario, POWER_TRUTH, ["power.P_total"], t, folder / "truth")[:, 0]
        power = clean + np.random.default_rng(seed).normal(0.0, noise, t.size)
        lines = lines[:1] + [line.rsplit(",", 1)[0] + f",{p / 1000:.9g}" for line, p in zip(lines[1:], power)]
        (folder / "power_case.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder / "power_case_spec.toml"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cases.calibration_synthetic", description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("impulse", "slot"))
    parser.add_argument("file", nargs="?", type=Path, default=None)
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus")
    args = parser.parse_args(argv)
    if args.what == "slot":
        print(write_slot_recording(args.file or SLOT_FILE, args.fmu_dir))
    else:
        print(write_impulse_recording(args.file or IMPULSE_FILE, args.fmu_dir))
    return 0


if __name__ == "__main__":
    sys.exit(main())

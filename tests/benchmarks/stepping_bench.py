"""Co-simulation stepping speed: a plain C driver, the orchestrator's fast and Python paths, an fmpy loop.

    .venv/bin/python tests/benchmarks/stepping_bench.py [--repeat 3] [--fmi 2] [--no-sweep] [--only CASE ...]

For each case the same FMUs are stepped with the same connections, recorded inputs and recorded
outputs four ways, in this process and run, best of --repeat. Wall times are end to end, each way
with its own setup and its own result writing; what each includes:

1. C driver: ``build/stepper/stepping_driver`` (tests/benchmarks/stepping_driver.c), a plain C
   master doing the same FMI calls as the orchestrator: the native limit. Its wall time runs from
   the start of its main() to its end: reading its configuration and the recorded inputs, dlopen
   of the FMU binaries, instantiation, start values, initialization, stepping, writing all rows
   (time and the recorded outputs, raw float64) to its result file with the guarantee the
   orchestrator gives its final run.json (temporary file, fsync, rename, fsync of the folder),
   freeing the instances and closing the libraries. It excludes the process start (about 1 ms)
   and unzipping the FMUs, which this script does once beforehand.
2. fast: ``milling_twin.orchestrator.master.run(stepping="fast")``, the compiled stepping loop; the wall time
   around run(): hashing the files for run.json, finding the unpacked FMUs (orchestrator.fmu_cache:
   unzipped by the first run of each FMU, reused by the next ones, as the C driver reuses its
   folders), loading them with fmpy (orchestrator.fmu_loading), setup, stepping (recorded inputs
   sampled in C), the Parquet chunks and run.json (the final one fsynced with its folder). Not
   included: importing the orchestrator (a command-line run adds about 0.15 s of imports, and
   pyarrow, about 0.35 s, when the first chunk is written).
3. python: ``run(stepping="python")``, the reference Python loop, the same way.
4. fmpy loop: a Python loop on fmpy's FMU2Slave (FMU3Slave with --fmi 3) convenience calls
   (setReal/doStep/getReal), recorded inputs precomputed with numpy, results saved with numpy and
   fsynced; unzipping (fmpy.extract, each run) and instantiation included.

Every path's results are compared with the fast path's, bit for bit ("identical" column).

Cases (each at least 10 s of simulated time):

* chatter: scenarios/chatter.toml (CuttingForce + ToolVibration, 10 us step, every step recorded)
  run for 10 s instead of 0.2 s;
* chatter+workpiece: the same plus the Workpiece FMU on the same 10 us grid, cutting a straight
  slot: the tool position comes from a recorded (two-sample, linearly interpolated) path at the
  chatter scenario's feed, 600 mm/min, 0.03 mm below the stock's top, entering the stock from
  outside; the workpiece's axial depth and entry/exit angles feed the force FMU;
* chatter+workpiece 100us: the same with the Workpiece stepped every 100 us (multi-rate; force and
  vibration stay at 10 us): the tool moves 1 um per workpiece step, 1/250 of a 0.25 mm Z-map cell,
  and the force FMU holds the engagement for 10 of its steps. The script reports how far its forces
  are from the 10 us case (max and RMS difference, relative to the largest force);
* umich_power: scenarios/umich_power.toml (recorded inputs, MrrEstimator 10 ms + SpindlePower
  1 ms, 105.4 s);
* umich_motion: scenarios/umich_motion.toml (the Interpolator running the part program
  reconstructed from UMich run 01, 10 ms steps, 105 s, its Int32 line and block numbers recorded).
* sweep (unless --no-sweep): 1, 2, 4, 8 trivial FMUs (SpindlePower, MrrEstimator -> SpindlePower
  pairs) at 1, 10 and 100 kHz for 10 s, outputs every 1 ms: how the ratios move with the number of
  FMUs and the step rate. The two Python paths are skipped where they would take over --slow-cap
  FMU steps.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from fmpy import extract
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from milling_twin.orchestrator.master import run  # noqa: E402
from milling_twin.orchestrator.results import load_results  # noqa: E402
from milling_twin.orchestrator.scenario import Scenario, load_scenario  # noqa: E402

PATHS = ("C driver", "fast", "python", "fmpy loop")
# A case whose native run is this short (s) is repeated at least SHORT_REPEAT times: a few ms of disk or
# scheduling latency on a shared machine would otherwise decide its ratios.
SHORT_RUN, SHORT_REPEAT = 0.05, 15


# ---- cases ----


def _edit(text: str, old: str, new: str) -> str:
    assert old in text, f"edit does not apply: {old!r}"
    return text.replace(old, new, 1)


def _with_fmi(text: str, fmi: int) -> str:
    return re.sub(r'^(fmu = "[A-Za-z]+")$', rf"\1\nfmi = {fmi}", text, flags=re.M)


def chatter_toml(fmi: int, stop: float, workpiece: bool, step: str = "1e-5", workpiece_step: str = "") -> str:
    """The chatter scenario for ``stop`` s; with ``workpiece``, the Workpiece FMU (every ``workpiece_step``
    s, default ``step``) gives the force FMU its engagement."""
    text = (REPO / "scenarios" / "chatter.toml").read_text()
    text = _with_fmi(text, fmi)
    text = _edit(text, "stop_time = 0.2", f"stop_time = {stop!r}")
    text = text.replace("step_size = 1e-5", f"step_size = {step}").replace(
        "output_interval = 1e-5", f"output_interval = {step}")
    if not workpiece:
        return text
    text = _edit(text, 'name = "chatter"', f'name = "chatter_workpiece{"_" + workpiece_step if workpiece_step else ""}"')
    for line in ('axial_depth = { value = 0.03, unit = "mm" }\n', "entry_angle = 0.0 ",
                 'exit_angle = { value = 180.0, unit = "deg" }\n'):
        start = text.index(line)
        text = text[:start] + text[text.index("\n", start) + 1:]
    block = f'''[fmus.workpiece]
fmu = "Workpiece"
fmi = {fmi}
step_size = {workpiece_step or step}
[fmus.workpiece.parameters]
helix_angle = 0.0
flute_count = 2
[fmus.workpiece.inputs]
tool_y = {{ value = 30.0, unit = "mm" }}          # the middle of the 60 mm wide stock
tool_z = {{ value = 29.97, unit = "mm" }}         # 0.03 mm below its top: the chatter depth
spindle_speed = {{ value = 6000.0, unit = "rpm" }}

'''
    text = _edit(text, "[fmus.force]\n", block + "[fmus.force]\n")
    text = _edit(text, "[[connections]]\n", f'''[recorded]
file = "tool_path.csv"
time_column = "t"
[recorded.channels]
tool_x = {{ column = "x", unit = "mm" }}

[[inputs]]
from = "tool_x"
to = "workpiece.tool_x"

[[connections]]
from = "workpiece.axial_depth"
to = "force.axial_depth"

[[connections]]
from = "workpiece.entry_angle"
to = "force.entry_angle"

[[connections]]
from = "workpiece.exit_angle"
to = "force.exit_angle"

[[connections]]
''')
    return _edit(text, 'record = ["force.Fx"', 'record = ["workpiece.mrr", "force.Fx"')


def tool_path_csv(stop: float) -> str:
    # 600 mm/min = 10 mm/s along +x, from the tool's edge touching the stock (x = -5 mm)
    return f"t,x\n0,-5\n{stop!r},{-5 + 10 * stop!r}\n"


def umich_toml(fmi: int, name: str) -> str:
    """scenarios/<name>.toml with its files (recorded data, { path = ... } parameters) made absolute."""
    text = _with_fmi((REPO / "scenarios" / f"{name}.toml").read_text(), fmi)
    absolute = lambda m: f'{m.group(1)}"{(REPO / "scenarios" / m.group(2)).as_posix()}"'  # noqa: E731
    text = re.sub(r'^(file = )"(.*)"$', absolute, text, flags=re.M)
    return re.sub(r'(\{ path = )"([^"]*)"', absolute, text)


def pairs_toml(fmi: int, n_fmus: int, step: float, stop: float) -> str:
    """``n_fmus`` trivial FMUs: SpindlePower alone (1) or MrrEstimator -> SpindlePower pairs."""
    out_interval = max(step, 1e-3)
    parts = [f'[scenario]\nname = "sweep_{n_fmus}_{round(1 / step)}"\nstop_time = {stop!r}\n'
             f"output_interval = {out_interval!r}\n"]
    record = []
    for i in range(max(1, n_fmus // 2)):
        if n_fmus > 1:
            parts.append(f'''[fmus.mrr{i}]
fmu = "MrrEstimator"
fmi = {fmi}
step_size = {step!r}
[fmus.mrr{i}.parameters]
width_of_cut = {{ value = 3.0, unit = "mm" }}
depth_of_cut = {{ value = 1.0, unit = "mm" }}
[fmus.mrr{i}.inputs]
feed_velocity_x = {{ value = {600 + i}.0, unit = "mm/min" }}
''')
            record.append(f'"mrr{i}.mrr"')
        parts.append(f'''[fmus.power{i}]
fmu = "SpindlePower"
fmi = {fmi}
step_size = {step!r}
[fmus.power{i}.inputs]
spindle_speed = {{ value = 6000.0, unit = "rpm" }}
''')
        record.append(f'"power{i}.P_total"')
        if n_fmus > 1:
            parts.append(f'[[connections]]\nfrom = "mrr{i}.mrr"\nto = "power{i}.mrr"\n')
    parts.append(f"[outputs]\nrecord = [{', '.join(record)}]\n")
    return "\n".join(parts)


# ---- the four ways ----


def _library(folder: str, inst: Any) -> str:
    platform = "x86_64-linux" if inst.fmi_version == 3 else "linux64"
    return os.path.join(folder, "binaries", platform, inst.model_identifier + ".so")


def _resource(folder: str, inst: Any) -> str:
    res = os.path.join(folder, "resources")
    return Path(res).as_uri() if inst.fmi_version == 2 else res + os.path.sep


def _kind(scenario: Scenario, ref: Any) -> str:
    return scenario.variable(ref).type  # real, bool or int (Int32: recorded outputs only)


def _n_ticks(scenario: Scenario) -> int:
    return int(np.floor((scenario.stop_time - scenario.start_time) / scenario.output_interval + 1e-9)
               * scenario.ticks_per_output)


def c_driver(driver: Path, scenario: Scenario, work: Path, folders: dict[Path, str]) -> tuple[float, float, np.ndarray]:
    """(wall time in the driver, loop time, rows); FMUs already extracted in ``folders``."""
    index = {inst.name: i for i, inst in enumerate(scenario.instances)}
    lines = [f"grid {scenario.start_time!r} {scenario.base_step!r} {_n_ticks(scenario)} "
             f"{scenario.ticks_per_output}"]
    rec = scenario.recorded
    channels = list(dict.fromkeys(i.channel for i in scenario.inputs))
    if channels:
        table = np.column_stack([rec.time] + [rec.channels[c].astype(np.float64) for c in channels])
        table.tofile(work / "recorded.bin")
        lines.append(f"recorded {work / 'recorded.bin'} {table.shape[0]} {len(channels)}")
    for inst in scenario.instances:
        folder = folders[inst.path]
        lines.append(f"instance {inst.name} {inst.fmi_version} {inst.ticks_per_step} {_library(folder, inst)} "
                     f"{inst.instantiation_token} {_resource(folder, inst)}")
    for inst in scenario.instances:
        for name, value in {**inst.parameters, **inst.inputs}.items():
            var = inst.variables[name]
            text = (repr(float(value)) if var.type == "real" else value if var.type == "string"
                    else str(int(value)))
            lines.append(f"start {index[inst.name]} {var.type} {var.value_reference} {text}")
    for i in scenario.inputs:  # recorded first, then connections, as the orchestrator orders inputs
        var = scenario.variable(i.target)
        mode = "hold" if rec.channels[i.channel].dtype == np.bool_ else i.interpolation
        lines.append(f"input {index[i.target.instance]} {_kind(scenario, i.target)} {var.value_reference} "
                     f"{channels.index(i.channel)} {mode} {i.factor!r}")
    for c in scenario.connections:
        lines.append(f"link {index[c.target.instance]} {_kind(scenario, c.target)} "
                     f"{scenario.variable(c.target).value_reference} {index[c.source.instance]} "
                     f"{scenario.variable(c.source).value_reference} {int(c.delay)} {c.factor!r}")
    for r in scenario.outputs:
        lines.append(f"record {index[r.instance]} {_kind(scenario, r)} {scenario.variable(r).value_reference}")
    lines.append(f"output {work / 'c_rows.bin'}")
    config = work / "driver.cfg"
    config.write_text("\n".join(lines) + "\n")
    proc = subprocess.run([str(driver), str(config)], capture_output=True, text=True, check=True)
    fields = dict(item.split("=") for item in proc.stdout.split())
    rows = np.fromfile(work / "c_rows.bin", dtype=np.float64).reshape(-1, 1 + len(scenario.outputs))
    return float(fields["wall_s"]), float(fields["loop_s"]), rows


def orchestrator(scenario: Scenario, out: Path, stepping: str) -> tuple[float, float, np.ndarray]:
    t0 = time.perf_counter()
    result = run(scenario, out, progress=False, stepping=stepping)
    wall = time.perf_counter() - t0
    assert result.status == "completed" and result.stepping == stepping, result
    return wall, result.loop_wall_time, load_results(result.run_dir).to_numpy(dtype=np.float64)


def fmpy_loop(scenario: Scenario, out: Path) -> tuple[float, float, np.ndarray]:
    """A straightforward Python master on fmpy's convenience calls, same semantics."""
    t0 = time.perf_counter()
    start, base, n_ticks, tpo = scenario.start_time, scenario.base_step, _n_ticks(scenario), scenario.ticks_per_output
    rec = scenario.recorded
    slaves, folders = [], []
    for inst in scenario.instances:
        folder = extract(str(inst.path))
        folders.append(folder)
        cls = FMU3Slave if inst.fmi_version == 3 else FMU2Slave
        fmu = cls(guid=inst.instantiation_token, unzipDirectory=folder, modelIdentifier=inst.model_identifier,
                  instanceName=inst.name)
        fmu.instantiate()
        fmi3 = inst.fmi_version == 3
        set_real, get_real = (fmu.setFloat64, fmu.getFloat64) if fmi3 else (fmu.setReal, fmu.getReal)
        values = {**inst.parameters, **inst.inputs}
        for kind, setter in (("real", set_real), ("int", fmu.setInt32 if fmi3 else fmu.setInteger),
                             ("bool", fmu.setBoolean), ("string", fmu.setString)):
            names = [n for n in values if inst.variables[n].type == kind]
            if names:
                setter([inst.variables[n].value_reference for n in names], [values[n] for n in names])
        vr = lambda names: [inst.variables[n].value_reference for n in names]  # noqa: E731
        rec_real = [i for i in scenario.inputs if i.target.instance == inst.name and _kind(scenario, i.target) == "real"]
        rec_bool = [i for i in scenario.inputs if i.target.instance == inst.name and _kind(scenario, i.target) == "bool"]
        conn_real = [c for c in scenario.connections if c.target.instance == inst.name and _kind(scenario, c.target) == "real"]
        conn_bool = [c for c in scenario.connections if c.target.instance == inst.name and _kind(scenario, c.target) == "bool"]
        wanted = list(dict.fromkeys([c.source.variable for c in scenario.connections if c.source.instance == inst.name]
                                    + [r.variable for r in scenario.outputs if r.instance == inst.name]))
        real_out = [n for n in wanted if inst.variables[n].type == "real"]
        bool_out = [n for n in wanted if inst.variables[n].type == "bool"]
        int_out = [n for n in wanted if inst.variables[n].type == "int"]
        slaves.append(dict(
            name=inst.name, fmu=fmu, m=inst.ticks_per_step, fmi3=fmi3, set_real=set_real, get_real=get_real,
            vr_real_in=vr([x.target.variable for x in rec_real + conn_real]),
            vr_bool_in=vr([x.target.variable for x in rec_bool + conn_bool]),
            vr_real_out=vr(real_out), vr_bool_out=vr(bool_out), vr_int_out=vr(int_out),
            get_int=fmu.getInt32 if fmi3 else fmu.getInteger, int_index={n: j for j, n in enumerate(int_out)},
            out_int=[0] * len(int_out), rec_real=rec_real, rec_bool=rec_bool,
            conn_real=conn_real, conn_bool=conn_bool, real_index={n: j for j, n in enumerate(real_out)},
            bool_index={n: j for j, n in enumerate(bool_out)}, out_real=[0.0] * len(real_out),
            out_bool=[False] * len(bool_out), prev_real=[0.0] * len(real_out), prev_bool=[False] * len(bool_out), feeds=any(c.source.instance == inst.name for c in scenario.connections),
            has_outputs=bool(wanted)))
    by_name = {s["name"]: s for s in slaves}
    for s in slaves:  # connection sources: (slave, kind, index, delay, factor)
        s["links_real"] = [(by_name[c.source.instance], by_name[c.source.instance]["real_index"][c.source.variable],
                            c.delay, c.factor) for c in s["conn_real"]]
        s["links_bool"] = [(by_name[c.source.instance], by_name[c.source.instance]["bool_index"][c.source.variable],
                            c.delay) for c in s["conn_bool"]]

    def sampled(s: dict, times: np.ndarray) -> tuple[list, list]:
        real = [rec.at(i.channel, times, i.interpolation) * i.factor for i in s["rec_real"]]
        boolean = [rec.at(i.channel, times, "hold") for i in s["rec_bool"]]
        return (np.column_stack(real).tolist() if real else [[] for _ in times],
                np.column_stack(boolean).tolist() if boolean else [[] for _ in times])

    def feed(s: dict, rr: list, rb: list) -> None:
        reals = rr + [(src["prev_real"] if d else src["out_real"])[j] * f for src, j, d, f in s["links_real"]]
        bools = rb + [(src["prev_bool"] if d else src["out_bool"])[j] for src, j, d in s["links_bool"]]
        if reals:
            s["set_real"](s["vr_real_in"], reals)
        if bools:
            s["fmu"].setBoolean(s["vr_bool_in"], bools)

    def get(s: dict) -> None:
        if s["vr_real_out"]:
            s["out_real"] = s["get_real"](s["vr_real_out"])
        if s["vr_bool_out"]:
            s["out_bool"] = s["fmu"].getBoolean(s["vr_bool_out"])
        if s["vr_int_out"]:
            s["out_int"] = s["get_int"](s["vr_int_out"])

    for s in slaves:
        if s["fmi3"]:
            s["fmu"].enterInitializationMode(startTime=start)
        else:
            s["fmu"].setupExperiment(startTime=start)
            s["fmu"].enterInitializationMode()
    for s in slaves:
        rr, rb = sampled(s, np.array([start]))
        feed(s, rr[0], rb[0])
        get(s)
    for s in slaves:
        s["fmu"].exitInitializationMode()
        get(s)
        s["prev_real"], s["prev_bool"] = list(s["out_real"]), list(s["out_bool"])
    columns = [(by_name[r.instance], f"out_{_kind(scenario, r)}", by_name[r.instance][f"{_kind(scenario, r)}_index"][r.variable])
               for r in scenario.outputs]
    delayed = [by_name[n] for n in dict.fromkeys(c.source.instance for c in scenario.connections if c.delay)]
    recorders = [s for s in slaves if s["has_outputs"]]
    for s in slaves:  # recorded inputs for the whole run, at the ticks where the instance is due
        s["rows_real"], s["rows_bool"] = sampled(s, start + np.arange(0, n_ticks, s["m"]) * base)
    rows = [[start] + [float(src[key][j]) for src, key, j in columns]]
    t_loop = time.perf_counter()
    for k in range(n_ticks):
        t = start + k * base
        for s in delayed:
            s["prev_real"], s["prev_bool"] = list(s["out_real"]), list(s["out_bool"])
        for s in slaves:
            m = s["m"]
            if k % m:
                continue
            feed(s, s["rows_real"][k // m], s["rows_bool"][k // m])
            s["fmu"].doStep(t, start + min(k + m, n_ticks) * base - t)
            if s["feeds"]:
                get(s)
        if (k + 1) % tpo == 0:
            for s in recorders:
                get(s)
            rows.append([start + (k + 1) * base] + [float(src[key][j]) for src, key, j in columns])
    loop = time.perf_counter() - t_loop
    array = np.array(rows, dtype=np.float64)
    with open(out / "fmpy_rows.npy", "wb") as fh:
        np.save(fh, array)
        fh.flush()
        os.fsync(fh.fileno())
    for s, folder in zip(slaves, folders):
        s["fmu"].terminate()
        s["fmu"].freeInstance()
        shutil.rmtree(folder, ignore_errors=True)
    return time.perf_counter() - t0, loop, array


# ---- measuring ----


@dataclasses.dataclass
class Measured:
    wall: float = float("inf")
    loop: float = float("inf")
    identical: bool | None = None
    skipped: bool = False
    runs: int = 0
    rows: np.ndarray | None = None  # kept for the fast path (the reference)


def measure(name: str, scenario: Scenario, driver: Path, repeat: int, slow_cap: float, work: Path,
            folders: dict[Path, str], paths: tuple[str, ...] = PATHS) -> dict[str, Measured]:
    n_ticks = _n_ticks(scenario)
    fmu_steps = sum(-(-n_ticks // inst.ticks_per_step) for inst in scenario.instances)
    results = {p: Measured() for p in PATHS}
    for inst in scenario.instances:
        if inst.path not in folders:
            folders[inst.path] = extract(str(inst.path))
    reference = None
    rep = 0
    while rep < repeat:
        for path in PATHS:
            if path not in paths or (path in ("python", "fmpy loop") and fmu_steps > slow_cap):
                results[path].skipped = True
                continue
            out = work / f"{path.replace(' ', '_')}_{rep}"  # fresh: no stale chunks to remove
            out.mkdir()
            if path == "C driver":
                wall, loop, rows = c_driver(driver, scenario, out, folders)
            elif path == "fmpy loop":
                wall, loop, rows = fmpy_loop(scenario, out)
            else:
                wall, loop, rows = orchestrator(scenario, out, path)
            if path == "fast":
                reference = rows
            m = results[path]
            m.wall, m.loop, m.runs = min(m.wall, wall), min(m.loop, loop), m.runs + 1
            m.rows = rows
            shutil.rmtree(out)
        if rep == 0 and results["C driver"].wall < SHORT_RUN:
            repeat = max(repeat, SHORT_REPEAT)
        rep += 1
    for path in PATHS:
        m = results[path]
        if not m.skipped:
            m.identical = m.rows.shape == reference.shape and np.array_equal(m.rows.view(np.uint64),
                                                                            reference.view(np.uint64))
            if path != "fast":
                m.rows = None
    return results


def multi_rate_effect(fine: np.ndarray, coarse: np.ndarray, scenario: Scenario) -> str:
    """How far the forces of the multi-rate case (``coarse``) are from those of the all-10-us case."""
    names = [str(r) for r in scenario.outputs]
    parts = []
    for name in ("force.Fx", "force.Fy"):
        j = 1 + names.index(name)
        a, b = fine[:, j], coarse[:, j]
        scale = np.abs(a).max()
        parts.append(f"{name}: max |difference| {np.abs(b - a).max() / scale:.2e}, RMS difference "
                     f"{np.sqrt(np.mean((b - a) ** 2)) / scale:.2e} of the largest |{name}| ({scale:.4g} N)")
    return "  multi-rate effect (workpiece every 100 us vs 10 us): " + "; ".join(parts)


def report(name: str, scenario: Scenario, results: dict[str, Measured]) -> str:
    n_ticks = _n_ticks(scenario)
    simulated = n_ticks * scenario.base_step
    fmu_steps = sum(-(-n_ticks // inst.ticks_per_step) for inst in scenario.instances)
    c = results["C driver"].wall
    lines = [f"{name}: {len(scenario.instances)} FMUs ({', '.join(i.model_identifier for i in scenario.instances)}), "
             f"base step {scenario.base_step:g} s, {simulated:g} s simulated, {n_ticks:,} ticks, "
             f"{fmu_steps:,} doSteps, {len(scenario.outputs)} outputs x "
             f"{n_ticks // scenario.ticks_per_output + 1:,} rows; best of {results['fast'].runs}",
             f"  {'path':<10} {'wall [s]':>9} {'loop [s]':>9} {'/ C':>7} {'/ fast':>7} {'RTF':>9} "
             f"{'us/doStep':>10} identical"]
    for path in PATHS:
        m = results[path]
        if m.skipped:
            lines.append(f"  {path:<10} {'skipped':>9}")
            continue
        lines.append(f"  {path:<10} {m.wall:9.3f} {m.loop:9.3f} {m.wall / c:7.2f} "
                     f"{m.wall / results['fast'].wall:7.2f} {simulated / m.wall:9.3g} "
                     f"{m.loop / fmu_steps * 1e6:10.3f} {'yes' if m.identical else 'NO'}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3,
                        help=f"best of this many runs per path (default 3; at least {SHORT_REPEAT} where the C driver "
                             f"takes under {SHORT_RUN * 1e3:g} ms)")
    parser.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of all FMUs (default 2)")
    parser.add_argument("--stop", type=float, default=10.0, help="simulated seconds of the chatter cases")
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus")
    parser.add_argument("--driver", type=Path, default=REPO / "build" / "stepper" / "stepping_driver")
    parser.add_argument("--no-sweep", action="store_true", help="skip the FMU-count / step-rate sweep")
    parser.add_argument("--slow-cap", type=float, default=3e6,
                        help="skip the python and fmpy paths in sweep cases with more doSteps (default 3e6)")
    parser.add_argument("--only", nargs="*", help="run only these cases (chatter, chatter+workpiece, umich, sweep)")
    parser.add_argument("--paths", nargs="*", default=list(PATHS[2:]), choices=PATHS[2:],
                        help="which Python paths to measure besides the C driver and the fast path")
    args = parser.parse_args()
    if not args.driver.is_file():
        sys.exit(f"{args.driver} not found: build it with cmake --build build")
    print(f"stepping benchmark, FMI {args.fmi}, best of {args.repeat}, {os.cpu_count()} CPUs; "
          f"RTF = simulated s per wall s; '/ C' etc.: wall-time ratios; us/doStep: loop time per FMU step",
          flush=True)
    folders: dict[Path, str] = {}
    summary = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        cases: list[tuple[str, str, str, float]] = []  # (name, toml, extra file, slow cap)
        wanted = set(args.only) if args.only else {"chatter", "chatter+workpiece", "umich", "sweep"}
        if "chatter" in wanted:
            cases.append(("chatter", chatter_toml(args.fmi, args.stop, False), "", float("inf")))
        if "chatter+workpiece" in wanted:
            cases.append(("chatter+workpiece", chatter_toml(args.fmi, args.stop, True), tool_path_csv(args.stop),
                          float("inf")))
            cases.append(("chatter+workpiece 100us", chatter_toml(args.fmi, args.stop, True, workpiece_step="1e-4"),
                          tool_path_csv(args.stop), float("inf")))
        if "umich" in wanted:
            cases.append(("umich_power", umich_toml(args.fmi, "umich_power"), "", float("inf")))
            cases.append(("umich_motion", umich_toml(args.fmi, "umich_motion"), "", float("inf")))
        if "sweep" in wanted and not args.no_sweep:
            for n_fmus in (1, 2, 4, 8):
                for rate in (1_000, 10_000, 100_000):
                    cases.append((f"sweep {n_fmus} FMUs {rate // 1000} kHz",
                                  pairs_toml(args.fmi, n_fmus, 1.0 / rate, 10.0), "", args.slow_cap))
        for name, toml, extra, cap in cases:
            case_dir = work / re.sub(r"[^A-Za-z0-9]+", "_", name)
            case_dir.mkdir()
            if extra:
                (case_dir / "tool_path.csv").write_text(extra)
            (case_dir / "case.toml").write_text(toml)
            scenario = load_scenario(case_dir / "case.toml", args.fmu_dir)
            results = measure(name, scenario, args.driver, args.repeat, cap, case_dir, folders,
                              PATHS[:2] + tuple(args.paths))
            text = report(name, scenario, results)
            if name == "chatter+workpiece 100us" and summary and summary[-1][0] == "chatter+workpiece":
                text += "\n" + multi_rate_effect(summary[-1][2]["fast"].rows, results["fast"].rows, scenario)
            print(text, flush=True)
            summary.append((name, scenario, results))
        for folder in folders.values():
            shutil.rmtree(folder, ignore_errors=True)
    print("\nsummary (wall-time ratios end to end; RTF of the fast path):")
    print(f"  {'case':<24} {'fast/C':>7} {'python/C':>9} {'fmpy/C':>7} {'fmpy/fast':>9} {'RTF C':>8} {'RTF fast':>9}")
    for name, scenario, r in summary:
        simulated = _n_ticks(scenario) * scenario.base_step
        c, f = r["C driver"].wall, r["fast"].wall
        py = f"{r['python'].wall / c:9.1f}" if not r["python"].skipped else f"{'-':>9}"
        fm = f"{r['fmpy loop'].wall / c:7.1f}" if not r["fmpy loop"].skipped else f"{'-':>7}"
        ff = f"{r['fmpy loop'].wall / f:9.1f}" if not r["fmpy loop"].skipped else f"{'-':>9}"
        print(f"  {name:<24} {f / c:7.2f} {py} {fm} {ff} {simulated / c:8.3g} {simulated / f:9.3g}")


if __name__ == "__main__":
    main()

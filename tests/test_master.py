"""The co-simulation master against hand-computed values of the two-FMU case (see conftest).

By hand: P_total = P_standby + on * (P_idle + c1*|w|) + on * c2 * (mrr / 1 cm3/s)^c3 with
P_standby = 100 W, P_idle = 200 W, c1 = 0.5 W.s/rad, c2 = 1000 W, c3 = 1, and
mrr = cutting * 5 mm * 2 mm * |v_xy|. Samples (speed rev/s, |v| mm/s, cutting):
0: (0, 0, no), 1: (10, 5, yes), 2: (20, 10, yes), 3: (20, 10, no), 4: (0, 0, no);
so mrr per sample is 0, 5e-8, 1e-7, 0, 0 m3/s and the cutting term 0, 50, 100, 0, 0 W.
"""
from __future__ import annotations

import math
import os
import signal

import numpy as np
import pytest

from milling_twin.orchestrator.master import SimulationError, run
from milling_twin.orchestrator.results import load_results, read_run_info
from milling_twin.orchestrator.scenario import load_scenario

PI = math.pi


def check(frame, column, expected):
    np.testing.assert_allclose(frame[column].to_numpy(dtype=float), expected, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("fmi", [3, 2])
def test_two_fmus_hand_computed(make_case, fmu_dir, tmp_path, fmi):
    edit = ("fmi = 3", f"fmi = {fmi}")
    scenario = load_scenario(make_case(edit, edit), fmu_dir)
    result = run(scenario, tmp_path / "runs", progress=False)
    assert result.status == "completed"
    assert (result.steps, result.fmu_steps, result.rows) == (4, 8, 5)
    frame = load_results(result.run_dir)
    assert list(frame.columns) == ["time", "power.P_total", "mrr.mrr", "power.spindle_on"]
    check(frame, "time", [0.0, 0.1, 0.2, 0.3, 0.4])
    # Row 0: after initialization with sample 0. Row k >= 1: after the step from t - 0.1,
    # whose inputs are sample k-1; mrr (first in the order) feeds power in the same step.
    check(frame, "mrr.mrr", [0.0, 0.0, 5e-8, 1e-7, 0.0])
    check(frame, "power.P_total", [100.0, 100.0, 300 + 0.5 * 2 * PI * 10 + 50,
                                   300 + 0.5 * 2 * PI * 20 + 100, 300 + 0.5 * 2 * PI * 20])
    assert frame["power.spindle_on"].dtype == bool
    assert frame["power.spindle_on"].tolist() == [False, False, True, True, True]
    info = read_run_info(result.run_dir)
    assert info["status"] == "completed" and info["rows_written"] == 5
    assert info["execution_order"] == ["mrr", "power"]
    assert {f["instance"]: f["fmi_version"] for f in info["fmus"]} == {"mrr": fmi, "power": fmi}
    assert all(len(f["sha256"]) == 64 and f["instantiation_token"].startswith("{") for f in info["fmus"])


@pytest.mark.parametrize("mrr_first", [False, True])
def test_delayed_connection(make_case, fmu_dir, tmp_path, mrr_first):
    path = make_case(("delay = false", "delay = true"))
    if mrr_first:  # the source precedes its target: the value must still be the previous one
        text = path.read_text()
        a, b, c = text.index("[fmus.power]"), text.index("[fmus.mrr]"), text.index("[recorded]")
        path.write_text(text[:a] + text[b:c] + text[a:b] + text[c:])
    scenario = load_scenario(path, fmu_dir)
    assert scenario.execution_order == (("mrr", "power") if mrr_first else ("power", "mrr"))
    frame = load_results(run(scenario, tmp_path / "runs", progress=False).run_dir)
    # power's step from t - 0.1 sees mrr as it was at t - 0.1 (from sample k-2)
    check(frame, "mrr.mrr", [0.0, 0.0, 5e-8, 1e-7, 0.0])
    check(frame, "power.P_total", [100.0, 100.0, 300 + 0.5 * 2 * PI * 10 + 0,
                                   300 + 0.5 * 2 * PI * 20 + 50, 300 + 0.5 * 2 * PI * 20 + 100])


def test_multi_rate_and_linear_interpolation(make_case, fmu_dir, tmp_path):
    path = make_case(("step_size = 0.1", "step_size = 0.05"),  # power: 0.05 s, mrr: 0.1 s
                     ('interpolation = "hold"', 'interpolation = "linear"'),
                     ('record = ["power.P_total",', 'record = ["power.spindle_speed", "power.P_total",'))
    scenario = load_scenario(path, fmu_dir)
    result = run(scenario, tmp_path / "runs", progress=False)
    assert (result.steps, result.fmu_steps) == (8, 8 + 4)
    frame = load_results(result.run_dir)
    check(frame, "time", [0.0, 0.1, 0.2, 0.3, 0.4])
    # Row at t: power's last step started at t - 0.05 with the speed interpolated there and
    # spindle_on (speed above a threshold) switched where the interpolated speed crosses it: on at
    # 0.05 s (5 rev/s), not held off until the next sample; mrr's last step started at t - 0.1.
    check(frame, "power.spindle_speed", [0.0, 2 * PI * 5, 2 * PI * 15, 2 * PI * 20, 2 * PI * 10])
    check(frame, "mrr.mrr", [0.0, 0.0, 5e-8, 1e-7, 0.0])
    check(frame, "power.P_total", [100.0, 300 + 0.5 * 2 * PI * 5, 300 + 0.5 * 2 * PI * 15 + 50,
                                   300 + 0.5 * 2 * PI * 20 + 100, 300 + 0.5 * 2 * PI * 10])


def test_should_stop_interrupts_after_the_current_step(make_case, fmu_dir, tmp_path):
    scenario = load_scenario(make_case(), fmu_dir)
    result = run(scenario, tmp_path / "runs", progress=False, should_stop=lambda t: t > 0.15)
    assert result.status == "interrupted" and result.steps == 2
    assert read_run_info(result.run_dir)["status"] == "interrupted"
    frame = load_results(result.run_dir)
    check(frame, "time", [0.0, 0.1, 0.2])
    check(frame, "power.P_total", [100.0, 100.0, 300 + 0.5 * 2 * PI * 10 + 50])


def test_sigint_interrupts_cleanly(make_case, fmu_dir, tmp_path):
    def ctrl_c(t: float) -> bool:
        if abs(t - 0.1) < 1e-9:
            os.kill(os.getpid(), signal.SIGINT)
        return False

    before = signal.getsignal(signal.SIGINT)
    result = run(load_scenario(make_case(), fmu_dir), tmp_path / "runs", progress=False, should_stop=ctrl_c)
    assert signal.getsignal(signal.SIGINT) is before  # handler restored
    assert result.status == "interrupted" and 1 <= result.steps < 4
    assert read_run_info(result.run_dir)["status"] == "interrupted"
    assert len(load_results(result.run_dir)) == result.steps + 1


@pytest.mark.parametrize("fmi", [3, 2])
def test_failing_fmu_call_keeps_results(make_case, fmu_dir, tmp_path, fmi):
    # 2000 rev/s = 12566 rad/s is beyond the 1e4 rad/s that SpindlePower accepts
    csv = "speed,vx,vy,process,power\n0,0,0,Prep,0\n10,3,4,Prep,0\n2000,0,0,Prep,0\n0,0,0,Prep,0\n"
    edits = [("fmi = 3", f"fmi = {fmi}")] * 2
    scenario = load_scenario(make_case(*edits, csv=csv), fmu_dir)
    with pytest.raises(SimulationError) as info:
        run(scenario, tmp_path / "runs", progress=False)
    err = info.value
    assert (err.instance, err.status) == ("power", "Error") and err.time == pytest.approx(0.2)
    assert "'power'" in str(err) and "t = 0.2" in str(err) and "spindle_speed" in str(err)
    run_dir = tmp_path / "runs" / "case"
    assert read_run_info(run_dir)["status"].startswith(
        f"failed: {'SetFloat64' if fmi == 3 else 'SetReal'} of instance 'power'")
    check(load_results(run_dir), "time", [0.0, 0.1, 0.2])


def test_fmi2_messages_reach_the_instance_that_logged_them(make_case, fmu_dir, tmp_path):
    # fmpy's FMI 2 logger proxy keeps only the logger installed last ('power', instantiated
    # after 'mrr' in execution order): mrr's own rejection message must still be attached.
    csv = "speed,vx,vy,process,power\n0,0,0,Prep,0\n10,20000,0,Prep,0\n0,0,0,Prep,0\n"
    scenario = load_scenario(make_case(*[("fmi = 3", "fmi = 2")] * 2, csv=csv), fmu_dir)
    with pytest.raises(SimulationError) as info:
        run(scenario, tmp_path / "runs", progress=False)
    assert info.value.instance == "mrr"
    assert "fmi2SetReal: variable 'feed_velocity_x' = 20 m/s is out of its allowed range" in str(info.value)


def test_after_a_run_fmpys_default_logger_works_again(make_case, fmu_dir, tmp_path):
    # fmpy's native logger proxy has one process-wide target; the master points it at its own
    # per-run callback, which is gone after the run. An FMI 2 FMU on fmpy's default callbacks that
    # logs afterwards (fmpy.simulate_fmu in the same notebook, say) called freed memory and crashed
    # the process: run it in a child process, so a regression fails here instead of killing pytest.
    import subprocess
    import sys
    import textwrap

    case = make_case(*[("fmi = 3", "fmi = 2")] * 2)
    script = textwrap.dedent(f"""
        import gc
        from fmpy import read_model_description
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi1 import FMICallException
        from milling_twin.orchestrator import fmu_cache
        from milling_twin.orchestrator.master import run
        from milling_twin.orchestrator.results import sha256_of
        from milling_twin.orchestrator.scenario import load_scenario

        run(load_scenario({str(case)!r}, {str(fmu_dir)!r}), {str(tmp_path / "runs")!r}, progress=False)
        gc.collect()
        path = {str(fmu_dir / "SpindlePower_fmi2.fmu")!r}
        folder = fmu_cache.unpack(path, sha256_of(path)).folder
        md = read_model_description(folder)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier)
        fmu.instantiate()  # fmpy's default callbacks: its proxy, then its printLogMessage
        vr = {{v.name: v.valueReference for v in md.modelVariables}}
        try:
            fmu.setReal([vr["spindle_speed"]], [float("nan")])  # the FMU logs an error
        except FMICallException:
            print("raised")
        fmu.freeInstance()
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(fmu_dir.parents[1])})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "raised" in proc.stdout and "spindle_speed" in proc.stdout  # fmpy printed the FMU's message

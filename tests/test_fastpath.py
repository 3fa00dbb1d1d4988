"""The compiled stepping path (orchestrator.fastpath, fmus/stepper/) against the Python reference.

Both paths must give bit-identical results on every scenario; stopping (should_stop, Ctrl-C),
FMU errors and the automatic choice with its fallback are checked on the fast path.
"""
from __future__ import annotations

import dataclasses
import os
import re
import shutil
import signal
import threading
import time

import numpy as np
import pytest

from conftest import LONG_TOML, REPO_ROOT
import fmu_helpers
from fmu_helpers import bits
from milling_twin.orchestrator import fastpath, master
from milling_twin.cli import main
from milling_twin.orchestrator.master import SimulationError, run
from milling_twin.orchestrator.results import load_results, read_run_info
from milling_twin.orchestrator.scenario import load_scenario, with_values

PATHS = ("python", "fast")


@pytest.fixture(autouse=True)
def library(fmu_dir):
    """The stepper library; missing fails the test (the test command builds it)."""
    path, reason = fastpath.find_library(load_scenario(REPO_ROOT / "scenarios" / "chatter.toml", fmu_dir))
    if path is None:
        pytest.fail(f"{reason}; build it with cmake --build {REPO_ROOT / 'build'}")
    return fastpath.load_library(path.resolve())


def run_both(scenario, tmp_path, **kwargs) -> dict:
    """Run ``scenario`` on both paths (whatever its status); returns {path: (RunResult, frame)}."""
    return fmu_helpers.run_both(scenario, tmp_path, must_complete=False, **kwargs)


def assert_identical(both: dict) -> None:
    (rp, fp), (rf, ff) = both["python"], both["fast"]
    assert list(fp.columns) == list(ff.columns) and list(fp.dtypes) == list(ff.dtypes)
    assert fp.shape == ff.shape and len(fp) > 1
    np.testing.assert_array_equal(bits(fp), bits(ff))  # bit for bit, -0.0 and NaN included
    assert (rp.status, rp.steps, rp.fmu_steps, rp.rows, rp.end_time) == \
           (rf.status, rf.steps, rf.fmu_steps, rf.rows, rf.end_time)


# ---- bit-identical results ----


@pytest.mark.parametrize("fmi_mrr, fmi_power", [(3, 3), (2, 2), (2, 3)])
def test_two_fmus_hand_computed_case_identical(make_case, fmu_dir, tmp_path, fmi_mrr, fmi_power):
    # power is listed first in the file: its "fmi = 3" is the first one
    path = make_case(("fmi = 3", f"fmi = {fmi_power}"), ("fmi = 3", f"fmi = {fmi_mrr}"))
    both = run_both(load_scenario(path, fmu_dir), tmp_path)
    assert_identical(both)
    assert both["fast"][1]["power.spindle_on"].tolist() == [False, False, True, True, True]


@pytest.mark.parametrize("mrr_first", [False, True])
def test_delayed_connection_identical(make_case, fmu_dir, tmp_path, mrr_first):
    path = make_case(("delay = false", "delay = true"), ("step_size = 0.1", "step_size = 0.02"),
                     ("output_interval = 0.1", "output_interval = 0.02"))
    if mrr_first:
        text = path.read_text()
        a, b, c = text.index("[fmus.power]"), text.index("[fmus.mrr]"), text.index("[recorded]")
        path.write_text(text[:a] + text[b:c] + text[a:b] + text[c:])
    assert_identical(run_both(load_scenario(path, fmu_dir), tmp_path))


@pytest.mark.parametrize("power_step, mrr_step, interval, m, ticks", [
    (0.001, 0.007, 0.01, 7, 400),  # mrr every 7 ticks: not a divisor of the output interval
    (0.0001, 0.07, 0.1, 700, 4000),  # mrr slower than the first chunks: some chunks hold no mrr step
])
def test_multi_rate_identical(make_case, fmu_dir, tmp_path, power_step, mrr_step, interval, m, ticks):
    path = make_case(("step_size = 0.1", f"step_size = {power_step}"), ("step_size = 0.1", f"step_size = {mrr_step}"),
                     ("output_interval = 0.1", f"output_interval = {interval}"),
                     ('interpolation = "hold"', 'interpolation = "linear"'),
                     ('record = ["power.P_total",', 'record = ["power.spindle_speed", "power.P_total",'))
    scenario = load_scenario(path, fmu_dir)
    assert [i.ticks_per_step for i in scenario.instances] == [m, 1]
    both = run_both(scenario, tmp_path)
    assert_identical(both)
    assert both["fast"][0].steps == ticks and both["fast"][0].fmu_steps == ticks + -(-ticks // m)


def test_umich_power_identical(fmu_dir, tmp_path):
    scenario = load_scenario(REPO_ROOT / "scenarios" / "umich_power.toml", fmu_dir)
    both = run_both(scenario, tmp_path)
    assert_identical(both)
    assert both["fast"][0].steps == 105_400


@pytest.mark.parametrize("fmi", [3, 2])
def test_chatter_identical(fmu_dir, tmp_path, fmi):
    scenario = load_scenario(REPO_ROOT / "scenarios" / "chatter.toml", fmu_dir)
    if fmi == 2:
        text = (REPO_ROOT / "scenarios" / "chatter.toml").read_text()
        path = tmp_path / "chatter2.toml"
        path.write_text(text.replace('fmu = "CuttingForce"', 'fmu = "CuttingForce"\nfmi = 2')
                        .replace('fmu = "ToolVibration"', 'fmu = "ToolVibration"\nfmi = 2'))
        scenario = load_scenario(path, fmu_dir)
    # deep enough to chatter: the displacement feedback (delayed connections) matters
    scenario = dataclasses.replace(with_values(scenario, {"force.axial_depth": {"value": 0.06, "unit": "mm"}}),
                                   stop_time=0.03)
    both = run_both(scenario, tmp_path)
    assert_identical(both)
    assert both["fast"][0].steps == 3000 and np.abs(both["fast"][1]["vibration.tip_displacement_y"]).max() > 0


def test_int32_outputs_recorded_identical(fmu_dir, tmp_path):
    """The Interpolator's Int32 outputs (program line, N word) are recorded as int32 columns, the same on both
    paths, with the values the program has."""
    program = (REPO_ROOT / "scenarios" / "programs" / "umich_01.nc").read_text().splitlines()
    n_words = {int(line.split()[0][1:]) for line in program if line.startswith("N")}
    scenario = dataclasses.replace(load_scenario(REPO_ROOT / "scenarios" / "umich_motion.toml", fmu_dir),
                                   stop_time=30.0)
    assert fastpath.unsupported(scenario) == ""
    both = run_both(scenario, tmp_path)
    assert_identical(both)
    frame = both["fast"][1]
    assert str(frame["interp.line_number"].dtype) == "int32" and str(frame["interp.block_number"].dtype) == "int32"
    lines, blocks = frame["interp.line_number"].to_numpy(), frame["interp.block_number"].to_numpy()
    assert lines[0] == 0 and np.all(np.diff(lines) >= 0) and 10 < lines[-1] <= len(program)
    assert set(blocks[lines > 0]) - {0} <= n_words and len(set(blocks)) > 5
    for r in (result for result, _ in both.values()):
        assert read_run_info(r.run_dir)["int_columns"] == ["interp.line_number", "interp.block_number"]


# ---- stopping ----


@pytest.mark.parametrize("path", PATHS)
def test_should_stop_is_asked_after_every_row(make_case, fmu_dir, tmp_path, path):
    scenario = load_scenario(make_case(("step_size = 0.1", "step_size = 0.01"),
                                       ("step_size = 0.1", "step_size = 0.01")), fmu_dir)
    asked = []
    result = run(scenario, tmp_path / path, progress=False, stepping=path,
                 should_stop=lambda t: asked.append(t) or t > 0.15)
    assert result.stepping == path and result.status == "interrupted"
    assert result.steps == 20 and asked == pytest.approx([0.1, 0.2])
    assert read_run_info(result.run_dir)["status"] == "interrupted"
    np.testing.assert_allclose(load_results(result.run_dir)["time"], [0.0, 0.1, 0.2])


def test_should_stop_exception_is_raised_after_saving_rows(make_case, fmu_dir, tmp_path):
    def boom(t: float) -> bool:
        if t > 0.25:
            raise ValueError("stop here")
        return False

    with pytest.raises(ValueError, match="stop here"):
        run(load_scenario(make_case(), fmu_dir), tmp_path, progress=False, stepping="fast", should_stop=boom)
    assert read_run_info(tmp_path / "case")["status"] == "failed: stop here"
    np.testing.assert_allclose(load_results(tmp_path / "case")["time"], [0.0, 0.1, 0.2, 0.3])


def test_ctrl_c_stops_after_the_current_chunk(fmu_dir, tmp_path, monkeypatch):
    (tmp_path / "long.toml").write_text(LONG_TOML)
    scenario = load_scenario(tmp_path / "long.toml", fmu_dir)
    updates = []

    class Bar:  # stands in for tqdm: records the progress the loop reports
        n = 0

        def __init__(self, **kwargs):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def update(self, k):
            self.n += k
            updates.append(self.n)

    monkeypatch.setattr(master, "tqdm", Bar)
    sent = []
    timer = threading.Timer(0.6, lambda: sent.append(time.perf_counter()) or os.kill(os.getpid(), signal.SIGINT))
    before = signal.getsignal(signal.SIGINT)
    timer.start()
    try:
        result = run(scenario, tmp_path / "runs", progress=True, stepping="fast")
    finally:
        timer.cancel()
    stopped = time.perf_counter()
    assert signal.getsignal(signal.SIGINT) is before
    assert result.stepping == "fast" and result.status == "interrupted"
    assert sent and stopped - sent[0] < 1.0  # within about one chunk (0.1 s)
    assert 0 < result.steps < 100_000_000 and updates[-1] == result.steps
    assert len([u for u in updates if u > 0]) >= 3  # the bar moved during the run, chunk by chunk
    info = read_run_info(result.run_dir)
    assert info["status"] == "interrupted" and info["stepping"]["path"] == "fast"
    frame = load_results(result.run_dir)
    assert len(frame) == result.rows == result.steps // 10 + 1  # every row up to the last tick
    np.testing.assert_allclose(frame["time"].to_numpy(), np.arange(len(frame)) * 0.01, atol=1e-6)
    assert (frame["power.P_total"] == 300.0).all()


# ---- errors ----


@pytest.mark.parametrize("fmi", [3, 2])
def test_fmu_error_mid_chunk_same_on_both_paths(make_case, fmu_dir, tmp_path, fmi):
    # SpindlePower accepts |speed| <= 1e4 rad/s = 1591.5 rev/s; the linear ramp from 10 to 2000 rev/s
    # between t = 0.1 and 0.2 s crosses it at t = 0.18 s, deep inside the first chunk
    csv = "speed,vx,vy,process,power\n0,0,0,Prep,0\n10,3,4,Prep,0\n2000,0,0,Prep,0\n0,0,0,Prep,0\n"
    path = make_case(*[("fmi = 3", f"fmi = {fmi}")] * 2, ("step_size = 0.1", "step_size = 0.001"),
                     ("step_size = 0.1", "step_size = 0.001"), ("output_interval = 0.1", "output_interval = 0.01"),
                     ('interpolation = "hold"', 'interpolation = "linear"'), csv=csv)
    scenario = load_scenario(path, fmu_dir)
    errors, frames = {}, {}
    for p in PATHS:
        with pytest.raises(SimulationError) as info:
            run(scenario, tmp_path / p, progress=False, stepping=p)
        errors[p] = info.value
        frames[p] = load_results(tmp_path / p / "case")
        assert read_run_info(tmp_path / p / "case")["status"].startswith(
            f"failed: {'SetFloat64' if fmi == 3 else 'SetReal'} of instance 'power' at t = 0.18")
    py, fast = errors["python"], errors["fast"]
    assert (fast.instance, fast.time, fast.status, fast.function) == (py.instance, py.time, py.status, py.function)
    assert str(fast) == str(py) and "spindle_speed" in str(fast)
    np.testing.assert_array_equal(bits(frames["fast"]), bits(frames["python"]))
    assert len(frames["fast"]) == 18 + 1  # rows up to t = 0.18 s (the failing step's own start)


# ---- the choice ----


def test_fallback_when_the_library_is_missing(make_case, fmu_dir, tmp_path, monkeypatch):
    scenario = load_scenario(make_case(), fmu_dir)
    monkeypatch.setenv(fastpath.LIBRARY_ENV, str(tmp_path / "nowhere.so"))
    result = run(scenario, tmp_path / "runs", progress=False)
    assert result.status == "completed" and result.stepping == "python"
    assert "nowhere.so: no such file" in result.stepping_reason
    info = read_run_info(result.run_dir)
    assert info["stepping"] == {"path": "python", "library": None, "reason": result.stepping_reason}
    assert len(load_results(result.run_dir)) == 5
    with pytest.raises(fastpath.FastPathUnavailable, match="nowhere.so"):
        run(scenario, tmp_path / "other", progress=False, stepping="fast")
    assert not (tmp_path / "other").exists()  # refused before writing anything
    monkeypatch.setenv(fastpath.LIBRARY_ENV, "off")
    assert fastpath.choose(scenario).reason.startswith("disabled by $MILLING_TWIN_STEPPER")


def test_auto_finds_the_library_beside_the_fmus(make_case, fmu_dir, tmp_path, monkeypatch):
    monkeypatch.delenv(fastpath.LIBRARY_ENV, raising=False)
    scenario = load_scenario(make_case(), fmu_dir)
    choice = fastpath.choose(scenario)
    assert choice.path == "fast" and choice.library.name == fastpath.LIBRARY_NAME
    result = run(scenario, tmp_path / "runs", progress=False)
    assert result.stepping == "fast" and result.stepping_reason == ""
    assert read_run_info(result.run_dir)["stepping"]["library"] == str(choice.library)


def test_unusable_library_falls_back(make_case, fmu_dir, tmp_path, monkeypatch):
    bogus = tmp_path / "libbogus.so"
    bogus.write_bytes(b"not an ELF file")
    monkeypatch.setenv(fastpath.LIBRARY_ENV, str(bogus))
    choice = fastpath.choose(load_scenario(make_case(), fmu_dir))
    assert choice.path == "python" and choice.reason.startswith("stepper library unusable")


@pytest.mark.parametrize("option, expected", [([], "; fast path"), (["--path", "python"], "; python path (requested)")])
def test_cli_path_option_and_summary(make_case, fmu_dir, tmp_path, capsys, option, expected):
    code = main(["run", str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"),
                 "--no-progress", *option])
    out = capsys.readouterr().out
    assert code == 0 and expected in out.splitlines()[0], out


def test_cli_fast_path_unavailable_is_a_clean_error(make_case, fmu_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(fastpath.LIBRARY_ENV, str(tmp_path / "nowhere.so"))
    code = main(["run", str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"),
                 "--no-progress", "--path", "fast"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: the fast path cannot run scenario 'case'") and "nowhere.so" in err


# ---- the benchmark's C driver does the same work ----


# every co-simulation scenario the repository ships (found by their [fmus.*] tables, so a new one is included)
SCENARIO_FILES = sorted(p for p in (REPO_ROOT / "scenarios").rglob("*.toml")
                        if re.search(r"^\[fmus\.", p.read_text(), flags=re.M))


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=lambda p: p.relative_to(REPO_ROOT / "scenarios").as_posix())
def test_every_scenario_is_bit_identical_on_both_paths(fmu_dir, tmp_path, path):
    scenario = load_scenario(path, fmu_dir)
    assert fastpath.unsupported(scenario) == ""  # none falls back to the Python path
    rows = {}
    for stepping in ("fast", "python"):
        result = run(scenario, tmp_path / stepping, progress=False, stepping=stepping)
        assert result.status == "completed" and result.stepping == stepping
        rows[stepping] = load_results(result.run_dir).to_numpy(dtype=np.float64)
    assert rows["fast"].shape == rows["python"].shape and len(rows["fast"]) > 1
    assert np.array_equal(rows["fast"].view(np.uint64), rows["python"].view(np.uint64))


def test_the_scenario_list_is_complete():
    assert len(SCENARIO_FILES) >= 10 and any(p.name == "slot_entry_forcenet.toml" for p in SCENARIO_FILES)


@pytest.mark.parametrize("case", ["chatter+workpiece", "umich_motion"])
def test_benchmark_paths_agree(fmu_dir, tmp_path, case):
    """The stepping benchmark's four ways (C driver, fast, python, fmpy loop) give the same rows
    on short runs of its chatter+workpiece case (recorded input, 3 FMUs, delayed loop) and of
    umich_motion (a String parameter, Int32 outputs)."""
    import sys

    sys.path.insert(0, str(REPO_ROOT / "tests" / "benchmarks"))
    try:
        import stepping_bench as bench
    finally:
        sys.path.pop(0)
    driver = REPO_ROOT / "build" / "stepper" / "stepping_driver"
    assert driver.is_file(), "build it with cmake --build build"
    if case == "umich_motion":
        (tmp_path / "case.toml").write_text(bench.umich_toml(2, "umich_motion"))
        scenario = dataclasses.replace(load_scenario(tmp_path / "case.toml", fmu_dir), stop_time=8.0)
    else:
        (tmp_path / "tool_path.csv").write_text(bench.tool_path_csv(0.02))
        (tmp_path / "case.toml").write_text(bench.chatter_toml(2, 0.02, True))
        scenario = load_scenario(tmp_path / "case.toml", fmu_dir)
    folders: dict = {}
    try:
        results = bench.measure("t", scenario, driver, 1, float("inf"), tmp_path, folders)
    finally:
        for folder in folders.values():
            shutil.rmtree(folder, ignore_errors=True)
    assert all(m.identical for m in results.values()), results


# ---- the C loop against fake FMUs: the outcomes no real FMU here produces ----


class FakeFmu:
    """FMI functions made from Python callbacks: output 0 is the instance's time; ``do_step_status``
    and ``get_status`` map a time to a status; ``terminate_at``: FMI 3 asks to terminate there."""

    def __init__(self, fmi3: bool, do_step_status=lambda t: 0, get_status=lambda t: 0, terminate_at=None):
        import ctypes as c

        self.time, self.calls, self.inputs = 0.0, [], []  # inputs: (reals, booleans) of each step
        b = c.c_bool if fmi3 else c.c_int
        vr, n = c.POINTER(c.c_uint32), c.c_size_t

        def get(comp, vrs, nvr, values, *extra):
            self.calls.append(("get", self.time))
            values[0] = self.time
            return get_status(self.time)

        def do_step(comp, t, h, no_prior, *flags):
            self.calls.append(("doStep", t))
            status = do_step_status(t)
            if status <= 1:
                self.time = t + h
            if fmi3 and terminate_at is not None and t >= terminate_at - 1e-12:
                flags[1][0] = True
            return status

        def ok(*args):
            return 0

        def set_real(comp, vrs, nvr, values, *extra):
            self.inputs.append(([values[i] for i in range(nvr)], []))
            return 0

        def set_boolean(comp, vrs, nvr, values, *extra):
            self.inputs[-1][1].extend(values[i] for i in range(nvr))
            return 0

        extra = (n,) if fmi3 else ()
        setter_r = c.CFUNCTYPE(c.c_int, c.c_void_p, vr, n, c.POINTER(c.c_double), *extra)
        setter_b = c.CFUNCTYPE(c.c_int, c.c_void_p, vr, n, c.POINTER(b), *extra)
        step = (c.CFUNCTYPE(c.c_int, c.c_void_p, c.c_double, c.c_double, c.c_bool, c.POINTER(c.c_bool),
                            c.POINTER(c.c_bool), c.POINTER(c.c_bool), c.POINTER(c.c_double)) if fmi3 else
                c.CFUNCTYPE(c.c_int, c.c_void_p, c.c_double, c.c_double, c.c_int))
        p = "fmi3" if fmi3 else "fmi2"
        names = ("SetFloat64", "GetFloat64") if fmi3 else ("SetReal", "GetReal")
        self.dll = type("Dll", (), {})()
        setattr(self.dll, p + names[0], setter_r(set_real))
        setattr(self.dll, p + names[1], setter_r(get))
        setattr(self.dll, p + "SetBoolean", setter_b(set_boolean))
        setattr(self.dll, p + "GetBoolean", setter_b(ok))
        setattr(self.dll, p + "DoStep", step(do_step))
        setter_i = c.CFUNCTYPE(c.c_int, c.c_void_p, vr, n, c.POINTER(c.c_int32), *extra)
        setattr(self.dll, p + ("GetInt32" if fmi3 else "GetInteger"), setter_i(ok))
        self.component = 1234

    def slave(self, fmi3: bool):
        import ctypes as c
        from types import SimpleNamespace

        b = c.c_bool if fmi3 else c.c_int
        return SimpleNamespace(
            fmu=self, fmi3=fmi3, m=1, name="fake", real_in=(c.c_double * 0)(), bool_in=(b * 0)(),
            real_out=(c.c_double * 1)(), real_prev=(c.c_double * 1)(), bool_out=(b * 0)(), bool_prev=(b * 0)(),
            vr_real_in=(c.c_uint32 * 0)(), vr_bool_in=(c.c_uint32 * 0)(), vr_real_out=(c.c_uint32 * 1)(7),
            vr_bool_out=(c.c_uint32 * 0)(), vr_int_out=(c.c_uint32 * 0)(), int_out=(c.c_int32 * 0)(),
            rec_real=[], rec_bool=[], n_rec_real=0, n_rec_bool=0, conn_real=[], conn_bool=[],
            out_index={"t": ("real", 0)}, feeds_connections=False)


def fake_stepper(library, fake: FakeFmu, fmi3: bool, n_ticks: int = 10):
    from types import SimpleNamespace

    slave = fake.slave(fmi3)
    scenario = SimpleNamespace(connections=(), ticks_per_output=1, start_time=0.0, base_step=0.1, recorded=None)
    return fastpath.Stepper(library, [slave], scenario, n_ticks, [(slave.real_out, 0)])


def test_fmi3_terminate_ends_the_chunk_after_that_tick(library):
    fake = FakeFmu(True, terminate_at=0.3)
    out = fake_stepper(library, fake, True).run_chunk(0, 10)
    assert (out.code, out.tick, out.instance, out.time) == (fastpath.TERMINATED, 4, "fake", 0.30000000000000004)
    np.testing.assert_array_equal(out.rows, [[0.1 * k, 0.1 * k] for k in range(1, 5)])


@pytest.mark.parametrize("fmi3", [True, False])
def test_failing_calls_are_reported_with_the_rows_before(library, fmi3):
    fake = FakeFmu(fmi3, do_step_status=lambda t: 3 if t > 0.45 else 1)  # Warning is not a failure
    out = fake_stepper(library, fake, fmi3).run_chunk(0, 10)
    assert (out.code, out.tick, out.instance, out.status) == (fastpath.FAILED, 5, "fake", 3)
    assert out.function == ("fmi3DoStep" if fmi3 else "fmi2DoStep") and out.time == 0.5
    assert len(out.rows) == 5 and out.rows[-1, 0] == 0.5
    # a failing get at an output row: the tick is done, its row is not
    fake = FakeFmu(fmi3, get_status=lambda t: 4 if t > 0.15 else 0)
    out = fake_stepper(library, fake, fmi3).run_chunk(0, 10)
    assert (out.code, out.tick, out.status, out.time) == (fastpath.FAILED, 2, 4, 0.2)
    assert out.function == ("fmi3GetFloat64" if fmi3 else "fmi2GetReal") and len(out.rows) == 1


def test_chunks_continue_where_the_last_one_ended(library):
    fake = FakeFmu(False)
    stepper = fake_stepper(library, fake, False, n_ticks=10)
    first, second = stepper.run_chunk(0, 3).rows.copy(), stepper.run_chunk(3, 10).rows
    assert len(first) == 3 and len(second) == 7
    np.testing.assert_array_equal(np.vstack([first, second])[:, 0], np.arange(1, 11) * 0.1)
    assert [t for call, t in fake.calls if call == "doStep"] == [k * 0.1 for k in range(10)]


def recorded_stepper(library, fmi3: bool, last_samples: tuple[float, float] = (0.81, 0.95)):
    """A fake instance fed by two real channels (linear, hold) and a boolean one, on irregular samples,
    stepped at 0.1 s for ten ticks."""
    import ctypes as c
    from types import SimpleNamespace

    from milling_twin.orchestrator.recorded import RecordedData

    time = np.array([0.0, 0.05, 0.2, 0.37, 0.5, *last_samples])  # 0.2 and 0.5 fall on the grid
    rng = np.random.default_rng(7)
    rec = RecordedData(path="rec.csv", time=time,
                       channels={"a": rng.normal(size=7) * 1e3, "b": rng.normal(size=7), "on": time > 0.3},
                       units={"a": "W", "b": "m", "on": "bool"})
    inputs = [SimpleNamespace(channel="a", interpolation="linear", factor=1e-3),
              SimpleNamespace(channel="b", interpolation="hold", factor=0.1),
              SimpleNamespace(channel="on", interpolation="linear", factor=1.0)]
    fake = FakeFmu(fmi3)
    slave = fake.slave(fmi3)
    b = c.c_bool if fmi3 else c.c_int
    slave.rec_real, slave.rec_bool, slave.n_rec_real, slave.n_rec_bool = inputs[:2], inputs[2:], 2, 1
    slave.real_in, slave.vr_real_in = (c.c_double * 2)(), (c.c_uint32 * 2)(1, 2)
    slave.bool_in, slave.vr_bool_in = (b * 1)(), (c.c_uint32 * 1)(3)
    scenario = SimpleNamespace(connections=(), ticks_per_output=1, start_time=0.0, base_step=0.1, recorded=rec)
    return fake, rec, inputs, fastpath.Stepper(library, [slave], scenario, 10, [(slave.real_out, 0)])


@pytest.mark.parametrize("fmi3", [False, True])
def test_recorded_inputs_are_sampled_in_c_as_recorded_data_at_samples_them(library, fmi3):
    fake, rec, inputs, stepper = recorded_stepper(library, fmi3)
    assert stepper.run_chunk(0, 10).code == fastpath.DONE
    times = 0.0 + np.arange(10) * 0.1  # the master's grid
    expected = np.column_stack([rec.at(i.channel, times, i.interpolation) * i.factor for i in inputs[:2]])
    got = np.array([reals for reals, _ in fake.inputs])
    np.testing.assert_array_equal(got.view(np.uint64), expected.view(np.uint64))  # bit for bit
    assert [bools[0] != 0 for _, bools in fake.inputs] == list(rec.at("on", times, "hold"))


def test_a_time_outside_the_recording_raises_what_the_python_path_raises(library):
    from milling_twin.orchestrator.recorded import RecordedDataError

    fake, rec, inputs, stepper = recorded_stepper(library, False, last_samples=(0.52, 0.55))
    out = stepper.run_chunk(0, 10)
    assert (out.code, out.tick, out.instance, out.time) == (fastpath.OUT_OF_RECORDING, 6, "fake", 0.6000000000000001)
    assert len(fake.inputs) == 6 and len(out.rows) == 6  # the ticks before it stepped and recorded
    with pytest.raises(RecordedDataError, match=r"channel 'a': time 0.6000000000000001 s is outside the recorded "
                                                r"range \[0.0, 0.55\] s"):
        stepper.raise_out_of_recording(out)

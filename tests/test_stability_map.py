"""The simulated stability map: the onset per speed read from a study summary, the semi-discretization and zero-order
columns, the table and the figure, and a tiny real grid of chatter co-simulations through the study layer."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fmu_helpers import fmu_dir, repo_root
from milling_twin.models.stability import Mode, semi_discretization_limit, stability_lobes
from milling_twin.orchestrator.scenario import load_scenario
from milling_twin.orchestrator.study import stability_map as sm
from milling_twin.orchestrator.study.reduce import get_reduction
from milling_twin.orchestrator.validation.chatter import tool_and_cut

SCENARIO = repo_root() / "scenarios" / "chatter.toml"
MODE = Mode(922.0, 0.011, 1.34e6)  # scenarios/chatter.toml's tool
KTC, KRC = 767.01e6, 168.8e6  # the CuttingForce defaults


def synthetic_summary(onset_by_speed: dict[float, float], depths: np.ndarray, rate: float = 40.0) -> pd.DataFrame:
    """Growth exp(rate (a / a_onset - 1)) at every depth: log(growth) is linear in depth, crossing 0 at the onset."""
    rows = []
    for rpm, onset in onset_by_speed.items():
        for depth in depths[::-1]:  # any order
            rows.append({"force.spindle_speed": rpm * 2 * math.pi / 60, "force.axial_depth": depth,
                         "growth": math.exp(rate * (depth / onset - 1)), "status": "ok"})
    return pd.DataFrame(rows)


def test_onset_is_the_log_growth_crossing_between_the_deepest_stable_and_shallowest_unstable_depth() -> None:
    depths = np.linspace(0.02e-3, 0.12e-3, 6)  # 0.02 mm steps
    summary = synthetic_summary({6000.0: 0.0391e-3, 16000.0: 0.0534e-3, 24000.0: 0.11e-3}, depths)
    found = sm.onsets(summary)
    assert [o.speed_rpm for o in found] == pytest.approx([6000.0, 16000.0, 24000.0])
    assert [o.depth for o in found] == pytest.approx([0.0391e-3, 0.0534e-3, 0.11e-3], rel=1e-9)
    assert (found[0].stable_depth, found[0].unstable_depth) == pytest.approx((0.02e-3, 0.04e-3))
    assert (found[2].stable_depth, found[2].unstable_depth) == pytest.approx((0.10e-3, 0.12e-3))
    assert all(o.note == "" for o in found)


def test_onset_not_bracketed_failed_cases_left_out_and_an_island_noted() -> None:
    assert math.isnan(sm.onset_of(6000.0, [1e-5, 2e-5], [0.3, 0.9]).depth)
    assert sm.onset_of(6000.0, [1e-5, 2e-5], [0.3, 0.9]).note == "stable up to 0.02 mm"
    below = sm.onset_of(6000.0, [1e-5, 2e-5], [1.3, 2.0])
    assert math.isnan(below.depth) and below.unstable_depth == 2e-5 / 2 and below.note == "chatter from 0.01 mm"
    island = sm.onset_of(9000.0, [1e-5, 2e-5, 3e-5, 4e-5], [0.5, 2.0, 0.8, 3.0])
    assert (island.stable_depth, island.unstable_depth, island.note) == (1e-5, 2e-5, "stable again above")
    assert island.depth == pytest.approx(1e-5 + math.log(2) / math.log(4) * 1e-5)
    summary = synthetic_summary({6000.0: 0.04e-3}, np.array([0.02e-3, 0.03e-3, 0.05e-3]))
    failed = summary.iloc[[0]].assign(**{"force.axial_depth": 0.045e-3, "growth": math.nan, "status": "failed"})
    (onset,) = sm.onsets(pd.concat([summary, failed], ignore_index=True))
    assert (onset.stable_depth, onset.unstable_depth) == pytest.approx((0.03e-3, 0.05e-3))
    with pytest.raises(KeyError, match="no column 'growth_z'"):
        sm.onsets(summary, growth="growth_z")


def test_sd_and_zoa_columns_are_the_stability_models_at_the_same_speeds(tmp_path: Path) -> None:
    base = load_scenario(SCENARIO, fmu_dir())
    speeds = [11000.0, 16000.0]
    summary = synthetic_summary({11000.0: 0.036e-3, 16000.0: 0.055e-3}, np.linspace(0.03e-3, 0.06e-3, 4))
    summary["chip_growth"] = summary["growth"] ** 2  # the same crossings
    maps = sm.stability_map(summary, base, tmp_path, sm.MapConfig(growth=("growth", "chip_growth"), curve_points=6),
                            echo=False)
    rows = maps["growth"]
    sd = [semi_discretization_limit((MODE,), (MODE,), KTC, KRC, 2, n) for n in speeds]
    zoa = stability_lobes((MODE,), (MODE,), KTC, KRC, 2, lobes=60).limit(speeds)
    assert [r.sd for r in rows] == pytest.approx(sd, rel=1e-12)
    assert [r.zoa for r in rows] == pytest.approx(zoa, rel=1e-12)
    assert [r.cosim for r in rows] == pytest.approx([0.036e-3, 0.055e-3], rel=1e-9)
    assert rows[0].cosim_vs_sd == pytest.approx(0.036e-3 / sd[0] - 1)
    assert [r.cosim for r in maps["chip_growth"]] == pytest.approx([r.cosim for r in rows], rel=1e-9)
    csv_path, figure = sm.map_paths(tmp_path, "growth", True)
    assert (csv_path.name, figure.name) == ("stability_map.csv", "stability_map.png")
    with csv_path.open() as f:
        table = list(csv.DictReader(f))
    assert [float(r["sd_mm"]) for r in table] == pytest.approx(np.array(sd) * 1e3, rel=1e-5)
    assert [float(r["zoa_vs_sd_pct"]) for r in table] == pytest.approx(100 * (zoa / np.array(sd) - 1), abs=1e-3)
    assert figure.stat().st_size > 20_000
    assert all(p.stat().st_size > 0 for p in sm.map_paths(tmp_path, "chip_growth", False))
    text = sm.table_text(rows)
    assert "11000" in text and "co-sim within 5 % of SD at" in text


def test_map_config_errors_name_the_file_and_key() -> None:
    assert sm.map_config({"curve_points": 0}, "s.toml") == sm.MapConfig(curve_points=0)
    assert sm.map_config({"growth": "chip_growth"}, "s.toml").growth == ("chip_growth",)
    with pytest.raises(ValueError, match=r"s\.toml: \[study\.map\]\.growth = \[\]"):
        sm.map_config({"growth": []}, "s.toml")
    with pytest.raises(ValueError, match=r"s\.toml: \[study\.map\]\.speeds: unknown key"):
        sm.map_config({"speeds": 3}, "s.toml")
    with pytest.raises(ValueError, match=r"s\.toml: \[study\.map\]\.zoa_lobes = 0"):
        sm.map_config({"zoa_lobes": 0}, "s.toml")
    with pytest.raises(ValueError, match=r"s\.toml: \[study\.map\]\.depth = 'depth'"):
        sm.map_config({"depth": "depth"}, "s.toml")


def test_chatter_growth_is_registered() -> None:
    assert get_reduction("chatter_growth") is sm.chatter_growth
    assert np.allclose(sm.growth_windows(0.0, 0.2), ((0.1, 0.15), (0.15, 0.2)), rtol=0, atol=1e-15)
    assert tool_and_cut(load_scenario(SCENARIO, fmu_dir())).modes_x == (MODE,)


def test_the_dynamic_chip_of_a_forced_response_cancels_where_the_tooth_period_is_no_multiple_of_the_step() -> None:
    """A forced response (harmonics of the tooth period, as a stable cut settles into) plus a decaying free
    vibration 1e-3 of its size: the dynamic chip's RMS is the free vibration's, its growth that vibration's
    decay, also at 25500 rpm where tau is 117.65 output steps of 10 us (a linear interpolation of r(t - tau) left
    3e-4 of the forced response there, and the growth levelled off at 1)."""
    scenario = load_scenario(SCENARIO, fmu_dir())
    rpm = 25500.0
    force = scenario.instance("force")
    force.inputs["spindle_speed"] = rpm / sm.RPM
    tau = 60.0 / (2 * rpm)
    t = np.arange(0.0, 0.2 + 5e-6, 1e-5)
    forced = sum(1e-6 / k ** 2 * np.sin(2 * math.pi * k * t / tau + k) for k in (1, 2, 3))
    decay = 20.0  # 1/s
    free = 1e-9 * np.exp(-decay * t) * np.sin(2 * math.pi * 922.0 * t)
    frame = pd.DataFrame({"time": t, "vibration.tip_displacement_x": forced + free,
                          "vibration.tip_displacement_y": 0.5 * forced})
    windows = sm.growth_windows(0.0, 0.2)
    growth = sm.dynamic_chip_growth(scenario, frame, windows)
    assert growth == pytest.approx(math.exp(-decay * 0.05), rel=0.02) and growth < 0.95
    only_free = pd.DataFrame({"time": t, "vibration.tip_displacement_x": free, "vibration.tip_displacement_y": 0 * t})
    assert sm.dynamic_chip_rms(scenario, frame, windows) == pytest.approx(
        sm.dynamic_chip_rms(scenario, only_free, windows), rel=0.02)


def test_a_dynamic_chip_larger_than_half_the_feed_per_tooth_is_a_limit_cycle_of_infinite_growth() -> None:
    """Chatter grown into a limit cycle (the tool leaves the cut, the growth stops near 1) is chatter once the
    dynamic chip's RMS exceeds LIMIT_CYCLE_CHIP feeds per tooth: its chip_growth is the growth while it grew (inf
    when it never did); the same vibration 100 times smaller, a slowly decaying stable cut, keeps its measured
    growth."""
    from milling_twin.orchestrator.study.reduce import CaseRun

    scenario = load_scenario(SCENARIO, fmu_dir())
    force = scenario.instance("force")
    rpm = force.inputs["spindle_speed"] * sm.RPM
    tau = 60.0 / (2 * rpm)
    fz = sm.feed_per_tooth(scenario)
    assert fz == pytest.approx(force.inputs["feed_velocity_x"] * tau)
    t = np.arange(0.0, scenario.stop_time + 5e-6, 1e-5)
    quarter = scenario.stop_time / 4

    def growth_of(r: np.ndarray) -> dict[str, float]:
        frame = pd.DataFrame({"time": t, "vibration.tip_displacement_x": r, "vibration.tip_displacement_y": 0 * t})
        return sm.chatter_growth(CaseRun("c", {}, scenario, Path("."), "ok", frame=frame))

    wave = np.sin(2 * math.pi * 950.0 * t)
    saturated = growth_of(2 * fz * np.exp(-0.1 * t) * wave)  # RMS 1.41 feeds per tooth, never grew
    assert math.isinf(saturated["chip_growth"]) and saturated["chip_rms"] > sm.LIMIT_CYCLE_CHIP * fz
    grew = growth_of(2 * fz * np.minimum(np.exp(30 * (t - 2 * quarter)), 1.0) * wave)  # e^30/s up to mid-run
    assert grew["chip_growth"] == pytest.approx(math.exp(30 * quarter), rel=0.05)  # the first quarter from tau
    stable = growth_of(0.02 * fz * np.exp(-0.1 * t) * wave)  # RMS 0.014 feeds per tooth
    assert stable["chip_growth"] == pytest.approx(math.exp(-0.1 * quarter), rel=1e-3)


TINY_STUDY = """
[study]
name = "tiny_map"
base = "{base}"
stop_time = 0.1
post = "stability_map"

[study.grid]
"force.spindle_speed" = {{ values = [16000, 20000], unit = "rpm" }}
"force.axial_depth" = {{ values = [0.025, 0.05, 0.1], unit = "mm" }}

[[study.reduce]]
kind = "chatter_growth"

[study.map]
growth = ["growth", "chip_growth"]
curve_points = 4
"""


def test_map_of_a_tiny_real_grid_through_the_serial_executor(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """2 speeds x 3 depths of 0.1 s through the study layer in this process, the map made by the sweep's
    post-processor: at each speed the semi-discretization onset lies in the co-simulated bracket (0.05-0.1 mm at
    16000 rpm, 0.025-0.05 mm at 20000 rpm), and the onset is within 15 % of it."""
    from milling_twin.api import sweep

    study = tmp_path / "tiny.toml"
    study.write_text(TINY_STUDY.format(base=SCENARIO.as_posix()))
    result = sweep(study, fmu_dir=fmu_dir(), out=tmp_path / "out", workers=0)
    summary = result.summary
    assert list(summary["status"]) == ["ok"] * 6
    # serially, the limits the map needs are computed in its preparation, before the cases
    assert list(result.phases) == ["executor start", "post preparation", "cases", "post-processing", "executor close"]
    assert {"growth_x", "growth_y", "growth", "stable", "chip_growth"} <= set(summary.columns)
    assert list(summary["stable"]) == [float(g <= 1) for g in summary["growth"]]
    printed = capsys.readouterr().out
    assert "co-simulation (growth = 1)" in printed and "co-simulation (chip_growth = 1)" in printed
    for growth, first in (("growth", True), ("chip_growth", False)):
        csv_path, figure = sm.map_paths(result.folder, growth, first)
        with csv_path.open() as f:
            rows = list(csv.DictReader(f))
        assert [float(r["speed_rpm"]) for r in rows] == [16000.0, 20000.0]
        for r in rows:
            low, high, sd, cosim = (float(r[k]) for k in ("stable_mm", "unstable_mm", "sd_mm", "cosim_mm"))
            assert low < sd < high and low < cosim < high
            assert abs(float(r["cosim_vs_sd_pct"])) < 15
        assert figure.stat().st_size > 20_000


class CountingExecutor:
    """Runs each submission at once and counts them (a ClientExecutor's ``priority`` never reaches it)."""

    def __init__(self) -> None:
        from milling_twin.orchestrator.study.executor import SerialExecutor

        self.inner, self.submitted = SerialExecutor(), 0

    def submit(self, fn, /, *args):  # noqa: ANN001, ANN202 - the Executor protocol
        self.submitted += 1
        return self.inner.submit(fn, *args)


def test_the_map_s_limits_prepared_before_the_cases_are_all_it_needs(tmp_path: Path) -> None:
    """prepare_map submits, before any case, the limits at the study's speeds and along the figure's curve; the map
    made afterwards from the summary submits none of its own and writes the serial map."""
    from milling_twin.api import sweep
    from milling_twin.orchestrator.study.spec import load_study

    path = tmp_path / "tiny.toml"
    path.write_text(TINY_STUDY.format(base=SCENARIO.as_posix()))
    result = sweep(path, fmu_dir=fmu_dir(), out=tmp_path / "out", workers=0, progress=False)
    study = load_study(path, fmu_dir())
    before = CountingExecutor()
    started = sm.prepare_map(study, study.post_config, before)
    assert len(started) == 2 + 4  # two speeds, four curve points
    assert before.submitted == math.ceil(len(started) / sm.SD_PER_TASK)  # several limits per task
    after = CountingExecutor()
    sm.stability_map(result.summary, study.base, tmp_path, study.post_config, echo=False, executor=after,
                     started=started)
    assert after.submitted == 0
    for growth, first in (("growth", True), ("chip_growth", False)):
        assert (sm.map_paths(tmp_path, growth, first)[0].read_text()
                == sm.map_paths(result.folder, growth, first)[0].read_text())


def test_study_file_map_errors_name_the_file_and_key(tmp_path: Path) -> None:
    from milling_twin.orchestrator.study.spec import StudyError, load_study

    study = tmp_path / "bad.toml"
    study.write_text(TINY_STUDY.format(base=SCENARIO.as_posix()).replace("curve_points = 4", "curve_points = -1"))
    with pytest.raises(StudyError, match=r"bad\.toml: \[study\.map\]\.curve_points"):
        load_study(study, fmu_dir())
    study.write_text(TINY_STUDY.format(base=SCENARIO.as_posix()).replace("curve_points = 4", "speeds = 4"))
    with pytest.raises(StudyError, match=r"bad\.toml: \[study\.map\]\.speeds: unknown key"):
        load_study(study, fmu_dir())


def test_the_sd_limits_through_an_executor_are_the_serial_ones_in_order() -> None:
    """The map computes its semi-discretization limits on the study's workers; any executor gives the same
    numbers in the speeds' order."""
    from concurrent.futures import ThreadPoolExecutor

    tool = tool_and_cut(load_scenario(SCENARIO, fmu_dir()))
    speeds = [6000.0, 9000.0, 11000.0]
    with ThreadPoolExecutor(2) as executor:
        parallel = sm.sd_limits(tool, speeds, executor)
    assert np.array_equal(parallel, sm.sd_limits(tool, speeds))
    started = sm.submit_sd_limits(tool, speeds[1:], CountingExecutor())  # some computed before
    counting = CountingExecutor()
    assert np.array_equal(sm.sd_limits(tool, speeds, counting, started), parallel) and counting.submitted == 1
    assert parallel[0] == semi_discretization_limit(tool.modes_x, tool.modes_y, tool.ktc, tool.krc, tool.n_flutes,
                                                    6000.0, tool.entry, tool.exit)


def test_a_failed_or_cancelled_task_of_sd_limits_reaches_each_of_its_speeds() -> None:
    """The limits go to the workers several per task; every speed's future carries its task's outcome."""
    from concurrent.futures import CancelledError, Future

    task: Future = Future()
    futures = sm._per_speed(task, (6000.0, 7000.0))
    task.set_exception(ValueError("semi-discretization: mode 1 in x"))
    for future in futures.values():
        with pytest.raises(ValueError, match="mode 1 in x"):
            future.result()
    task = Future()
    futures = sm._per_speed(task, (6000.0, 7000.0))
    task.cancel()
    assert all(f.cancelled() for f in futures.values())
    with pytest.raises(CancelledError):
        futures[7000.0].result()


def test_the_committed_map_s_depth_grid_brackets_the_sd_onset_at_every_speed() -> None:
    """studies/stability_map.toml can compare the co-simulated onset with semi-discretization at every one of its
    speeds only if its depths reach below and above each speed's SD onset (by more than the 5 % the comparison
    allows): a narrower grid leaves speeds 'stable up to' its top, as 14000 and 25000 rpm were at 0.3 mm."""
    from milling_twin.orchestrator.scenario import with_values
    from milling_twin.orchestrator.study.run import si_inputs
    from milling_twin.orchestrator.study.spec import load_study

    study = load_study(repo_root() / "studies" / "stability_map.toml", fmu_dir())
    names = ("force.spindle_speed", "force.axial_depth")
    points = [si_inputs(with_values(study.base, case.values), names) for case in study.cases]
    speeds = sorted({p[names[0]] * 60 / (2 * math.pi) for p in points})
    depths = np.array(sorted({p[names[1]] for p in points}))
    assert len(speeds) == 20 and len(depths) == 12
    limits = sm.sd_limits(tool_and_cut(study.base), speeds)
    assert np.all(np.isfinite(limits))
    for rpm, limit in zip(speeds, limits):
        assert depths[0] < limit / 1.05 and limit * 1.05 < depths[-1], (rpm, limit, depths[[0, -1]])

"""Temporal alignment (orchestrator.align): time maps, the three methods on known warps of a
real UMich path, the output-delay convention of co-simulation results, the CLI."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from milling_twin.orchestrator.align import METHODS, AlignmentError, TimeMap, Trajectory, align, align_results
from milling_twin.cli import main


def align_cli(args: list[str]) -> int:
    return main(["align", *args])
from milling_twin.orchestrator.align.dtw_baseline import DtwOptions
from milling_twin.orchestrator.align.patent import PatentOptions
from cases.align_synthetic import (Warp, make_recording, path_from_umich,
                                          quantize_significant)
from milling_twin.orchestrator.align.timemap import path_residual
from milling_twin.orchestrator.align.trajectory import delay_corrected
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.recorded import RecordedData
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import load_scenario

PI = math.pi


@pytest.fixture(scope="module")
def sim(repo_root) -> Trajectory:
    """Smooth 100 Hz path from the real experiment 01 (105 s)."""
    return path_from_umich(repo_root / "scenarios" / "data" / "umich_experiment_01.csv")


def errors_ms(tm: TimeMap, truth: np.ndarray) -> np.ndarray:
    return np.abs(tm.simulated_time - truth) * 1000.0


# ----------------------------------------------------------------------------- TimeMap


def test_time_map_maps_both_ways_with_flat_pause_and_nan_outside():
    tm = TimeMap(np.array([0.0, 1.0, 2.0, 3.0, 4.0]), np.array([10.0, 11.0, 11.0, 11.0, 13.0]),
                 np.ones(5), "test")
    np.testing.assert_allclose(tm.to_simulated([0.5, 2.5, 3.5]), [10.5, 11.0, 12.0])
    assert np.isnan(tm.to_simulated(4.5))
    # flat part (machine paused from t = 1 to 3): the first recorded time reaching 11
    np.testing.assert_allclose(tm.to_recorded([10.5, 11.0, 12.0, 13.0]), [0.5, 1.0, 3.5, 4.0])
    assert np.all(np.isnan(tm.to_recorded([9.9, 13.1])))
    sim_t = np.array([10.0, 12.0, 14.0])
    np.testing.assert_allclose(tm.resample_simulated(sim_t, np.array([0.0, 2.0, 4.0])),
                               [0.0, 1.0, 1.0, 1.0, 3.0])
    vals = np.c_[np.arange(5.0), 10 * np.arange(5.0)]
    np.testing.assert_allclose(tm.resample_recorded(vals, np.array([10.5, 12.0]))[:, 1],
                               [5.0, 35.0])
    early = TimeMap(np.array([0.0, 1.0]), np.array([5.0, 6.0]), np.ones(2), "test")
    assert np.isnan(early.resample_simulated(np.array([5.5, 7.0]), np.array([1.0, 2.0]))[0])


@pytest.mark.parametrize("sim_time, conf, message", [
    ([1.0, 0.5, 2.0], [1, 1, 1], "non-decreasing (row 1)"),
    ([1.0, 1.5, 2.0], [1, 2, 1], "confidence must lie in [0, 1]"),
    ([1.0, np.nan, 2.0], [1, 1, 1], "simulated_time is not finite at row 1"),
])
def test_time_map_rejects_bad_maps(sim_time, conf, message):
    with pytest.raises(AlignmentError, match=message.replace("[", r"\[").replace("(", r"\(")
                       .replace(")", r"\)").replace("]", r"\]")):
        TimeMap(np.array([0.0, 1.0, 2.0]), np.array(sim_time), np.array(conf, float), "m")


def test_trajectory_errors_name_row_and_column():
    with pytest.raises(AlignmentError, match="position is not finite at row 2, axis y"):
        Trajectory(np.arange(4.0), np.c_[np.zeros(4), [0, 0, np.nan, 0], np.zeros(4)], "rec")
    with pytest.raises(AlignmentError, match=r"row 2 \(1.0 s\) follows row 1 \(1.0 s\)"):
        Trajectory(np.array([0.0, 1.0, 1.0]), np.zeros((3, 3)), "rec")
    frame = pd.DataFrame({"time": [0.0, 1.0], "a.x": [0, 1], "a.y": [0, 1]})
    with pytest.raises(AlignmentError, match="no column 'a.z'"):
        Trajectory.from_results(frame, ["a.x", "a.y", "a.z"])
    with pytest.raises(AlignmentError, match="output_delay must be"):
        Trajectory.from_results(frame.assign(**{"a.z": 0}), ["a.x", "a.y", "a.z"], -0.1)


# --------------------------------------------------------- output-delay convention


def test_output_delay_convention_of_cosimulation_results(make_case, fmu_dir, tmp_path):
    """A doStep result belongs to the end of its step: the master's row at t holds what
    doStep(t - h, h) left, computed from recorded inputs sampled at t - h (the case of
    conftest: P_total of sample k appears in row k + 1). With output_delay = h the row is
    moved back to the moment of its inputs, the initial row dropped."""
    result = run(load_scenario(make_case(), fmu_dir), tmp_path / "runs", progress=False)
    frame = load_results(result.run_dir)
    per_sample = [100.0, 300 + 0.5 * 2 * PI * 10 + 50, 300 + 0.5 * 2 * PI * 20 + 100,
                  300 + 0.5 * 2 * PI * 20, 100.0]  # P_total from inputs of samples 0..4
    np.testing.assert_allclose(frame["time"], [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-12)
    np.testing.assert_allclose(frame["power.P_total"][1:], per_sample[:4], rtol=1e-12)
    shifted = delay_corrected(frame, 0.1)
    np.testing.assert_allclose(shifted["time"], [0.0, 0.1, 0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(shifted["power.P_total"], per_sample[:4], rtol=1e-12)
    # identity map on the recorded samples: each simulated value lands on its input's sample
    tm = TimeMap(np.arange(5) * 0.1, np.arange(5) * 0.1, np.ones(5), "identity")
    on_rec = tm.resample_simulated(shifted["time"].to_numpy(), shifted["power.P_total"].to_numpy())
    np.testing.assert_allclose(on_rec[:4], per_sample[:4], rtol=1e-12)
    assert np.isnan(on_rec[4])  # nothing simulated from sample 4's inputs within the run
    # without the correction every value would sit one sample late
    raw = tm.resample_simulated(frame["time"].to_numpy(), frame["power.P_total"].to_numpy())
    assert raw[2] == pytest.approx(per_sample[1]) and raw[2] != pytest.approx(per_sample[2])


# ----------------------------------------------------------------------- methods


def warped(sim: Trajectory, warp: Warp, seed: int = 1, **kw):
    return make_recording(sim, warp, sample_period=0.1, noise=0.01,
                          rng=np.random.default_rng(seed), **kw)


AFFINE = Warp(start=2.6, scale=1.22)
HARD = Warp(start=-2.5, scale=0.87, overrides=((6.5, 1.33), (36.4, 1.1), (45.6, 0.73),
                                               (69.2, 1.16)),
            pauses=((16.4, 10.6), (89.7, 8.8)), tail=0.3)


def test_multiscale_recovers_offset_and_scale_better_than_plain_dtw(sim):
    rec = warped(sim, AFFINE)
    tm = align(rec.trajectory, sim)
    err = errors_ms(tm, rec.truth)
    base = errors_ms(align(rec.trajectory, sim, "dtw"), rec.truth)
    assert np.median(err) < 10.0 and np.percentile(err, 95) < 50.0  # 10 Hz data: 100 ms
    assert np.median(err) < 0.5 * np.median(base)
    assert tm.info["rate"] == pytest.approx(1 / 1.22, rel=0.03)
    assert np.all(np.diff(tm.simulated_time) >= 0)


def test_multiscale_handles_overrides_pauses_dropouts_quantization(sim):
    rec = warped(sim, HARD, gaps=3, drop=0.02)
    assert rec.info["kept"] < 0.97  # dropouts really happened
    tm = align(rec.trajectory, sim)
    err = errors_ms(tm, rec.truth)
    assert np.median(err) < 15.0 and np.percentile(err, 95) < 100.0
    # inside the pause at simulated 16.4 s the map is flat, and confidence is reduced there
    t = rec.trajectory.time
    t0 = t[np.argmax(rec.truth >= 16.4 - 1e-9)]  # first recorded time at the pause point
    inside = (t > t0 + 1.0) & (t < t0 + 9.0)
    assert inside.sum() > 40 and np.ptp(rec.truth[inside]) == 0
    assert np.ptp(tm.simulated_time[inside]) < 0.05
    assert np.median(tm.confidence[inside]) < 0.6 < np.median(tm.confidence[~inside])


def test_multiscale_levels_at_100_hz(sim):
    """10,500 samples at 100 Hz: a coarse level of 2048 points, then the banded level on the
    recorded samples; median error under half a sample (the 95th percentile is set by where
    the machine paused: the held position, stored in 1 mm steps, fixes the pause moment only
    to tens of ms)."""
    rec = make_recording(sim, HARD, sample_period=0.01, noise=0.01,
                         rng=np.random.default_rng(3))
    tm = align(rec.trajectory, sim)
    assert [lv["samples"] for lv in tm.info["levels"]] == [2048, len(rec.trajectory)]
    err = errors_ms(tm, rec.truth)
    assert np.median(err) < 5.0 and np.percentile(err, 95) < 100.0


def test_recorded_positions_quantized_like_the_data():
    v = np.array([198.44, 99.96, 72.44, 27.55, -141.4, 0.0123])
    np.testing.assert_allclose(quantize_significant(v), [198.0, 100.0, 72.4, 27.6, -141.0,
                                                         0.0123])


def test_patent_method_follows_its_steps_and_is_seeded(sim):
    rec = warped(sim, AFFINE)
    tm = align(rec.trajectory, sim, "patent")
    assert np.median(errors_ms(tm, rec.truth)) < 60.0
    assert tm.info["factor"] == pytest.approx(1.225, abs=0.03)  # stretch factor 1.22 found
    assert len(tm.info["division_counts"]) == 3
    assert all(4 <= c <= 12 for c in tm.info["division_counts"])
    again = align(rec.trajectory, sim, "patent")
    np.testing.assert_array_equal(tm.simulated_time, again.simulated_time)
    other = align(rec.trajectory, sim, "patent", PatentOptions(seed=5))
    assert other.info["division_counts"] != tm.info["division_counts"]
    with pytest.raises(AlignmentError, match="num1 <= num2"):
        align(rec.trajectory, sim, "patent", PatentOptions(num1=9, num2=4))


def test_dispatch_and_baseline_guards(sim):
    rec = warped(sim, AFFINE)
    with pytest.raises(AlignmentError, match="unknown alignment method 'fast'"):
        align(rec.trajectory, sim, "fast")
    with pytest.raises(AlignmentError, match="takes DtwOptions, got PatentOptions"):
        align(rec.trajectory, sim, "dtw", PatentOptions())
    with pytest.raises(AlignmentError, match="matrix cells"):
        align(rec.trajectory, sim, "dtw", DtwOptions(max_cells=1e4))
    assert set(METHODS) == {"multiscale", "patent", "dtw"}


def test_scale_invariance_in_metres_and_residual(sim):
    """SI metres (as the loaders give) align like millimetres; the residual after alignment is
    of the order of the storage step."""
    rec = warped(sim, AFFINE)
    mm = align(rec.trajectory, sim)
    rec_m = Trajectory(rec.trajectory.time, rec.trajectory.position / 1000)
    sim_m = Trajectory(sim.time, sim.position / 1000)
    m = align(rec_m, sim_m)
    assert np.median(np.abs(m.simulated_time - mm.simulated_time)) < 1e-3
    res = path_residual(m, rec_m, sim_m)
    assert res.median < 0.5e-3 and res.p95 < 1.0e-3  # metres: under 0.5 mm / 1 mm


def test_align_results_takes_recorded_data_and_results_frame(sim):
    rec = warped(sim, AFFINE)
    recorded = RecordedData("rec.csv", rec.trajectory.time,
                            {k: rec.trajectory.position[:, i] / 1000 for i, k in
                             enumerate("xyz")}, {k: "m" for k in "xyz"})
    results = pd.DataFrame({"time": sim.time, "interp.x": sim.position[:, 0] / 1000,
                            "interp.y": sim.position[:, 1] / 1000,
                            "interp.z": sim.position[:, 2] / 1000})
    tm = align_results(recorded, results, ["interp.x", "interp.y", "interp.z"])
    assert np.median(errors_ms(tm, rec.truth)) < 10.0


# --------------------------------------------------------------------------- CLI


def test_cli_temporal_writes_map_and_plot(sim, tmp_path, capsys):
    rec = warped(sim, AFFINE)
    pd.DataFrame({"X": rec.trajectory.position[:, 0], "Y": rec.trajectory.position[:, 1],
                  "Z": rec.trajectory.position[:, 2], "t": rec.trajectory.time}).to_csv(
        tmp_path / "rec.csv", index=False)
    pd.DataFrame({"time": sim.time, "x": sim.position[:, 0], "y": sim.position[:, 1],
                  "z": sim.position[:, 2]}).to_csv(tmp_path / "sim.csv", index=False)
    args = ["temporal", "--recorded", str(tmp_path / "rec.csv"), "--columns", "X,Y,Z",
            "--time-column", "t", "--simulated", str(tmp_path / "sim.csv"), "--sim-columns",
            "x,y,z", "--sim-unit", "mm", "--out", str(tmp_path / "map.csv"), "--plot",
            str(tmp_path / "map.png")]
    assert align_cli(args) == 0
    out = pd.read_csv(tmp_path / "map.csv")
    assert list(out.columns) == ["recorded_time", "simulated_time", "confidence"]
    assert np.median(np.abs(out["simulated_time"] - rec.truth)) < 0.01
    assert 0 < (tmp_path / "map.png").stat().st_size < 200_000
    bad = args.copy()
    bad[bad.index("X,Y,Z")] = "X,Y,W"
    assert align_cli(bad) == 2  # bad input: exit 2, as in every subcommand
    assert "column 'W'" in capsys.readouterr().err

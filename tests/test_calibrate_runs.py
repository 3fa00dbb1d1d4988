"""Kind "runs": one machine, several recordings; shared parameters, leave-one-run-out, HAC intervals.

Runs on the two UMich recordings the repository ships (runs 01 and 11) and a spliced copy of run 11 (blocks of
rows at the home position with the spindle stopped, as the logger of runs 02-12 writes them)."""
from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest

from milling_twin.datasets import DataMissing
from milling_twin.orchestrator.calibrate import CalibrationSpecError, calibrate, load_spec

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "scenarios" / "data"


def spliced_copy(source: Path, target: Path, every: int = 60, block: int = 8) -> Path:
    """``source`` with ``block`` rows at the home position (spindle stopped, 0 W) after every ``every`` rows."""
    with source.open(newline="") as fh:
        rows = list(csv.reader(fh))
    header, data = rows[0], rows[1:]
    home = list(data[0])
    for column, value in (("X1_ActualPosition", "198"), ("Y1_ActualPosition", "158"), ("Z1_ActualPosition", "119"),
                          ("X1_ActualVelocity", "0"), ("Y1_ActualVelocity", "0"), ("Z1_ActualVelocity", "0"),
                          ("S1_ActualVelocity", "0"), ("S1_CommandVelocity", "0"), ("S1_OutputPower", "0")):
        home[header.index(column)] = value
    out = [header]
    for k, row in enumerate(data):
        out.append(row)
        if k % every == every - 1:
            out += [home] * block
    with target.open("w", newline="") as fh:
        csv.writer(fh).writerows(out)
    return target


POWER_PARAMETERS = """
[parameters."power.P_idle"]
min = 0.0
max = 500.0
unit = "W"

[parameters."power.k_speed_loop"]
min = 0.0
max = 10.0
scale = 0.1
"""
POWER_OUTPUTS = """
[[outputs]]
simulated = "power.P_total"
recorded = "spindle_power"
unit = "W"
"""


def write_spec(folder: Path, files: list[str] | str, extra: str = "", parameters: str = POWER_PARAMETERS,
               outputs: str = POWER_OUTPUTS, scenario: Path = REPO / "scenarios" / "umich_power.toml") -> Path:
    spec = folder / "runs.toml"
    spec.write_text(f"""
[calibration]
name = "runs_test"
kind = "runs"
scenario = "{os.path.relpath(scenario, folder)}"
parameter_set = "runs_test.params.toml"

[runs]
folder = "."
files = {json.dumps(files)}
{extra}
{parameters}
{outputs}
[solver]
starts = 2
""")
    return spec


@pytest.fixture(scope="module")
def outcome(tmp_path_factory, fmu_dir):
    folder = tmp_path_factory.mktemp("runs")
    for name in ("umich_experiment_01.csv", "umich_experiment_11.csv"):
        (folder / name).write_bytes((DATA / name).read_bytes())
    spliced_copy(DATA / "umich_experiment_11.csv", folder / "spliced_11.csv")
    spec = write_spec(folder, ["umich_experiment_01.csv", "umich_experiment_11.csv", "spliced_11.csv"])
    return calibrate(spec, fmu_dir, folder / "out", progress=False)


def test_every_run_is_predicted_by_the_set_fitted_without_it(outcome):
    rows = {r["run"]: r for r in outcome.extra["cross_validation"]}
    assert set(rows) == {"umich_experiment_01", "umich_experiment_11", "spliced_11"}
    for row in rows.values():
        assert row["without_it"] < row["priors"], row  # the speed-loop term the priors lack
        assert row["with_it"] <= row["without_it"] * 1.05, row
    # the spliced copy is cut at every block: its pairs are run 11's (the first sample of each segment aside)
    assert rows["umich_experiment_11"]["pairs"] - rows["spliced_11"]["pairs"] < 2 * (2314 // 60 + 1)
    with (outcome.out_dir / "cross_validation.csv").open() as fh:
        assert len(list(csv.reader(fh))) == 1 + 3  # written fold by fold


def test_the_report_says_what_the_checks_found_and_how_the_runs_agree(outcome):
    titles = [t.title for t in outcome.tables]
    assert any(t.startswith("Leave-one-run-out") for t in titles)
    assert any(t.startswith("Estimates with 95 % intervals") for t in titles)
    runs = next(t for t in outcome.tables if t.title.startswith("Runs:"))
    segments = {r[0]: int(r[3]) for r in runs.rows}
    assert segments["umich_experiment_01"] == 1  # a clean pass
    # run 11 as recorded is spliced already; the copy adds a block every 60 rows (a few fall on existing cuts)
    assert segments["spliced_11"] - segments["umich_experiment_11"] > 0.8 * (2314 // 60)
    assert all("impossible transitions" in r[5] for r in runs.rows)
    assert any("models/ vs FMU at the calibrated values" in n and float(n.split()[-1].rstrip(".")) < 1e-8
               for n in outcome.notes)
    report = outcome.report_md.read_text()
    assert "Leave-one-run-out" in report and "moving-block bootstrap" in report
    text = outcome.parameter_set.read_text()
    assert "[parameters.power]" in text and "k_speed_loop" in text


def test_per_run_parameters_are_fitted_per_run_and_not_written(tmp_path, fmu_dir):
    (tmp_path / "a.csv").write_bytes((DATA / "umich_experiment_01.csv").read_bytes())
    (tmp_path / "b.csv").write_bytes((DATA / "umich_experiment_11.csv").read_bytes())
    spec = write_spec(tmp_path, ["a.csv", "b.csv"], extra='per_run = ["power.P_idle"]\ncross_validation = false')
    result = calibrate(spec, fmu_dir, tmp_path / "out", progress=False)
    names = [q.name for q in result.fit.parameters]
    assert names == ["power.k_speed_loop", "power.P_idle [a]", "power.P_idle [b]"]
    assert "P_idle" not in result.parameter_set.read_text().split("[parameters.power]")[1]
    assert not (tmp_path / "out" / "calibration" / "runs_test" / "cross_validation.csv").exists()


@pytest.mark.parametrize("extra, key, words", [
    ('per_run = ["power.c1"]', "[runs].per_run[0]", "not in [parameters]"),
    ('per_run = ["power.P_idle", "power.k_speed_loop"]', "[runs].per_run", "nothing would be shared"),
    ("hac_lags = -1", "[runs].hac_lags", "whole number"),
])
def test_mistakes_in_the_runs_table_name_the_key(tmp_path, extra, key, words):
    spec = write_spec(tmp_path, ["a.csv"], extra=extra)
    with pytest.raises(CalibrationSpecError) as info:
        load_spec(spec)
    assert f": {key}: " in str(info.value) and words in str(info.value)


def test_runs_found_by_a_pattern(tmp_path, fmu_dir):
    from milling_twin.orchestrator.calibrate.runs_fit import run_files

    for name in ("run_b.csv", "run_a.csv", "notes.txt"):
        (tmp_path / name).write_text("x\n")
    spec = load_spec(write_spec(tmp_path, "run_*.csv"))
    assert [name for name, _ in run_files(spec, None)] == ["run_a", "run_b"]
    with pytest.raises(CalibrationSpecError, match="no file in .* matches 'nothing_\\*.csv'"):
        run_files(load_spec(write_spec(tmp_path, "nothing_*.csv")), None)


def test_a_missing_folder_or_file_is_named(tmp_path, fmu_dir):
    spec = write_spec(tmp_path, ["nowhere.csv"])
    with pytest.raises(CalibrationSpecError, match="nowhere.csv not found"):
        calibrate(spec, fmu_dir, tmp_path / "out", progress=False)
    with pytest.raises(DataMissing, match="--data"):
        calibrate(spec, fmu_dir, tmp_path / "out", data=tmp_path / "absent", progress=False)


def test_outputs_that_read_unexposed_states_are_refused(tmp_path, fmu_dir):
    (tmp_path / "impulse.csv").write_bytes((REPO / "scenarios" / "calibration" / "data" / "impulse_hammer.csv")
                                           .read_bytes())
    spec = write_spec(tmp_path, ["impulse.csv"], parameters='[parameters."vib.frequency_x1"]',
                      outputs='[[outputs]]\nsimulated = "vib.tip_acceleration_x"\nrecorded = "acceleration"',
                      scenario=REPO / "scenarios" / "calibration" / "impulse_vibration.toml")
    with pytest.raises(CalibrationSpecError, match="does not expose as an output"):
        calibrate(spec, fmu_dir, tmp_path / "out", progress=False)


def test_hac_intervals_widen_for_autocorrelated_residuals():
    from milling_twin.orchestrator.calibrate.statistics import hac_meat, newey_west_lags

    rng = np.random.default_rng(0)
    n = 4000
    J = np.ones((n, 1))
    white = rng.normal(size=n)
    smooth = np.convolve(rng.normal(size=n + 9), np.ones(10) / np.sqrt(10), mode="valid")  # MA(9): correlated
    groups = np.zeros(n, dtype=int)
    for r, ratio in ((white, (0.7, 1.3)), (smooth, (5.0, 15.0))):
        classic = float(r @ r)
        hac = float(hac_meat(J, r, groups, 20)[0, 0])
        assert ratio[0] < hac / classic < ratio[1], (hac / classic, ratio)
    # no lag reaches across groups: every pair its own group leaves only the lag-0 term
    assert float(hac_meat(J, smooth, np.arange(n), 20)[0, 0]) == pytest.approx(float(smooth @ smooth))
    assert newey_west_lags(100) == 4 and newey_west_lags(1000) == 6


def test_block_bootstrap_keeps_blocks_inside_groups_and_finds_the_spread():
    from milling_twin.orchestrator.calibrate.statistics import block_bootstrap

    rng = np.random.default_rng(1)
    n = 3000
    x = rng.normal(size=n)
    J = np.column_stack([np.ones(n), x])  # a line: the Gauss-Newton step is the exact weighted solution
    r = np.convolve(rng.normal(size=n + 19), np.ones(20) / np.sqrt(20), mode="valid")  # correlated residuals
    groups = np.repeat(np.arange(30), 100)
    reps = block_bootstrap(J, r, [0.0, 0.0], groups, block=50, replicates=400, seed=0)
    white = block_bootstrap(J, r, [0.0, 0.0], groups, block=1, replicates=400, seed=0)
    # the intercept's spread: blocks keep the correlation (about sqrt(20) wider than resampling single pairs)
    assert 2.5 < np.std(reps[:, 0]) / np.std(white[:, 0]) < 7.0
    # the estimate itself: replicates centre on the least-squares solution of the data
    exact = -np.linalg.lstsq(J, r, rcond=None)[0]
    assert np.allclose(np.mean(reps, axis=0), exact, atol=4 * np.std(reps, axis=0) / np.sqrt(400) + 1e-3)


def test_between_runs_finds_the_spread_the_runs_own_errors_do_not_explain():
    from milling_twin.orchestrator.calibrate.statistics import between_runs

    agree = between_runs([1.0, 1.1, 0.9, 1.05], [0.1, 0.1, 0.1, 0.1])
    assert agree.tau == 0.0 and agree.i2 == 0.0 and agree.mean == pytest.approx(1.0125)
    assert agree.standard_error == pytest.approx(0.05)  # 0.1 / sqrt(4)
    apart = between_runs([1.0, 2.0, 3.0], [0.1, 0.1, 0.1])  # spread 1, errors 0.1: almost all between runs
    assert apart.tau == pytest.approx(1.0, rel=0.01) and apart.i2 > 0.98 and apart.mean == pytest.approx(2.0)
    low, high = apart.interval(1.0, 0.1)
    assert high > 2.9 and low < -0.9  # a run's interval widened by the spread reaches the others
    with pytest.raises(ValueError, match="at least two runs"):
        between_runs([1.0], [0.1])


def test_the_report_says_how_the_runs_agree(outcome):
    agreement = outcome.extra["agreement"]["power.k_speed_loop"]
    assert len(agreement.identifying) >= 2 and agreement.overlap[1] >= 1
    table = next(t for t in outcome.tables if t.title.startswith("Estimates"))
    row = next(r for r in table.rows if r[0] == "power.k_speed_loop")
    assert "spread" in row[3] and "runs identify it" in row[4]

"""``[alignment]``: comparisons on the recording's own samples mapped to simulated time (orchestrator/report.py),
and the scenario's checks of the section (orchestrator/scenario.py)."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

import milling_twin
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario

ALIGNMENT = """
[alignment]
recorded = ["x_actual", "y_actual", "z_actual"]
simulated = ["interp.x", "interp.y", "interp.z"]
"""


def _umich_motion(repo_root: Path, tmp_path: Path, extra: str, name: str) -> Path:
    """scenarios/umich_motion.toml (the Interpolator on UMich run 01's program against the recorded positions)
    with its files named by absolute paths, ``extra`` appended, in tmp_path."""
    folder = repo_root / "scenarios"
    text = (folder / "umich_motion.toml").read_text()
    text = text.replace('name = "umich_motion"', f'name = "{name}"')
    for relative in ('"programs/', '"data/'):
        assert relative in text
        text = text.replace(relative, f'"{folder.as_posix()}/{relative[1:]}')
    path = tmp_path / f"{name}.toml"
    path.write_text(text + extra)
    return path


def test_aligned_comparison_pairs_each_recorded_sample_with_its_simulated_moment(repo_root: Path, fmu_dir: Path,
                                                                                 tmp_path: Path) -> None:
    """The recording starts before the motion and the program has no dwells: at equal times the positions differ
    by up to several mm; aligned, the RMS error of every axis falls (by more than half), the time map is written
    and summarised."""
    plain = _umich_motion(repo_root, tmp_path, "", "plain_times")
    aligned = _umich_motion(repo_root, tmp_path, ALIGNMENT, "aligned_times")
    before = milling_twin.simulate(plain, fmu_dir=fmu_dir, out=tmp_path).report
    after = milling_twin.simulate(aligned, fmu_dir=fmu_dir, out=tmp_path).report
    assert before is not None and after is not None
    for b, a in zip(before.comparisons, after.comparisons):
        assert a.simulated == b.simulated and a.n_samples > 1000
        assert a.rms_error < 0.5 * b.rms_error, (a.simulated, a.rms_error, b.rms_error)
    doc = json.loads((tmp_path / "aligned_times" / "report.json").read_text())
    assert doc["alignment"]["method"] == "multiscale" and doc["alignment"]["samples"] > 1000
    table = pd.read_csv(tmp_path / "aligned_times" / "time_map.csv")
    assert list(table.columns) == ["recorded_time", "simulated_time", "confidence"]
    assert table["simulated_time"].is_monotonic_increasing


@pytest.mark.parametrize("section, key, message", [
    ('[alignment]\nrecorded = ["x_actual", "y_actual"]\nsimulated = ["interp.x"]\n',
     "[alignment].simulated", "expected 2 or 3 names (x, y[, z]), got ['interp.x']"),
    ('[alignment]\nrecorded = ["x_actual", "y_actual"]\nsimulated = ["interp.x", "interp.y", "interp.z"]\n',
     "[alignment].simulated", "3 outputs for 2 recorded channels: give one per axis"),
    ('[alignment]\nrecorded = ["x_actual", "wrong"]\nsimulated = ["interp.x", "interp.y"]\n',
     "[alignment].recorded[1]", "unknown recorded channel 'wrong'; channels: x_actual, y_actual, z_actual, line"),
    ('[alignment]\nrecorded = ["x_actual", "y_actual"]\nsimulated = ["interp.x", "interp.feed"]\n',
     "[alignment].simulated[1]", "aligns positions: 'y_actual' (m) and interp.feed (m/s) must both be lengths"),
    ('[alignment]\nrecorded = ["x_actual", "y_actual"]\nsimulated = ["interp.x", "interp.y"]\nmethod = "best"\n',
     "[alignment].method", "'best': expected one of multiscale, patent, dtw"),
])
def test_alignment_errors_name_the_key(repo_root: Path, fmu_dir: Path, tmp_path: Path, section: str, key: str,
                                       message: str) -> None:
    path = _umich_motion(repo_root, tmp_path, "\n" + section, "bad_alignment")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path, fmu_dir)
    assert f"{path}: {key}: {message}" in str(err.value)

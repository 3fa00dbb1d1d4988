"""orchestrator/validation/slot_milling.py: on synthetic recordings made from the model (it must recover
the tool that made them), its data-folder rules, and on the real recordings in ../shared when present."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import fmu_dir, require_fmu
from milling_twin import datasets
from milling_twin.cli import main
from milling_twin.models.cutting_force import CUTTING_FORCE
from milling_twin.orchestrator.validation import slot_milling as sm

FEEDS = (300, 600, 900, 1200, 1500)  # mm/min, as the recordings
TOOL = {"Ktc": 950e6, "Krc": 250e6, "Kac": 150e6, "Kte": 16e3, "Kre": 19e3, "Kae": 18e3}  # N/m2, N/m


def write_dynoware(path: Path, t: np.ndarray, forces: np.ndarray) -> None:
    """A file laid out like a DynoWare export: 18 header lines, the column and unit lines, data."""
    header = ["DynoWare,Version 2.5.1.2", f"Filename:,{path.stem}.dwd", "Sampling rate [Hz]:,10000",
              f"Samples per channel:,{len(t)}"] + [f"Note {i}:, " for i in range(14)]
    rows = [f"{ti:.4f},{fx:.6g},{fy:.6g},{fz:.6g}" for ti, (fx, fy, fz) in zip(t, forces)]
    path.write_text("\n".join(header + ["Time,Fx,Fy,Fz", "s,N,N,N"] + rows) + "\n")


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> Path:
    """Five recordings of a known tool (TOOL, 25 mm, 30 deg helix as the scenario assumes), 0.5 s at
    10 kHz starting at an arbitrary spindle angle, in the files' axes (Fx cross-feed, Fy feed)."""
    folder = tmp_path_factory.mktemp("slot_data")
    t = 3.0 + np.arange(5000) * 1e-4
    omega = 6000 * 2 * math.pi / 60
    for feed in FEEDS:
        angle = np.mod(1.234 + omega * (t - t[0]), 2 * math.pi)
        out = CUTTING_FORCE.evaluate(**TOOL, n_flutes=2, tool_diameter=0.025, helix_angle=math.radians(30),
                                     spindle_speed=omega, feed_velocity_x=feed / 60_000, axial_depth=0.003,
                                     angle=angle, delayed_displacement_x=0.0, delayed_displacement_y=0.0)
        forces = np.column_stack([out["Fy"], out["Fx"], out["Fz"]])
        write_dynoware(folder / f"6-n6000f{feed}ap3ae25.csv", t, forces)
    (folder / "README.md").write_text("synthetic\n")
    return folder


def test_reads_a_dynoware_export(synthetic: Path) -> None:
    recording = datasets.read_recording(synthetic / "6-n6000f900ap3ae25.csv")
    assert (recording.rpm, recording.feed, recording.axial_depth, recording.radial_depth) == (6000, 900, 3, 25)
    assert recording.sample_rate == 10000 and recording.forces.shape == (5000, 3)
    assert recording.time[0] == 3.0


def test_recovers_the_synthetic_tool(synthetic: Path, tmp_path: Path) -> None:
    require_fmu(fmu_dir() / "CuttingForce.fmu")
    doc = sm.validate(synthetic, sm.DEFAULT_SCENARIO, fmu_dir(), tmp_path)
    assert doc["coefficients"]["identified_from_recorded_means"] == pytest.approx(TOOL, rel=0.01)
    assert [c["feed_mm_per_min"] for c in doc["cases"]] == list(FEEDS)
    for case in doc["cases"]:
        fit = case["identified"]
        assert max(abs(e) for e in fit["mean_relative_error"].values()) < 0.01, case
        assert min(fit["waveform_r2"].values()) > 0.99, case
        # two flutes, no runout: the waveform repeats every half revolution, so the phase is known mod 180 deg
        expected = math.degrees(1.234) % 180
        assert min(abs(fit["phase_shift_deg"] % 180 - expected), 180 - abs(fit["phase_shift_deg"] % 180 - expected)) < 0.5
        prior = case["prior"]  # the scenario's literature coefficients are another tool
        assert max(abs(e) for e in prior["mean_relative_error"].values()) > 0.05
    written = json.loads((tmp_path / "slot_milling" / "slot_milling.json").read_text())
    assert written["axes"] == {"recorded Fx": "simulated force.Fy", "recorded Fy": "simulated force.Fx",
                               "recorded Fz": "simulated force.Fz"}
    for name in ("means.png", "waveforms_prior.png", "waveforms_identified.png"):
        assert (tmp_path / "slot_milling" / name).stat().st_size > 10_000


def test_missing_data_says_where_to_put_it(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.delenv(datasets.DATA_ENV, raising=False)
    missing = tmp_path / "nowhere"
    assert main(["validate", "slot-milling", "--data", str(missing), "--out", str(tmp_path / "out")]) == 2
    message = capsys.readouterr().err
    for part in (f"no slot-milling recordings in {missing} (from --data)", str(datasets.DEFAULT_DATA), "--data DIR",
                 f"{datasets.DATA_ENV}=DIR", "leekunhwee/ForceCalculation", "never copy them into the repository"):
        assert part in message, message
    assert not (tmp_path / "out").exists()


def test_the_environment_variable_names_the_folder(synthetic: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv(datasets.DATA_ENV, str(synthetic))
    assert datasets.data_dir() == synthetic
    with pytest.raises(datasets.DataMissing, match="from --data"):  # an option wins over the variable
        datasets.data_dir(tmp_path)
    monkeypatch.setenv(datasets.DATA_ENV, str(tmp_path))
    with pytest.raises(datasets.DataMissing, match=f"from \\${datasets.DATA_ENV}"):
        datasets.data_dir()


REAL_DATA = Path(__import__("os").environ.get(datasets.DATA_ENV) or datasets.DEFAULT_DATA)


@pytest.mark.skipif(not REAL_DATA.is_dir(), reason=f"the measured slot-milling recordings are not in {REAL_DATA}: "
                    f"put them there (see orchestrator/validation/slot_milling.py) or set {datasets.DATA_ENV}")
def test_real_recordings(tmp_path: Path) -> None:
    """The five Kistler recordings: what the model achieves today, as a floor (numbers in docs/validation.md)."""
    require_fmu(fmu_dir() / "CuttingForce.fmu")
    doc = sm.validate(datasets.data_dir(REAL_DATA), sm.DEFAULT_SCENARIO, fmu_dir(), tmp_path)
    assert [c["feed_mm_per_min"] for c in doc["cases"]] == list(FEEDS)
    for case in doc["cases"]:
        prior, fit = case["prior"], case["identified"]
        for axis in ("Fx", "Fy", "Fz"):  # the axis mapping and sign convention: the means agree in sign
            assert np.sign(prior["simulated_mean_N"][axis]) == np.sign(prior["recorded_mean_N"][axis]), case
        assert max(abs(e) for e in fit["mean_relative_error"].values()) < 0.2, case
        assert fit["waveform_r2"]["Fx"] > 0.25 and fit["waveform_r2"]["Fy"] > 0.5, case
        assert 0 < case["feed_per_tooth_mm"] <= 0.125
    assert (tmp_path / "slot_milling" / "slot_milling.json").is_file()

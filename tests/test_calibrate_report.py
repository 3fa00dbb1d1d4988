"""The whole loop on a synthetic power case: simulate, fit, write the parameter set, re-simulate, report."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from milling_twin.orchestrator.calibrate import calibrate
from cases.calibration_synthetic import POWER_TRUTH, write_power_case

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, fmu_dir: Path):
    folder = tmp_path_factory.mktemp("loop")
    spec = write_power_case(folder / "case", fmu_dir=fmu_dir, noise=5.0, seed=1)
    return calibrate(spec, fmu_dir, folder / "out", progress=False)


def test_the_report_is_self_contained(calibrated) -> None:
    html = calibrated.report_html.read_text()
    assert calibrated.report_html.name == "report.html" and calibrated.report_md.is_file()
    images = re.findall(r"<img [^>]*src='([^']*)'", html)
    assert len(images) >= 6 and all(src.startswith("data:image/png;base64,") for src in images)
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", html)
    assert not re.search(r"(https?:|src='(?!')|href=|//[a-z]|<script|<link|<iframe|@import|url\()", text, re.IGNORECASE)
    for heading in ("Parameters", "Directions of the parameter space", "Errors of the FMU simulation",
                    "Solver starts", "Time per stage", "Identities", "Correlation matrix", "Solver trace"):
        assert heading in html, heading
    assert "sha256" in html and "instantiation_token" in html
    md = calibrated.report_md.read_text()
    assert "| power.c3 |" in md and "![" in md
    for link in re.findall(r"\]\((figures/[^)]+)\)", md):
        assert (calibrated.out_dir / link).is_file()
    doc = json.loads((calibrated.out_dir / "calibration.json").read_text())
    assert [p["name"] for p in doc["parameters"]] == list(POWER_TRUTH)


def test_the_truth_lies_in_the_intervals_and_validation_error_drops(calibrated) -> None:
    st = calibrated.fit.statistics
    for name, value in POWER_TRUTH.items():
        p = st.by_name(name)
        assert p.ci_low <= value <= p.ci_high, (name, p)
        assert p.identifiable
    errors = {(e.output, e.dataset): e for e in calibrated.errors}
    for dataset in ("learning", "validation"):
        e = errors[("power.P_total", dataset)]
        assert e.rms_after < 0.1 * e.rms_before, e  # from the scenario's wrong priors to the noise level
        assert e.rms_after == pytest.approx(5.0, rel=0.25)


def test_the_parameter_set_round_trips(calibrated, fmu_dir: Path) -> None:
    """The written set, applied by name, gives the FMUs exactly the estimates (repr round trip)."""
    from milling_twin.orchestrator.scenario import load_scenario
    case = calibrated.spec.scenario
    scenario = load_scenario(case, fmu_dir, parameter_sets=[calibrated.parameter_set])
    applied = scenario.instance("power").parameters
    for q, value in zip(calibrated.fit.parameters, calibrated.fit.theta):
        assert applied[q.name.split(".")[1]] == value
    assert calibrated.parameter_set == calibrated.out_dir / "power_case.params.toml"
    assert not (calibrated.spec.parameter_set).exists()  # the spec's place changes only with write_set
    text = calibrated.parameter_set.read_text()
    assert "[parameters.power]" in text and "95 % CI" in text and "spec_sha256" in text
    ssv = calibrated.ssv.read_text()
    assert 'name="power.c3"' in ssv and "ssv:ParameterSet" in ssv


def test_the_command_line(tmp_path: Path, fmu_dir: Path) -> None:
    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir, noise=5.0, seed=2)
    done = subprocess.run([sys.executable, "-m", "milling_twin", "calibrate", str(spec), "--fmu-dir", str(fmu_dir),
                           "--out", str(tmp_path / "out"), "--no-progress"], cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "power.P_total on validation" in done.stdout and "report:" in done.stdout
    assert (tmp_path / "out" / "calibration" / "power_case" / "report.html").is_file()
    spec.write_text(spec.read_text().replace('[parameters."power.c3"]', '[parameters."power.c9"]'))
    bad = subprocess.run([sys.executable, "-m", "milling_twin", "calibrate", str(spec), "--fmu-dir", str(fmu_dir),
                          "--out", str(tmp_path / "out"), "--no-progress"], cwd=REPO, capture_output=True, text=True)
    assert bad.returncode == 2 and '[parameters."power.c9"]: unknown parameter' in bad.stderr


def test_alignment_effect_is_reported(tmp_path: Path, fmu_dir: Path) -> None:
    """With an alignment method the report shows how far the map is from the identity and what it changed."""
    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir, noise=5.0, seed=3)
    spec.write_text(spec.read_text() + '\n[alignment]\nmethod = "dtw"\nsimulated = ["power.spindle_speed", '
                                       '"mrr.feed_velocity_x", "mrr.feed_velocity_y"]\nrecorded = ["speed", "vx", "vy"]\n')
    result = calibrate(spec, fmu_dir, tmp_path / "out", progress=False)
    assert result.alignment.method == "dtw" and result.alignment.paired > 0
    table = next(t for t in result.tables if t.title.startswith("What the alignment"))
    assert [row[0] for row in table.rows] == list(POWER_TRUTH)
    assert np.isfinite(result.alignment.max_shift)


def _assert_readable(fig) -> None:
    """Drawn as the report draws it: no offset text on any axis (matplotlib's "1e-9+1.7695e2" lands over the
    axis label) and tick labels that differ from each other."""
    from milling_twin.orchestrator.calibrate.plots import figure_png

    figure_png(fig)
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            assert axis.get_offset_text().get_text() == "", (ax.get_title(), axis.get_offset_text().get_text())
            labels = [t.get_text() for t in axis.get_ticklabels() if t.get_text()]
            assert len(labels) == len(set(labels)), labels


def _series(recorded: np.ndarray, before: np.ndarray, after: np.ndarray):
    from milling_twin.orchestrator.calibrate.result import Series

    return Series("power.P_total", "power", "validation", np.arange(recorded.size) * 0.1, recorded, before, after,
                  "W", "W", 1.0)


@pytest.mark.parametrize("jitter", [0.0, 1e-9, 1e-12])
def test_figures_of_constant_values_have_readable_axes(jitter: float) -> None:
    """Simulated values constant (exactly, or to rounding as in the UMich validation layer): the axis of the
    simulated values spans +-5 % around them; errors at rounding level of noise-free data are drawn as 0 on
    +-5 % of the data's size."""
    from milling_twin.orchestrator.calibrate.plots import fit_figure, residual_figure

    k = np.arange(300)
    simulated = 176.95 + jitter * (k % 3)
    noisy = _series(simulated + np.random.default_rng(0).normal(0.0, 20.0, k.size), simulated, simulated)
    fig = residual_figure([noisy])
    _assert_readable(fig)
    lo, hi = fig.axes[1].get_xlim()  # residual against the simulated value
    assert lo < 176.95 < hi and hi - lo == pytest.approx(0.1 * 176.95, rel=1e-6)
    _assert_readable(fit_figure([noisy]))
    exact = _series(simulated, simulated + 1e-13 * (k % 2), simulated)  # a noise-free fit: errors of rounding
    fig = fit_figure([exact])
    _assert_readable(fig)
    lo, hi = fig.axes[1].get_ylim()  # the errors
    assert lo < 0 < hi and hi - lo == pytest.approx(0.1 * np.abs(simulated).max(), rel=1e-3)
    _assert_readable(residual_figure([exact]))
    zero = _series(np.zeros(k.size), np.zeros(k.size), np.zeros(k.size))
    for fig in (fit_figure([zero]), residual_figure([zero])):
        _assert_readable(fig)


def test_a_calibration_with_constant_simulated_power_reports_readable_figures(tmp_path: Path, fmu_dir: Path) -> None:
    """Over the validation window the spindle turns at a constant speed and feed, so the simulated power is
    constant to rounding there (as in UMich's last layer): every figure of the report is readable."""
    from milling_twin.orchestrator.calibrate.plots import fit_figure, residual_figure

    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir, noise=5.0, seed=6, steady_from=290)
    spec.write_text(spec.read_text().replace("starts = 3", "starts = 1"))
    result = calibrate(spec, fmu_dir, tmp_path / "out", progress=False)
    validation = [s for s in result.series if s.dataset == "validation"]
    after = validation[0].after
    assert 0 < np.ptp(after) < 1e-9 * np.abs(after).max()  # constant to rounding, as UMich's 1e-9 W in 177 W
    for fig in (fit_figure(validation), residual_figure(validation)):
        _assert_readable(fig)
    lo, hi = residual_figure(validation).axes[1].get_xlim()
    assert hi - lo > 0.09 * np.abs(after).max()
    assert result.report_html.is_file()

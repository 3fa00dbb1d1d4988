"""The chatter validation's pieces: analytic limit from the scenario, and chatter read from the
co-simulation alone (the full sweep is `milling-twin validate chatter`)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import fmu_dir, repo_root
from milling_twin.cli import main
from milling_twin.models.stability import Mode, stability_lobes
from milling_twin.orchestrator.scenario import load_scenario
from milling_twin.orchestrator.validation import chatter

SCENARIO = repo_root() / "scenarios" / "chatter.toml"


def test_analytic_limit_uses_the_scenarios_coefficients_and_modes() -> None:
    base = load_scenario(SCENARIO, fmu_dir())
    mode = Mode(922.0, 0.011, 1.34e6)
    expected = stability_lobes((mode,), (mode,), 767.01e6, 168.8e6, 2, lobes=60).limit([6000.0, 16000.0])
    assert chatter.analytic_limit(base, np.array([6000.0, 16000.0])) == pytest.approx(expected, rel=1e-12)


def test_one_speed_bisection_brackets_the_analytic_limit(tmp_path: Path) -> None:
    """6000 rpm, 3 bisection steps: stable at half the limit, chatter at twice, and the simulated
    limit within 10 % of the analytic one (-4.6 % with 8 steps)."""
    assert main(["validate", "chatter", "--speeds", "6000", "--iterations", "3", "--out", str(tmp_path),
                 "--fmu-dir", str(fmu_dir())]) == 0
    report = json.loads((tmp_path / "chatter" / "chatter.json").read_text())
    (limit,) = report["limits"]
    low, high = limit["bracket"]
    assert low < limit["simulated"] < high and high - low == pytest.approx(1.5 * limit["analytic"] / 8)
    assert abs(limit["relative_difference"]) < 0.1
    cuts = report["cuts"]
    assert cuts[0]["stable"] and cuts[0]["growth"] < 0.5  # half the limit: the entry transient dies out
    assert not cuts[1]["stable"] and cuts[1]["growth"] > 2  # twice the limit: chatter grows
    assert (tmp_path / "chatter" / "chatter.png").stat().st_size > 10_000


def test_multiple_regeneration_bounds_the_chatter_one_delay_lets_grow(tmp_path: Path) -> None:
    """scenarios/chatter.toml at 0.1 mm, about 2.5 times its stability limit: with one delay (the delay equation)
    the vibration grows to 0.76 mm in 0.2 s, each flute cutting material that the flutes thrown out of the cut
    before it would have left; with the surface the thinnest of the last three (regeneration_passes = 3) the chatter
    is the same at first and settles into a limit cycle near 0.08 mm (of a 0.05 mm feed per tooth)."""
    from milling_twin.api import simulate
    from milling_twin.orchestrator.scenario import with_values

    base = load_scenario(SCENARIO, fmu_dir())
    amplitude = {}
    for passes in (1, 3):
        case = with_values(base, {"force.axial_depth": 1e-4, "force.regeneration_passes": passes},
                           name=f"passes_{passes}")
        frame = simulate(case, out=tmp_path, stepping="fast", progress=False).frame
        r = np.hypot(frame["vibration.tip_displacement_x"], frame["vibration.tip_displacement_y"]).to_numpy()
        t = frame["time"].to_numpy()
        amplitude[passes] = [r[(t >= start) & (t < start + 0.025)].max() for start in (0.025, 0.125, 0.175)]
    single, three = amplitude[1], amplitude[3]
    assert three[0] == pytest.approx(single[0], rel=0.1)  # chatter sets in alike (27 and 28 um)
    assert single[2] > 5e-4 and single[2] > 1.5 * single[1]  # one delay: still growing (0.30 -> 0.76 mm)
    assert three[2] < 1.5e-4 and abs(three[2] / three[1] - 1) < 0.05  # three: a limit cycle (0.080 mm)

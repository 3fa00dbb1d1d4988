"""SpindlePower's spindle dynamics (models/power.py): the definition without them is the static model, the
speed-rate state, and the calibration graph deciding "dynamic" from what the fitted outputs depend on. The FMU's
side (the same numbers over a speed ramp) is in tests/test_fmu_compliance.py."""
from __future__ import annotations

from pathlib import Path
from typing import NoReturn

import numpy as np
import pytest

from milling_twin.models.power import MRR_REFERENCE, POWER
from milling_twin.orchestrator.calibrate.graph import NotExpressible, build_graph
from milling_twin.orchestrator.scenario import Ref, load_scenario

STATES = ("previous_spindle_speed", "spindle_speed_rate", "has_previous_speed")


def random_points(count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every argument of the equations at random within its range (states included), booleans 0/1."""
    values = {}
    for v in POWER.of("parameter") + POWER.of("input"):
        values[v.name] = (rng.integers(0, 2, count).astype(float) if v.type == "Boolean"
                          else rng.uniform(v.min, v.max, count))
    values["previous_spindle_speed"] = rng.uniform(-1e4, 1e4, count)
    values["spindle_speed_rate"] = rng.uniform(-1e6, 1e6, count)
    values["has_previous_speed"] = rng.integers(0, 2, count).astype(float)
    return values


def test_without_dynamics_the_outputs_are_the_static_model() -> None:
    """J_spindle = k_speed_loop = 0: P_total = P_standby + on*(P_idle + c1*|n| + c2*(mrr/MRR_ref)^c3) whatever the
    states and the command, P_dynamic = 0; P_spindle and P_cutting are as they were."""
    v = random_points(500, np.random.default_rng(5))
    v["J_spindle"][:] = 0.0
    v["k_speed_loop"][:] = 0.0
    v["cutting_power_from_force"][:] = 0.0
    out = POWER.evaluate(**v)
    on, n = v["spindle_on"], v["spindle_speed"]
    spindle = on * (v["P_idle"] + v["c1"] * np.abs(n))
    cutting = on * v["c2"] * (v["mrr"] / MRR_REFERENCE) ** v["c3"]
    np.testing.assert_allclose(out["P_spindle"], spindle, rtol=1e-14)
    np.testing.assert_allclose(out["P_cutting"], cutting, rtol=1e-14)
    np.testing.assert_allclose(out["P_total"], v["P_standby"] + spindle + cutting, rtol=1e-14)
    assert np.all(out["P_dynamic"] == 0.0)
    np.testing.assert_array_equal(out["spindle_acceleration"], v["spindle_speed_rate"])


def test_cutting_power_from_force_replaces_the_mrr_term() -> None:
    """cutting_power_from_force: P_cutting = on * cutting_power / drive_efficiency, whatever the MRR; off: the MRR
    term, whatever cutting_power."""
    v = random_points(500, np.random.default_rng(7))
    from_force = v["cutting_power_from_force"] == 1.0
    out = POWER.evaluate(**v)
    on = v["spindle_on"]
    expected = np.where(from_force, on * v["cutting_power"] / v["drive_efficiency"],
                        on * v["c2"] * (v["mrr"] / MRR_REFERENCE) ** v["c3"])
    assert from_force.any() and (~from_force).any()
    np.testing.assert_allclose(out["P_cutting"], expected, rtol=1e-14)


def test_dynamic_power_is_inertia_plus_speed_loop_while_the_spindle_runs() -> None:
    v = random_points(500, np.random.default_rng(6))
    out = POWER.evaluate(**v)
    on, n, rate = v["spindle_on"], v["spindle_speed"], v["spindle_speed_rate"]
    dynamic = on * (v["J_spindle"] * n * rate + v["k_speed_loop"] * (v["spindle_speed_command"] - n) * np.abs(n))
    np.testing.assert_allclose(out["P_dynamic"], dynamic, rtol=1e-12, atol=1e-6)
    static = POWER.evaluate(**{**v, "J_spindle": 0.0, "k_speed_loop": 0.0})["P_total"]
    np.testing.assert_allclose(out["P_total"], static + dynamic, rtol=1e-12, atol=1e-3)
    assert np.all(out["P_dynamic"][on == 0] == 0.0) and np.any(out["P_dynamic"][on == 1] != 0.0)


def test_the_rate_is_zero_on_the_first_step_then_the_change_over_the_step() -> None:
    h = 0.1
    states = {s.name: s.start for s in POWER.states}
    assert states == dict.fromkeys(STATES, 0.0)
    seen = []
    for n in (300.0, 300.0, 320.0, 350.0, 350.0, 330.0):  # rad/s, held over each step
        states = {k: float(x) for k, x in POWER.step(h, spindle_speed=n, **states).items()}
        assert states["previous_spindle_speed"] == n and states["has_previous_speed"] == 1.0
        seen.append(states["spindle_speed_rate"])
    # the first step has no previous speed: 0, not 300/0.1
    assert seen == pytest.approx([0.0, 0.0, 200.0, 300.0, 0.0, -200.0], abs=1e-9)


# ---- the calibration graph: stateless unless the fitted outputs read the states ----


def _fail(key: str, message: str) -> NoReturn:
    raise AssertionError(f"{key}: {message}")


def _graph(scenario, parameters: list[str], outputs: list[str] = ["power.P_total"]):  # noqa: B006
    refs = [Ref.parse(p) for p in parameters]
    outs = [Ref.parse(o) for o in outputs]
    return build_graph(scenario, refs, outs, _fail, {r: str(r) for r in refs + outs})


@pytest.fixture
def power_case(make_case, fmu_dir: Path):
    """The two-FMU case (power at 0.1 s, recorded every 0.1 s) with extra SpindlePower parameters."""
    def load(extra: str = "", output_interval: str = "0.1"):
        path = make_case(("c3 = 1.0\n", "c3 = 1.0\n" + extra),
                         ("output_interval = 0.1", f"output_interval = {output_interval}"))
        return load_scenario(path, fmu_dir)
    return load


def test_graph_with_the_dynamics_off_is_stateless(power_case) -> None:
    """J_spindle and k_speed_loop at 0 and not fitted: P_total reads no state once the constants are folded, so
    the fit is stateless (it needs no recording of every step), as before the dynamics existed."""
    scenario = power_case(output_interval="0.2")  # not every step: a dynamic fit would be refused
    graph = _graph(scenario, ["power.P_standby", "power.P_idle", "power.c1"])
    assert graph.dynamic is None and graph.sample is not None
    graph = _graph(scenario, ["power.k_speed_loop"])  # the speed loop reads no state either
    assert graph.dynamic is None
    assert "power.spindle_speed_command" in [c.ref for c in graph.data]


def test_graph_is_dynamic_when_the_inertia_term_is_on(power_case) -> None:
    """J_spindle fitted, or set to a non-zero value with P_idle fitted: P_total reads the speed-rate state, so the
    graph steps the states (all three: the rate's update reads the previous speed and the first-step flag)."""
    for scenario, parameters in ((power_case(), ["power.J_spindle"]),
                                 (power_case("J_spindle = 1.5e-3\n"), ["power.P_idle"])):
        graph = _graph(scenario, parameters)
        assert graph.sample is None and graph.dynamic is not None
        assert graph.dynamic.states == STATES and graph.dynamic.step_size == 0.1
    with pytest.raises(NotExpressible, match="must record every step"):
        _graph(power_case("J_spindle = 1.5e-3\n", output_interval="0.2"), ["power.P_idle"])


def test_dynamic_graph_steps_like_the_model(power_case) -> None:
    """The graph's step function over a speed ramp gives what models/power.py (and so the FMU) gives."""
    graph = _graph(power_case("k_speed_loop = 0.076\n"), ["power.J_spindle", "power.P_idle"])
    columns = [c.ref for c in graph.data]
    h, theta = 0.1, [1.5e-3, 170.0]
    speeds = [0.0, 0.0, 62.8, 125.7, 188.5, 251.3, 314.2, 335.0, 334.0, 0.0]
    x = graph.dynamic.initial
    expected_states = {s.name: s.start for s in POWER.states}
    for n in speeds:
        row = {"power.spindle_speed": n, "power.spindle_on": 1.0, "power.mrr": 0.0,
               "power.spindle_speed_command": 335.0, "power.cutting_power": 0.0}
        x, y = graph.dynamic.step(x, theta, [row[c] for c in columns])
        values = dict(P_standby=100.0, P_idle=170.0, c1=0.5, c2=1000.0, c3=1.0, J_spindle=1.5e-3, k_speed_loop=0.076,
                      spindle_speed=n, spindle_on=1.0, mrr=0.0, spindle_speed_command=335.0,
                      cutting_power=0.0, cutting_power_from_force=0.0, drive_efficiency=0.85)
        expected_states = {k: float(v) for k, v in POWER.step(h, **values, **expected_states).items()}
        expected = float(POWER.evaluate(**values, **expected_states)["P_total"])
        assert float(y) == pytest.approx(expected, rel=1e-13)

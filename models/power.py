"""Spindle power model of the process-simulation method:

    P = P_standby + P_idle + c1*n + c2*(MRR/MRR_ref)^c3

``P_standby`` is drawn whenever the machine is on; the spindle terms (idle power, the
speed-proportional term and the cutting term) only while the spindle runs. ``n`` enters as
its magnitude, so M4 (reverse) costs the same as M3. The cutting term uses MRR relative to
MRR_ref = 1 cm^3/s: that keeps ``c2`` in watts (the cutting power at 1 cm^3/s) whatever the
exponent ``c3``, and keeps both of order one for the optimiser.
"""
from __future__ import annotations

from typing import Mapping

import casadi as ca

from milling_twin.models.definition import ModelDefinition, Variable

MRR_REFERENCE = 1e-6  # m^3/s, = 1 cm^3/s


def equations(v: Mapping[str, ca.SX]) -> dict[str, ca.SX]:
    running = v["spindle_on"]
    spindle = running * (v["P_idle"] + v["c1"] * ca.fabs(v["spindle_speed"]))
    cutting = running * v["c2"] * (v["mrr"] / MRR_REFERENCE) ** v["c3"]
    return {
        "P_total": v["P_standby"] + spindle + cutting,
        "P_spindle": spindle,
        "P_cutting": cutting,
    }


POWER = ModelDefinition(
    identifier="SpindlePower",
    description="Machine-tool power: standby + spindle idle + speed term + material-removal term",
    default_step_size=1e-3,
    default_stop_time=10.0,
    equations=equations,
    variables=(
        Variable("P_standby", "Float64", "parameter", "Standby power of the machine (always drawn)",
                 unit="W", display_unit="kW", start=500.0, min=0.0, max=1e5),
        Variable("P_idle", "Float64", "parameter", "Extra power while the spindle runs, independent of speed",
                 unit="W", display_unit="kW", start=200.0, min=0.0, max=1e5),
        Variable("c1", "Float64", "parameter", "Speed-proportional spindle power coefficient",
                 unit="W.s/rad", display_unit="W/rpm", start=0.3, min=0.0, max=1e3),
        Variable("c2", "Float64", "parameter", "Cutting power at a material removal rate of 1 cm3/s",
                 unit="W", display_unit="kW", start=1500.0, min=0.0, max=1e6),
        Variable("c3", "Float64", "parameter", "Exponent of the material removal rate",
                 unit="", start=0.9, min=0.1, max=3.0),
        Variable("spindle_speed", "Float64", "input", "Spindle speed (sign gives the direction)",
                 unit="rad/s", display_unit="rpm", start=0.0, min=-1e4, max=1e4),
        Variable("mrr", "Float64", "input", "Material removal rate",
                 unit="m3/s", display_unit="cm3/min", start=0.0, min=0.0, max=1e-2),
        Variable("spindle_on", "Boolean", "input", "Spindle running (M3/M4) or stopped (M5)", start=True),
        Variable("P_total", "Float64", "output", "Total electrical power", unit="W", display_unit="kW"),
        Variable("P_spindle", "Float64", "output", "Spindle power without cutting (idle + speed term)",
                 unit="W", display_unit="kW"),
        Variable("P_cutting", "Float64", "output", "Cutting power (material-removal term)",
                 unit="W", display_unit="kW"),
    ),
)

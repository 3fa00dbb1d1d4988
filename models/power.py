"""Spindle power model of the process-simulation method, with the spindle's dynamics:

    P_total   = P_standby + P_spindle + P_cutting + P_dynamic
    P_spindle = on * (P_idle + c1*|n|)
    P_cutting = on * c2*(MRR/MRR_ref)^c3                    (cutting_power_from_force false, the default)
    P_cutting = on * cutting_power / drive_efficiency       (cutting_power_from_force true)
    P_dynamic = on * (J_spindle * n * dn/dt + k_speed_loop * (n_cmd - n) * |n|)

``P_standby`` is drawn whenever the machine is on; the spindle terms (idle power, the
speed-proportional term, the cutting term and the dynamic term) only while the spindle runs
(``on`` = ``spindle_on``: after M5 the drive brakes into its resistor and reports ~0 W). ``n``
(``spindle_speed``, rad/s) enters the static terms as its magnitude, so M4 (reverse) costs the same as
M3. The cutting term uses MRR relative to MRR_ref = 1 cm^3/s: that keeps ``c2`` in watts (the cutting
power at 1 cm^3/s) whatever the exponent ``c3``, and keeps both of order one for the optimiser.

The cutting term comes from one of two models, chosen by the parameter ``cutting_power_from_force``: the
material-removal term above (an empirical law fitted to a machine's power recordings), or the mechanical
cutting power a force model computes (CuttingForce's or ForceNet's ``power`` = torque x spindle speed, the
input ``cutting_power``) divided by the efficiency of the spindle motor and drive, so the electrical power
follows the forces the whole-part scenario predicts (``drive_efficiency`` 0.85 is a typical value for a
spindle motor and its drive, not a measured one: calibrate it against a power recording).

The dynamic term has two parts, both 0 at their default parameters (the model is then the static one):

* inertia: ``J_spindle * n * dn/dt`` (kg.m2), the power that accelerates the rotor, e.g. the run-up;
* speed loop: ``k_speed_loop * (n_cmd - n) * |n|`` (N.m.s/rad = W.s2/rad2): the torque
  ``k_speed_loop * (n_cmd - n)`` the drive's speed controller adds for the speed error against the
  command ``n_cmd`` (``spindle_speed_command``), times the speed.

``dn/dt`` is the rate of change of the spindle speed over the last step, ``(n - n_previous) / h``, a
state (``spindle_speed_rate``, also the output ``spindle_acceleration``): over a co-simulation step
of size h the inputs are held, so ``update`` stores the speed held over the step (``previous_spindle_speed``)
and the rate from the one held over the step before. Before the first step there is no previous speed
(``has_previous_speed`` = 0): that step's rate is 0, not n/h. The outputs after a step read the states
after it: y_k = equations(inputs held over the step ending at t_k, states after that step).
"""
from __future__ import annotations

from typing import Mapping

import casadi as ca

from milling_twin.models.definition import ModelDefinition, State, Variable

MRR_REFERENCE = 1e-6  # m^3/s, = 1 cm^3/s


def equations(v: Mapping[str, ca.SX]) -> dict[str, ca.SX]:
    running = v["spindle_on"]
    n = v["spindle_speed"]
    spindle = running * (v["P_idle"] + v["c1"] * ca.fabs(n))
    from_mrr = v["c2"] * (v["mrr"] / MRR_REFERENCE) ** v["c3"]
    from_force = v["cutting_power"] / v["drive_efficiency"]
    cutting = running * ca.if_else(v["cutting_power_from_force"], from_force, from_mrr)
    rate = v["spindle_speed_rate"]
    dynamic = running * (v["J_spindle"] * n * rate
                         + v["k_speed_loop"] * (v["spindle_speed_command"] - n) * ca.fabs(n))
    return {
        "P_total": v["P_standby"] + spindle + cutting + dynamic,
        "P_spindle": spindle,
        "P_cutting": cutting,
        "spindle_acceleration": rate,
        "P_dynamic": dynamic,
    }


def update(v: Mapping[str, ca.SX], h: ca.SX) -> dict[str, ca.SX]:
    """Over a step of size h with the spindle speed n held: the rate against the speed held over the
    previous step (0 on the first step, which has none), and n becomes the previous speed."""
    n = v["spindle_speed"]
    return {
        "previous_spindle_speed": n,
        "spindle_speed_rate": ca.if_else(v["has_previous_speed"], (n - v["previous_spindle_speed"]) / h, 0.0),
        "has_previous_speed": ca.SX(1.0),
    }


POWER = ModelDefinition(
    identifier="SpindlePower",
    description="Machine-tool power: standby + spindle idle + speed term + material-removal term "
                "+ spindle inertia and speed-loop term",
    default_step_size=1e-3,
    default_stop_time=10.0,
    equations=equations,
    update=update,
    states=(
        State("previous_spindle_speed", "Spindle speed held over the previous step", unit="rad/s"),
        State("spindle_speed_rate", "Rate of change of the spindle speed over the last step", unit="rad/s2"),
        State("has_previous_speed", "1 once a step has been taken (previous_spindle_speed holds a speed), else 0"),
    ),
    # The variables added with the dynamic term come last, so the others keep their value references.
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
        Variable("J_spindle", "Float64", "parameter",
                 "Moment of inertia of the spindle rotor and tool: inertia power J*n*dn/dt while the spindle runs "
                 "(0: no inertia term)", unit="kg.m2", start=0.0, min=0.0, max=10.0),
        Variable("k_speed_loop", "Float64", "parameter",
                 "Gain of the spindle drive's speed loop, torque per speed error: power "
                 "k*(n_command - n)*|n| while the spindle runs (0: no speed-loop term)",
                 unit="N.m.s/rad", start=0.0, min=0.0, max=100.0),
        Variable("spindle_speed_command", "Float64", "input",
                 "Commanded spindle speed (S word, sign gives the direction); read only by the speed-loop term",
                 unit="rad/s", display_unit="rpm", start=0.0, min=-1e4, max=1e4),
        Variable("spindle_acceleration", "Float64", "output",
                 "Rate of change of the spindle speed over the last step (0 before the second step)",
                 unit="rad/s2"),
        Variable("P_dynamic", "Float64", "output",
                 "Spindle inertia and speed-loop power (J*n*dn/dt + k*(n_command - n)*|n|, while the spindle runs)",
                 unit="W", display_unit="kW"),
        Variable("cutting_power_from_force", "Boolean", "parameter",
                 "Cutting term from the input cutting_power (a force model's torque x speed) / drive_efficiency "
                 "instead of the material-removal term c2*(MRR/MRR_ref)^c3", start=False),
        Variable("cutting_power", "Float64", "input",
                 "Mechanical cutting power at the tool (a force model's power output); used when "
                 "cutting_power_from_force is true", unit="W", display_unit="kW", start=0.0, min=-1e6, max=1e6),
        Variable("drive_efficiency", "Float64", "parameter",
                 "Efficiency of the spindle motor and drive: electrical cutting power = cutting_power / it",
                 unit="", start=0.85, min=0.05, max=1.0),
    ),
)

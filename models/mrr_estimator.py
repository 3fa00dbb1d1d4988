"""Material removal rate from the feed velocity and a constant engagement cross-section.

    MRR = a_e * a_p * |v_xy|   while cutting, else 0

The cheap stand-in for the workpiece (Z-map) model when only the path feed and the nominal
width and depth of cut are known, as in recorded machine data without the part program.
"""
from __future__ import annotations

from typing import Mapping

import casadi as ca

from milling_twin.models.definition import ModelDefinition, Variable


def equations(v: Mapping[str, ca.SX]) -> dict[str, ca.SX]:
    feed = ca.sqrt(v["feed_velocity_x"] ** 2 + v["feed_velocity_y"] ** 2)
    return {"mrr": v["cutting"] * v["width_of_cut"] * v["depth_of_cut"] * feed}


MRR_ESTIMATOR = ModelDefinition(
    identifier="MrrEstimator",
    description="Material removal rate from path feed and nominal width and depth of cut",
    default_step_size=1e-3,
    default_stop_time=10.0,
    equations=equations,
    variables=(
        Variable("width_of_cut", "Float64", "parameter", "Radial engagement a_e",
                 unit="m", display_unit="mm", start=0.005, min=0.0, max=0.5),
        Variable("depth_of_cut", "Float64", "parameter", "Axial depth of cut a_p",
                 unit="m", display_unit="mm", start=0.001, min=0.0, max=0.2),
        Variable("feed_velocity_x", "Float64", "input", "Feed velocity along X",
                 unit="m/s", display_unit="mm/min", start=0.0, min=-10.0, max=10.0),
        Variable("feed_velocity_y", "Float64", "input", "Feed velocity along Y",
                 unit="m/s", display_unit="mm/min", start=0.0, min=-10.0, max=10.0),
        Variable("cutting", "Boolean", "input", "Tool is in the material", start=True),
        Variable("mrr", "Float64", "output", "Material removal rate", unit="m3/s", display_unit="cm3/min"),
    ),
)

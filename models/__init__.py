"""Model definitions: the single source of truth for every FMU's equations (see models.definition).

The definitions are imported on first use (PEP 562 ``__getattr__``): ``import models.units`` (the
orchestrator's unit handling) does not pay for casadi and the eight model graphs.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from milling_twin.models.cutting_force import CUTTING_FORCE
    from milling_twin.models.definition import ModelDefinition, Variable
    from milling_twin.models.force_net import FORCE_NET
    from milling_twin.models.interpolator import INTERPOLATOR
    from milling_twin.models.measuring_chain import MEASURING_CHAIN
    from milling_twin.models.mrr_estimator import MRR_ESTIMATOR
    from milling_twin.models.power import POWER
    from milling_twin.models.vibration import VIBRATION
    from milling_twin.models.workpiece import WORKPIECE

    MODELS: dict[str, ModelDefinition]

# definition -> its module, in the order of MODELS
_DEFINITIONS = {"POWER": "milling_twin.models.power", "MRR_ESTIMATOR": "milling_twin.models.mrr_estimator", "VIBRATION": "milling_twin.models.vibration",
                "CUTTING_FORCE": "milling_twin.models.cutting_force", "WORKPIECE": "milling_twin.models.workpiece",
                "INTERPOLATOR": "milling_twin.models.interpolator", "FORCE_NET": "milling_twin.models.force_net",
                "MEASURING_CHAIN": "milling_twin.models.measuring_chain"}

__all__ = ["MODELS", "ModelDefinition", "Variable", *_DEFINITIONS]


def __getattr__(name: str) -> Any:
    if name in _DEFINITIONS:
        value = getattr(importlib.import_module(_DEFINITIONS[name]), name)
    elif name == "MODELS":
        value = {m.identifier: m for m in (__getattr__(n) for n in _DEFINITIONS)}
    elif name in ("ModelDefinition", "Variable"):
        value = getattr(importlib.import_module("milling_twin.models.definition"), name)
    else:
        raise AttributeError(f"module 'models' has no attribute {name!r}")
    globals()[name] = value
    return value

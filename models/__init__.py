"""Model definitions: the single source of truth for every FMU's equations (see models.definition).

The definitions are imported on first use (PEP 562 ``__getattr__``): ``import models.units`` (the
orchestrator's unit handling) does not pay for casadi and the seven model graphs.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from models.cutting_force import CUTTING_FORCE
    from models.definition import ModelDefinition, Variable
    from models.force_net import FORCE_NET
    from models.interpolator import INTERPOLATOR
    from models.mrr_estimator import MRR_ESTIMATOR
    from models.power import POWER
    from models.vibration import VIBRATION
    from models.workpiece import WORKPIECE

    MODELS: dict[str, ModelDefinition]

# definition -> its module, in the order of MODELS
_DEFINITIONS = {"POWER": "models.power", "MRR_ESTIMATOR": "models.mrr_estimator", "VIBRATION": "models.vibration",
                "CUTTING_FORCE": "models.cutting_force", "WORKPIECE": "models.workpiece",
                "INTERPOLATOR": "models.interpolator", "FORCE_NET": "models.force_net"}

__all__ = ["MODELS", "ModelDefinition", "Variable", *_DEFINITIONS]


def __getattr__(name: str) -> Any:
    if name in _DEFINITIONS:
        value = getattr(importlib.import_module(_DEFINITIONS[name]), name)
    elif name == "MODELS":
        value = {m.identifier: m for m in (__getattr__(n) for n in _DEFINITIONS)}
    elif name in ("ModelDefinition", "Variable"):
        value = getattr(importlib.import_module("models.definition"), name)
    else:
        raise AttributeError(f"module 'models' has no attribute {name!r}")
    globals()[name] = value
    return value

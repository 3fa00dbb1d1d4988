"""Model definitions: the single source of truth for every FMU's equations (see models.definition)."""
from models.cutting_force import CUTTING_FORCE
from models.definition import ModelDefinition, Variable
from models.force_net import FORCE_NET
from models.interpolator import INTERPOLATOR
from models.mrr_estimator import MRR_ESTIMATOR
from models.power import POWER
from models.vibration import VIBRATION
from models.workpiece import WORKPIECE

MODELS: dict[str, ModelDefinition] = {m.identifier: m for m in (POWER, MRR_ESTIMATOR, VIBRATION, CUTTING_FORCE, WORKPIECE, INTERPOLATOR, FORCE_NET)}

__all__ = ["MODELS", "ModelDefinition", "Variable", "POWER", "MRR_ESTIMATOR", "VIBRATION", "CUTTING_FORCE", "WORKPIECE", "INTERPOLATOR", "FORCE_NET"]

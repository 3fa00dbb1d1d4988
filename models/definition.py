"""The form every model definition takes: its variables and its equations as casadi expressions.

A model definition is the single source of truth for a model: calibration evaluates the
equations symbolically (casadi) or numerically (numpy arrays through casadi), and
``models.codegen`` turns the very same expressions into the C code and the model
descriptions of the FMU. Nothing about a model's equations is written twice.
"""
from __future__ import annotations

import hashlib
import uuid
from dataclasses import dataclass, field
from typing import Callable, Literal, Mapping

import casadi as ca
import numpy as np

VariableType = Literal["Float64", "Boolean"]
Causality = Literal["parameter", "input", "output"]
Variability = Literal["fixed", "tunable", "continuous", "discrete"]


@dataclass(frozen=True)
class Variable:
    """One FMU variable. Values are in SI ``unit``; ``display_unit`` is what users see in tools."""

    name: str
    type: VariableType
    causality: Causality
    description: str
    unit: str = ""
    display_unit: str = ""
    start: float | bool | None = None
    min: float | None = None
    max: float | None = None
    variability: Variability | None = None

    @property
    def effective_variability(self) -> Variability:
        if self.variability is not None:
            return self.variability
        if self.causality == "parameter":
            return "tunable"
        return "discrete" if self.type == "Boolean" else "continuous"


Equations = Callable[[Mapping[str, ca.SX]], dict[str, ca.SX]]


@dataclass(frozen=True)
class ModelDefinition:
    """A model: identifier, variables and the equations giving every output from parameters and inputs."""

    identifier: str
    description: str
    variables: tuple[Variable, ...]
    equations: Equations
    default_step_size: float = 1e-3
    default_stop_time: float = 10.0
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def of(self, causality: Causality) -> tuple[Variable, ...]:
        return tuple(v for v in self.variables if v.causality == causality)

    def variable(self, name: str) -> Variable:
        for v in self.variables:
            if v.name == name:
                return v
        raise KeyError(f"{self.identifier} has no variable '{name}'")

    @property
    def arguments(self) -> tuple[Variable, ...]:
        """The equations' arguments in order: parameters, then inputs."""
        return self.of("parameter") + self.of("input")

    def function(self) -> ca.Function:
        """The equations as one casadi Function (arguments -> outputs), scalar in and out."""
        if "function" not in self._cache:
            symbols = {v.name: ca.SX.sym(v.name) for v in self.arguments}
            outputs = self.equations(symbols)
            expected = {v.name for v in self.of("output")}
            if set(outputs) != expected:
                raise ValueError(
                    f"{self.identifier}: equations give {sorted(outputs)}, outputs are {sorted(expected)}"
                )
            self._cache["function"] = ca.Function(
                self.identifier,
                [symbols[v.name] for v in self.arguments],
                [outputs[v.name] for v in self.of("output")],
                [v.name for v in self.arguments],
                [v.name for v in self.of("output")],
            )
        return self._cache["function"]

    def defaults(self) -> dict[str, float]:
        """Start values of parameters and inputs (booleans as 0.0/1.0)."""
        return {v.name: float(v.start) for v in self.arguments if v.start is not None}

    def evaluate(self, **values: float | np.ndarray) -> dict[str, np.ndarray]:
        """Numeric evaluation on numpy arrays (broadcast); missing arguments take their start values."""
        args = {**self.defaults(), **values}
        missing = [v.name for v in self.arguments if v.name not in args]
        if missing:
            raise ValueError(f"{self.identifier}: no value for {', '.join(missing)}")
        unknown = sorted(set(values) - {v.name for v in self.arguments})
        if unknown:
            raise ValueError(f"{self.identifier}: unknown argument(s) {', '.join(unknown)}")
        arrays = np.broadcast_arrays(*[np.asarray(args[v.name], dtype=float) for v in self.arguments])
        shape = arrays[0].shape
        flat = [a.reshape(1, -1) for a in arrays]
        count = flat[0].shape[1]
        result = self.function().map(count)(*flat)
        result = result if isinstance(result, (list, tuple)) else [result]
        return {
            v.name: np.asarray(r, dtype=float).reshape(shape)
            for v, r in zip(self.of("output"), result)
        }

    def instantiation_token(self) -> str:
        """A GUID that changes whenever the variables or equations change."""
        function = self.function()
        fingerprint = repr(self.variables) + str(function(*function.sx_in())) + self.identifier
        digest = hashlib.sha256(fingerprint.encode()).hexdigest()
        return "{" + str(uuid.UUID(digest[:32])) + "}"

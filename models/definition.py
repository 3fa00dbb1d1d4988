"""The form every model definition takes: its variables and its equations as casadi expressions.

A model definition is the single source of truth for a model: calibration evaluates the
equations symbolically (casadi) or numerically (numpy arrays through casadi), and
``milling_twin.models.codegen`` turns the very same expressions into the C code and the model
descriptions of the FMU. Nothing about a model's equations is written twice.
"""
from __future__ import annotations

import hashlib
import math
import uuid
from dataclasses import dataclass, field
from typing import Callable, Literal, Mapping

import casadi as ca
import numpy as np

VariableType = Literal["Float64", "Int32", "Boolean", "String"]
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
    start: float | int | bool | str | None = None
    min: float | None = None
    max: float | None = None
    variability: Variability | None = None
    # An array (FMI 3: one variable with <Dimension>s; FMI 2: one scalar per element, named
    # name[i,j] with 1-based indices, in row-major order). Float64 only; outputs are computed by model.c
    # (native_outputs), inputs and parameters are read by model.c only (they are no arguments of the
    # casadi equations). ``start``, ``min`` and ``max`` hold for every element.
    shape: tuple[int, ...] = ()

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    def element_names(self) -> list[str]:
        """FMI 2 names of the elements, row-major: name[1,1], name[1,2], ..."""
        if not self.shape:
            return [self.name]
        return [f"{self.name}[{','.join(str(i + 1) for i in index)}]" for index in np.ndindex(*self.shape)]

    @property
    def effective_variability(self) -> Variability:
        if self.variability is not None:
            return self.variability
        if self.causality == "parameter":
            return "tunable"
        return "continuous" if self.type == "Float64" else "discrete"


#: Capacity of a String variable in the FMU, terminating NUL included (a longer value is rejected).
STRING_CAPACITY = 4096


@dataclass(frozen=True)
class State:
    """A state the model keeps between steps (not an FMI variable); SI ``unit``."""

    name: str
    description: str
    unit: str = ""
    start: float = 0.0


Equations = Callable[[Mapping[str, ca.SX]], dict[str, ca.SX]]
# (parameters, inputs and states by name, step size h) -> the states at the end of the step
StateUpdate = Callable[[Mapping[str, ca.SX], ca.SX], dict[str, ca.SX]]


@dataclass(frozen=True)
class ModelDefinition:
    """A model: identifier, variables, states, the equations giving every output from parameters,
    inputs and states, and (for models with states) the update of the states over one step of
    size h with inputs held constant over the step (what a co-simulation step does)."""

    identifier: str
    description: str
    variables: tuple[Variable, ...]
    equations: Equations | None
    states: tuple[State, ...] = ()
    update: StateUpdate | None = None
    # Outputs and states that the model's C code (model.c) computes itself, because casadi cannot
    # express them (searches, buffers, grids); models/ then holds a reference implementation and a
    # test proves the two equal. Everything else is generated from the expressions here.
    native_outputs: tuple[str, ...] = ()
    native_states: tuple[str, ...] = ()
    # An Int32 parameter (with min and max) whose value shapes the equations, e.g. the number of
    # flutes: the C code gets one copy of the equations per value in its range, the value folded in
    # as a constant (casadi then drops what cannot count at that value, e.g. the terms of absent
    # flutes), and runs the copy for the parameter's value (the generic equations otherwise). Only
    # the C code is specialized; it computes the same expressions.
    specialize_on: str | None = None
    # Further parameters folded in as constants in every specialized copy (name, value), e.g. the chip-thickness law
    # whose default needs no powers: the copy runs only while they hold these values, the generic equations otherwise.
    specialize_fixed: tuple[tuple[str, int], ...] = ()
    # (name, threshold): a fixed Int32 parameter that splits every specialized copy in two, folded in as its min
    # (the copy run while it is below threshold) and as its max (at or above), e.g. CuttingForce's
    # regeneration_passes: one delay, or the thinnest of several surfaces. The equations must compute, with the max
    # folded in, what every value at or above threshold needs (CuttingForce's model.c makes the delays beyond the
    # value inert), and the parameter counts as no dependency: it is fixed, and the copies agree in Initialization
    # Mode (there all delays are the current displacement).
    specialize_split: tuple[str, int] | None = None
    default_step_size: float = 1e-3
    default_stop_time: float = 10.0
    # Constants the model's C code shares with its Python definition or reference (name, value: an int, a
    # float or a tuple of floats): models.codegen writes them into the generated model_constants.h, so they
    # are written once, here.
    constants: tuple[tuple[str, int | float | tuple[float, ...]], ...] = ()
    # What model.c computes reads, declared (casadi cannot see into C): native output or native state -> the inputs
    # and parameters (any variability) its value at a communication point depends on directly, that is not through
    # something kept from an earlier step. Every native output and native state needs an entry (codegen refuses to
    # write the <ModelStructure> otherwise); the generated outputs' dependencies are derived from their equations.
    native_dependencies: tuple[tuple[str, tuple[str, ...]], ...] = ()
    # The same in Initialization Mode, for the native outputs whose values there come from other variables (e.g. the
    # Interpolator's start position); an output not listed has its native_dependencies there too.
    native_initial_dependencies: tuple[tuple[str, tuple[str, ...]], ...] = ()
    # Native states that in Initialization Mode equal one of the equations' arguments (e.g. the delayed displacement
    # is the current one while there is no history): the argument replaces the state in the equations there, so
    # what cancels (x - x) drops out of the dependencies.
    native_initial_states: tuple[tuple[str, str], ...] = ()
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.specialize_on is not None:
            v = self.variable(self.specialize_on)
            if (v.type != "Int32" or v.causality != "parameter" or v.min is None or v.max is None
                    or not 0 <= v.max - v.min <= 16):
                raise ValueError(f"{self.identifier}.{v.name}: specialize_on needs an Int32 parameter with min and "
                                 "max at most 16 apart")
        for name, _ in self.specialize_fixed:
            v = self.variable(name)
            if self.specialize_on is None or v.type != "Int32" or v.causality != "parameter":
                raise ValueError(f"{self.identifier}.{name}: specialize_fixed needs specialize_on and an Int32 "
                                 "parameter")
        if self.specialize_split is not None:
            name, threshold = self.specialize_split
            v = self.variable(name)
            if (self.specialize_on is None or v.type != "Int32" or v.causality != "parameter"
                    or v.variability != "fixed" or v.min is None or v.max is None or not v.min < threshold <= v.max):
                raise ValueError(f"{self.identifier}.{name}: specialize_split needs specialize_on and a fixed Int32 "
                                 "parameter with min < threshold <= max")
        for v in self.variables:
            if not v.shape:
                continue
            if v.type != "Float64" or (v.causality == "output" and v.name not in self.native_outputs):
                raise ValueError(f"{self.identifier}.{v.name}: arrays are Float64 outputs that model.c computes "
                                 "(native_outputs), or Float64 inputs and parameters that model.c reads")
            if v.causality != "output" and v.start is None:
                raise ValueError(f"{self.identifier}.{v.name}: an array input or parameter needs a start value")

    def of(self, causality: Causality) -> tuple[Variable, ...]:
        return tuple(v for v in self.variables if v.causality == causality)

    def variable(self, name: str) -> Variable:
        for v in self.variables:
            if v.name == name:
                return v
        raise KeyError(f"{self.identifier} has no variable '{name}'")

    @property
    def arguments(self) -> tuple[Variable | State, ...]:
        """The equations' arguments in order: parameters, inputs, then states (Strings and arrays are no
        arguments: only a model's C code reads them, e.g. a file name or a map)."""
        numeric = tuple(v for v in self.of("parameter") + self.of("input") if v.type != "String" and not v.shape)
        return numeric + self.states

    @property
    def computed_outputs(self) -> tuple[Variable, ...]:
        """Outputs given by ``equations`` (generated into C), in definition order."""
        return tuple(v for v in self.of("output") if v.name not in self.native_outputs)

    @property
    def updated_states(self) -> tuple[State, ...]:
        """States given by ``update`` (generated into C), in definition order."""
        return tuple(s for s in self.states if s.name not in self.native_states)

    def _symbols(self) -> dict[str, ca.SX]:
        return {v.name: ca.SX.sym(v.name) for v in self.arguments}

    def update_function(self) -> ca.Function:
        """The state update as a casadi Function (arguments..., h) -> new states."""
        if "update" not in self._cache:
            symbols, h = self._symbols(), ca.SX.sym("h")
            new = self.update(symbols, h) if self.update else {}
            expected = {s.name for s in self.updated_states}
            if set(new) != expected:
                raise ValueError(f"{self.identifier}: update gives {sorted(new)}, states are {sorted(expected)}")
            self._cache["update"] = ca.Function(
                f"{self.identifier}_update",
                [symbols[v.name] for v in self.arguments] + [h],
                [new[s.name] for s in self.updated_states],
                [v.name for v in self.arguments] + ["h"],
                [f"{s.name}_next" for s in self.updated_states],
            )
        return self._cache["update"]

    def specialized_values(self) -> range:
        """The values of ``specialize_on`` the C code has its own copy of the equations for."""
        if self.specialize_on is None:
            return range(0)
        v = self.variable(self.specialize_on)
        return range(int(v.min), int(v.max) + 1)

    def split_values(self) -> tuple[int, ...]:
        """The values ``specialize_split``'s parameter is folded in as (its min and its max), none without one."""
        if self.specialize_split is None:
            return ()
        v = self.variable(self.specialize_split[0])
        return int(v.min), int(v.max)

    def function(self, specialized: int | None = None, split: int | None = None) -> ca.Function:
        """The equations as one casadi Function (arguments -> outputs), scalar in and out;
        ``specialized``: with ``specialize_on`` fixed to this value and the ``specialize_fixed`` parameters to
        theirs (their arguments are then unused); ``split``: ``specialize_split``'s parameter too (one of
        :meth:`split_values`; None: its min)."""
        if specialized is not None and self.specialize_split is not None and split is None:
            split = self.split_values()[0]
        key = "function" if specialized is None else f"function_{specialized}_{split}"
        if key not in self._cache:
            symbols = self._symbols()
            given = symbols if specialized is None else {
                **symbols, self.specialize_on: ca.SX(float(specialized)),
                **{name: ca.SX(float(value)) for name, value in self.specialize_fixed},
                **({self.specialize_split[0]: ca.SX(float(split))} if self.specialize_split else {})}
            outputs = self.equations(given) if self.equations else {}
            expected = {v.name for v in self.computed_outputs}
            if set(outputs) != expected:
                raise ValueError(
                    f"{self.identifier}: equations give {sorted(outputs)}, outputs are {sorted(expected)}"
                )
            self._cache[key] = ca.Function(
                self.identifier,
                [symbols[v.name] for v in self.arguments],
                [outputs[v.name] for v in self.computed_outputs],
                [v.name for v in self.arguments],
                [v.name for v in self.computed_outputs],
            )
        return self._cache[key]

    def defaults(self) -> dict[str, float]:
        """Start values of parameters and inputs (booleans as 0.0/1.0)."""
        return {v.name: float(v.start) for v in self.arguments if v.start is not None}

    def _evaluate(self, function: ca.Function, names: list[str], extra: dict[str, float | np.ndarray],
                  values: dict[str, float | np.ndarray]) -> dict[str, np.ndarray]:
        args = {**self.defaults(), **values, **extra}
        expected = [v.name for v in self.arguments] + list(extra)
        missing = [name for name in expected if name not in args]
        if missing:
            raise ValueError(f"{self.identifier}: no value for {', '.join(missing)}")
        unknown = sorted(set(values) - set(expected))
        if unknown:
            raise ValueError(f"{self.identifier}: unknown argument(s) {', '.join(unknown)}")
        arrays = np.broadcast_arrays(*[np.asarray(args[name], dtype=float) for name in expected])
        shape = arrays[0].shape
        flat = [a.reshape(1, -1) for a in arrays]
        result = function.map(flat[0].shape[1])(*flat)
        result = result if isinstance(result, (list, tuple)) else [result]
        return {name: np.asarray(r, dtype=float).reshape(shape) for name, r in zip(names, result)}

    def evaluate(self, **values: float | np.ndarray) -> dict[str, np.ndarray]:
        """Outputs on numpy arrays (broadcast); missing arguments take their start values."""
        return self._evaluate(self.function(), [v.name for v in self.computed_outputs], {}, values)

    def step(self, h: float | np.ndarray, **values: float | np.ndarray) -> dict[str, np.ndarray]:
        """The states after one step of size ``h`` with the given parameters, inputs and states."""
        return self._evaluate(self.update_function(), [s.name for s in self.updated_states], {"h": h}, values)

    def direct_dependencies(self, initial: bool = False) -> dict[str, tuple[str, ...]]:
        """Output -> the inputs and parameters (definition order, any variability) its value depends on directly: at
        a communication point (``initial``: in Initialization Mode, the states at their start values), not through a
        state kept from an earlier step.
        Generated outputs: structurally, from the instructions of their equations (those the C code runs: one copy
        per value of ``specialize_on``), a native state among their arguments counting with its declared
        dependencies; native outputs: as declared. Raises ValueError for a native output or state without a
        declaration, or a declaration naming what is no input or parameter."""
        key = f"dependencies_{initial}"
        if key in self._cache:
            return self._cache[key]
        knowns = [v.name for v in self.of("parameter") + self.of("input")]
        declared = dict(self.native_dependencies)
        if initial:
            declared.update(self.native_initial_dependencies)
        for name in self.native_outputs + self.native_states:
            if name not in declared:
                raise ValueError(f"{self.identifier}.{name} is computed by model.c: declare the inputs and parameters "
                                 "it depends on in native_dependencies (models/), none: an empty tuple")
        for name, names in declared.items():
            if name not in self.native_outputs + self.native_states:
                raise ValueError(f"{self.identifier}: native_dependencies names '{name}', which is no native output "
                                 "or native state")
            unknown = [n for n in names if n not in knowns]
            if unknown:
                raise ValueError(f"{self.identifier}.{name}: native_dependencies names {unknown}, no inputs or "
                                 "parameters of the model")
        # in Initialization Mode the generated states hold their start values (constants: what they multiply drops
        # out) and the native states named in native_initial_states are the arguments they equal
        substitutes = dict(self.native_initial_states) if initial else {}
        symbols = self._symbols()
        starts = {s.name: ca.SX(float(s.start)) for s in self.updated_states} if initial else {}
        given = {**symbols, **starts, **{s: symbols[a] for s, a in substitutes.items()}}
        # the generic equations (the C code picks the copy by the value of specialize_on: a dependency on it), then
        # the copies the C code runs with specialize_on folded in (what they drop is no dependency)
        # (specialize_split's parameter folded in as each of its values: no dependency, see the field)
        splits = [{}] + [{self.specialize_split[0]: ca.SX(float(x))} for x in self.split_values()]
        values = [(None, {})] + [(n, split) for n in self.specialized_values() for split in splits[1:] or splits]
        found: dict[str, set[str]] = {v.name: set() for v in self.computed_outputs}
        names = [v.name for v in self.arguments]
        for value, split in values:
            fixed = given if value is None else {**given, self.specialize_on: ca.SX(float(value)), **split}
            outputs = self.equations(fixed) if self.equations else {}
            function = ca.Function("dependencies", [symbols[n] for n in names],
                                   [outputs[v.name] for v in self.computed_outputs])
            for output, arguments in zip(found, _instruction_dependencies(function)):
                for index in arguments:
                    name = names[index]
                    if value is None and self.specialize_on is not None and name != self.specialize_on:
                        continue
                    found[output] |= set(declared[name]) if name in self.native_states else (
                        set() if any(s.name == name for s in self.states) else {name})
        result = {v.name: tuple(n for n in knowns if n in (found[v.name] if v.name in found else declared[v.name]))
                  for v in self.of("output")}
        self._cache[key] = result
        return result

    def instantiation_token(self) -> str:
        """A GUID that changes whenever the variables or equations change."""
        function, update = self.function(), self.update_function()
        fingerprint = (repr(self.variables) + repr(self.states) + repr(self.native_outputs)
                       + repr(self.native_states) + str(function(*function.sx_in()))
                       + str(update(*update.sx_in())) + self.identifier)
        digest = hashlib.sha256(fingerprint.encode()).hexdigest()
        return "{" + str(uuid.UUID(digest[:32])) + "}"



def _instruction_dependencies(function: ca.Function) -> list[set[int]]:
    """For each output of a scalar SX Function, the indices of the inputs its instructions read (what the
    translated C code computes it from; casadi has already dropped what cancels, e.g. x - x)."""
    reads: dict[int, set[int]] = {}
    result: list[set[int]] = [set() for _ in range(function.n_out())]
    for k in range(function.n_instructions()):
        op = function.instruction_id(k)
        ins, outs = function.instruction_input(k), function.instruction_output(k)
        if op == ca.OP_INPUT:
            reads[outs[0]] = {ins[0]}
        elif op == ca.OP_OUTPUT:
            result[outs[0]] |= reads[ins[0]]
        elif op == ca.OP_CONST:
            reads[outs[0]] = set()
        else:
            reads[outs[0]] = set().union(*(reads[i] for i in ins if i >= 0))
    return result

"""The scenario's FMU instances as one casadi expression graph, built from the models/ equations.

For the fitted outputs, each instance's equations (``ModelDefinition.equations``, the very
expressions the FMU's C code is generated from) are called with

* fitted parameters: casadi symbols (SI);
* every other parameter: its number (the scenario's value, else the FMU's start value), so
  casadi folds the constants and the graph stays small (a 2-flute CuttingForce shrinks from
  5188 to about 1200 operations);
* inputs fed by a non-delayed connection from an instance whose outputs depend on a fitted
  parameter: that instance's output expression times the connection's unit factor (so a
  parameter upstream is fitted through the chain, as the master would compute it);
* every other input: a data symbol, one column of the co-simulation results (the value the FMU
  actually held: the orchestrator records the instance's inputs for calibration);
* an input with a floor (the spec's ``[inputs]``) is read as ``fmax(value, floor)``, for
  expressions whose derivative is undefined at a boundary value (0^c3 of the power model).

A model's states enter its equations as symbols too. An instance is dynamic when its fitted outputs
depend on them (``ca.depends_on``, after the constants above are folded: SpindlePower's P_total with
J_spindle = 0 not fitted does not read its speed-rate state, and is fitted as stateless). A dynamic
instance (one, e.g. ToolVibration) gives ``step(x_prev, theta, d)``: the states after one step
``x_k = update(theta, d_k, x_prev, h)`` and the outputs ``y_k = equations(theta, d_k, x_k)``: row k
of the results holds the inputs held over the step that ended at t_k and the outputs after it. Only
the states the fitted outputs depend on (directly or through other states' updates) are kept.

What the graph cannot express raises :class:`NotExpressible` (naming the spec key): outputs or
states computed by a model's C code (native), an instance without a models/ definition, an
instance upstream of the fitted outputs whose output that feeds them depends on its states, several
dynamic instances, a dynamic instance not recorded every step. Such fits run through the FMUs with
finite differences instead (:mod:`milling_twin.orchestrator.calibrate.fmu_outputs`).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import NoReturn

import casadi as ca
import numpy as np

from milling_twin.models import MODELS
from milling_twin.models.definition import ModelDefinition, State
from milling_twin.orchestrator.scenario import Ref, Scenario

__all__ = ["DataColumn", "DynamicPart", "ModelGraph", "NO_DATA_DERIVATIVE", "NotExpressible", "build_graph"]

# Data are not differentiated: without this, casadi's forward mode multiplies a zero seed by an
# infinite partial (sqrt at 0 of |v| = 0, in MrrEstimator) and gets NaN for every parameter.
NO_DATA_DERIVATIVE = {"is_diff_in": [True, False]}


class NotExpressible(Exception):
    """The models/ expressions cannot give the fitted outputs (``key``: the spec key concerned)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key, self.message = key, message


@dataclass(frozen=True)
class DataColumn:
    ref: str  # "instance.input": a column of the results
    is_bool: bool
    input: Ref  # the input whose values the column holds


@dataclass(frozen=True)
class DynamicPart:
    instance: str
    step_size: float
    states: tuple[str, ...]
    initial: np.ndarray  # start values of the kept states
    step: ca.Function  # (x_prev, theta, d) -> (x_next, y)
    initial_outputs: ca.Function  # (x0, theta, d) -> y at the initialization row


@dataclass(frozen=True)
class ModelGraph:
    parameters: tuple[Ref, ...]  # fitted, in theta order
    outputs: tuple[Ref, ...]  # fitted outputs, in y order
    data: tuple[DataColumn, ...]  # per-sample data, in d order
    sample: ca.Function | None  # stateless: (theta, d) -> y
    dynamic: DynamicPart | None
    instances: tuple[str, ...]  # instances whose equations are part of the graph
    models: dict[str, ModelDefinition]
    inputs: tuple[Ref, ...] = ()  # every input the graph reads, from data or a connection


def model_of(scenario: Scenario, instance: str) -> ModelDefinition | None:
    return MODELS.get(scenario.instance(instance).model_identifier)


def build_graph(scenario: Scenario, parameters: Sequence[Ref], outputs: Sequence[Ref],
                fail: Callable[[str, str], NoReturn], keys: Mapping[Ref, str],
                floors: Mapping[Ref, float] | None = None) -> ModelGraph:
    """``keys`` maps each of ``parameters`` and ``outputs`` to its spec key for ``fail(key, message)``;
    ``floors``: input -> lower limit applied to that input."""
    floors = floors or {}
    inputs_used: list[Ref] = []
    theta = {ref: ca.SX.sym(str(ref)) for ref in parameters}
    fitted_instances = {ref.instance for ref in parameters}
    data_symbols: dict[Ref, ca.SX] = {}
    data_columns: list[DataColumn] = []
    models: dict[str, ModelDefinition] = {}
    feeds = {c.target: c for c in scenario.connections if not c.delay}
    depends: dict[str, bool] = {}

    def model(instance: str, key: str) -> ModelDefinition:
        m = model_of(scenario, instance)
        if m is None:
            raise NotExpressible(key, f"instance {instance!r} runs {scenario.instance(instance).model_identifier}, which has no "
                      "models/ definition: its equations are not available to calibration")
        models[instance] = m
        return m

    def needs(instance: str, seen: tuple[str, ...] = ()) -> bool:
        """Does the instance's output depend on a fitted parameter?"""
        if instance not in depends:
            upstream = [c.source.instance for t, c in feeds.items() if t.instance == instance]
            depends[instance] = instance in fitted_instances or any(
                needs(u, seen + (instance,)) for u in upstream if u not in seen)
        return depends[instance]

    def data(ref: Ref) -> ca.SX:
        if ref not in data_symbols:
            data_symbols[ref] = ca.SX.sym(str(ref))
            data_columns.append(DataColumn(str(ref), scenario.variable(ref).type == "bool", ref))
        return data_symbols[ref]

    def arguments(instance: str, key: str, states: Mapping[str, ca.SX] | None) -> dict[str, ca.SX]:
        m = model(instance, key)
        inst = scenario.instance(instance)
        values: dict[str, ca.SX] = {}
        for arg in m.arguments:
            name = arg.name
            ref = Ref(instance, name)
            if isinstance(arg, State):
                values[name] = states[name]
            elif arg.causality == "parameter":
                if ref in theta:
                    values[name] = theta[ref]
                else:
                    value = inst.parameters.get(name, arg.start)
                    values[name] = ca.SX(float(value))
            else:
                if ref in feeds and needs(feeds[ref].source.instance):
                    source = feeds[ref].source
                    values[name] = output_of(source.instance, source.variable, key) * feeds[ref].factor
                else:
                    values[name] = data(ref)
                inputs_used.append(ref)
                if ref in floors:
                    values[name] = ca.fmax(values[name], floors[ref])
        return values

    cache: dict[str, dict[str, ca.SX]] = {}
    argument_cache: dict[str, dict[str, ca.SX]] = {}
    state_symbols: dict[str, dict[str, ca.SX]] = {}

    def outputs_of(instance: str, key: str) -> dict[str, ca.SX]:
        """The instance's outputs as expressions; its states (if any) as symbols (``state_symbols``)."""
        if instance not in cache:
            m = model(instance, key)
            states = state_symbols[instance] = {s.name: ca.SX.sym(f"{instance}.{s.name}") for s in m.states}
            argument_cache[instance] = arguments(instance, key, states)
            cache[instance] = m.equations(argument_cache[instance])
        return cache[instance]

    def reads_states(instance: str, expression: ca.SX) -> bool:
        return any(ca.depends_on(expression, s) for s in state_symbols[instance].values())

    def output_of(instance: str, variable: str, key: str) -> ca.SX:
        """An output feeding another instance: it must not depend on its instance's states."""
        expression = outputs_of(instance, key)[variable]
        if reads_states(instance, expression):
            m = models[instance]
            raise NotExpressible(key, f"{instance}.{variable} depends on the states of {instance} ({m.identifier}): "
                                 "a dynamic model must be the instance whose outputs are fitted, with its inputs "
                                 "from data")
        return expression

    out_instances = {o.instance for o in outputs}
    for o in outputs:
        var = o.variable
        m = model(o.instance, keys[o])
        if var in m.native_outputs:
            raise NotExpressible(keys[o], f"{o} is computed by the FMU's C code (model.c), not by a models/ expression")
        if m.variable(var).causality != "output":
            fail(keys[o], f"{o} is {m.variable(var).causality}, not an output")
    for name in parameters:
        inst = name.instance
        if not any(needs(i) and (i == inst or _upstream(feeds, i, inst)) for i in out_instances):
            fail(keys[name], f"no fitted output depends on {name}: the outputs come from "
                             f"{', '.join(sorted(out_instances))}, and {inst} does not feed them through "
                             "non-delayed connections")

    # dynamic: an instance whose fitted outputs depend on its states (with the constants folded). What an
    # output cannot be built from (an upstream instance's states, no definition) is reported after "fit one
    # dynamic instance at a time", which holds whatever the other outputs are.
    y: list[ca.SX] = []
    deferred: NotExpressible | None = None
    for o in outputs:
        try:
            y.append(outputs_of(o.instance, keys[o])[o.variable])
        except NotExpressible as exc:
            deferred = deferred or exc
    dynamic_instances = sorted({o.instance for o in outputs
                                if o.instance in cache and reads_states(o.instance, cache[o.instance][o.variable])})
    if not dynamic_instances and deferred is None:
        th = ca.vertcat(*[theta[n] for n in parameters])
        d = ca.vertcat(*[data_symbols[c.input] for c in data_columns]) if data_columns else ca.SX(0, 1)
        sample = ca.Function("sample", [th, d], [ca.vertcat(*y)], ["theta", "d"], ["y"], NO_DATA_DERIVATIVE)
        return ModelGraph(tuple(parameters), tuple(outputs), tuple(data_columns), sample, None,
                          tuple(models), models, tuple(inputs_used))
    if dynamic_instances and len(out_instances) > 1:
        o = next(o for o in outputs if o.instance == dynamic_instances[0])
        raise NotExpressible(keys[o], f"outputs of a dynamic model ({dynamic_instances[0]}) are fitted together with outputs of "
                      f"{', '.join(sorted(out_instances - {dynamic_instances[0]}))}: fit one dynamic instance at a time")
    if deferred is not None:
        raise deferred
    instance = dynamic_instances[0]
    graph = _dynamic(scenario, instance, parameters, outputs, theta, state_symbols[instance],
                     argument_cache[instance], cache[instance], data_symbols, data_columns, models, keys)
    return replace(graph, inputs=tuple(inputs_used))


def _upstream(feeds: Mapping, target: str, source: str) -> bool:
    """Is ``source`` upstream of ``target`` along non-delayed connections?"""
    frontier, seen = [target], set()
    while frontier:
        node = frontier.pop()
        for t, c in feeds.items():
            if t.instance == node and c.source.instance not in seen:
                if c.source.instance == source:
                    return True
                seen.add(c.source.instance)
                frontier.append(c.source.instance)
    return False


def _dynamic(scenario: Scenario, instance: str, parameters: Sequence[Ref], outputs: Sequence[Ref],
             theta: Mapping[Ref, ca.SX], states: Mapping[str, ca.SX], values: Mapping[str, ca.SX],
             equations: Mapping[str, ca.SX], data_symbols: dict, data_columns: list, models: dict,
             keys: Mapping[Ref, str]) -> ModelGraph:
    """``states``, ``values`` and ``equations``: the instance's state symbols, the arguments of its equations
    (states included) and its outputs, as ``build_graph`` made them."""
    m = models[instance]
    key = keys[next(o for o in outputs if o.instance == instance)]
    if m.native_states:
        raise NotExpressible(key, f"{instance} ({m.identifier}) keeps states in its C code ({', '.join(m.native_states)}): "
                  "not expressible for the generic fit")
    inst = scenario.instance(instance)
    if inst.ticks_per_step != scenario.ticks_per_output:
        raise NotExpressible(key, f"{instance} is dynamic: the scenario must record every step of it ([scenario].output_interval = "
                  f"{inst.step_size!r} s, the instance's step_size; it is {scenario.output_interval!r} s)")
    h = ca.SX(float(inst.step_size))
    new = m.update(values, h)
    y_of_x = [equations[o.variable] for o in outputs]
    # states the outputs need, closed under the update
    kept: list[str] = [s for s in states if any(ca.depends_on(y, states[s]) for y in y_of_x)]
    changed = True
    while changed:
        changed = False
        for s in list(kept):
            for other in states:
                if other not in kept and ca.depends_on(new[s], states[other]):
                    kept.append(other)
                    changed = True
    kept = [s.name for s in m.states if s.name in kept]
    th = ca.vertcat(*[theta[n] for n in parameters])
    d = ca.vertcat(*[data_symbols[c.input] for c in data_columns]) if data_columns else ca.SX(0, 1)
    x = ca.vertcat(*[states[s] for s in kept]) if kept else ca.SX(0, 1)
    x_next = ca.vertcat(*[new[s] for s in kept]) if kept else ca.SX(0, 1)
    y = ca.vertcat(*y_of_x)
    y_next = ca.substitute([y], [x], [x_next])[0] if kept else y
    step = ca.Function("step", [x, th, d], [x_next, y_next], ["x_prev", "theta", "d"], ["x", "y"],
                       {"is_diff_in": [True, True, False]})
    initial_outputs = ca.Function("initial_outputs", [x, th, d], [y], ["x0", "theta", "d"], ["y"],
                                  {"is_diff_in": [True, True, False]})
    start = np.array([next(s.start for s in m.states if s.name == k) for k in kept], dtype=float)
    dyn = DynamicPart(instance, inst.step_size, tuple(kept), start, step, initial_outputs)
    return ModelGraph(tuple(parameters), tuple(outputs), tuple(data_columns), None, dyn, tuple(models), models)

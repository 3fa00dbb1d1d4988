"""Generate an FMU's C equations, variable table and both model descriptions from its definition.

Run by the CMake build (``python -m milling_twin.models.codegen SpindlePower build/generated/SpindlePower``).
Writes into the output folder:

- ``model_generated.h`` / ``model_generated.c``: value references, the ``ModelVariables`` struct,
  the variable table the generic FMI wrapper uses for every get/set/range check, and
  ``model_evaluate_equations`` (straight-line C translated instruction by instruction from
  the casadi expression graph, so the FMU computes exactly what calibration fits);
- ``model_constants.h``: the constants the model's C code shares with its Python definition
  (``ModelDefinition.constants``: OMEGA_MIN, TWO_PI, the interpolator's tuning constants ...), so they are
  written once, in models/;
- ``config.h`` with ``--config``: the ``ModelInternal`` of a model that keeps nothing besides its variables
  and generated states (its hooks are ``fmus/common/generated_model.c``; its folder has no config.h);
- ``fmi2/modelDescription.xml`` and ``fmi3/modelDescription.xml``.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.metadata
import math
import os
import subprocess
import sys
import tomllib
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path
from xml.sax.saxutils import quoteattr

import casadi as ca

from milling_twin import __version__
from milling_twin.models import MODELS
from milling_twin.models.definition import STRING_CAPACITY, ModelDefinition, Variable

FMU_MAX_RANK = 4  # fmus/common/fmu_variables.h: dimensions of an FMI 3 array the variable table describes
from milling_twin.models.units import BASE_DIMENSIONS, parse_unit, si_unit_of

GENERATION_TOOL = f"milling-twin {__version__} models.codegen"
AUTHOR = "The milling-twin authors"
#: What the licence attribute says while the project declares none (no [project] license, no LICENSE file).
NO_LICENCE = "No licence declared: the milling-twin project states none (pyproject.toml, LICENSE)"
#: The unit of every dimensionless Float64 variable in the model descriptions (declared in UnitDefinitions).
DIMENSIONLESS = "1"
REPOSITORY = Path(__file__).resolve().parents[1]

# SI unit -> the display units its model-description <Unit> offers (dimensions and factors: models.units).
DISPLAY_UNITS: dict[str, tuple[str, ...]] = {
    "W": ("kW",),
    "rad/s": ("rpm",),
    "W.s/rad": ("W/rpm",),
    "m3/s": ("cm3/min", "mm3/s"),
    "m": ("mm", "um"),
    "m/s": ("mm/min", "mm/s"),
    "s": ("ms",),
}

# casadi operation -> C expression template over operands {0}, {1}
_BINARY = {
    ca.OP_ADD: "{0} + {1}", ca.OP_SUB: "{0} - {1}", ca.OP_MUL: "{0} * {1}", ca.OP_DIV: "{0} / {1}",
    ca.OP_POW: "pow({0}, {1})", ca.OP_CONSTPOW: "pow({0}, {1})", ca.OP_FMIN: "fmin({0}, {1})",
    ca.OP_FMAX: "fmax({0}, {1})", ca.OP_ATAN2: "atan2({0}, {1})", ca.OP_LT: "(double)({0} < {1})",
    ca.OP_LE: "(double)({0} <= {1})", ca.OP_EQ: "(double)({0} == {1})", ca.OP_NE: "(double)({0} != {1})",
    ca.OP_AND: "(double)({0} != 0.0 && {1} != 0.0)", ca.OP_OR: "(double)({0} != 0.0 || {1} != 0.0)",
    ca.OP_IF_ELSE_ZERO: "({0} != 0.0 ? {1} : 0.0)", ca.OP_HYPOT: "hypot({0}, {1})",
    ca.OP_FMOD: "fmod({0}, {1})", ca.OP_COPYSIGN: "copysign({0}, {1})",
}
_UNARY = {
    ca.OP_NEG: "-{0}", ca.OP_SQ: "{0} * {0}", ca.OP_TWICE: "2.0 * {0}", ca.OP_INV: "1.0 / {0}",
    ca.OP_SQRT: "sqrt({0})", ca.OP_FABS: "fabs({0})", ca.OP_SIN: "sin({0})", ca.OP_COS: "cos({0})",
    ca.OP_TAN: "tan({0})", ca.OP_EXP: "exp({0})", ca.OP_LOG: "log({0})", ca.OP_TANH: "tanh({0})",
    ca.OP_ATAN: "atan({0})", ca.OP_ASIN: "asin({0})", ca.OP_ACOS: "acos({0})", ca.OP_SINH: "sinh({0})",
    ca.OP_COSH: "cosh({0})", ca.OP_FLOOR: "floor({0})", ca.OP_CEIL: "ceil({0})", ca.OP_ERF: "erf({0})",
    ca.OP_NOT: "(double)({0} == 0.0)", ca.OP_SIGN: "(double)(({0} > 0.0) - ({0} < 0.0))",
    ca.OP_ASSIGN: "{0}",
}


def value_references(model: ModelDefinition) -> dict[str, int]:
    """VR 0 is the independent variable ``time``; model variables follow in definition order (an
    array is one variable in FMI 3)."""
    return {v.name: i + 1 for i, v in enumerate(model.variables)}


def fmi2_element_references(model: ModelDefinition) -> dict[str, list[int]]:
    """FMI 2 has no arrays: each array element is a scalar, numbered after all the variables (so
    the other variables keep their FMI 3 value references)."""
    next_vr = len(model.variables) + 1
    result: dict[str, list[int]] = {}
    for v in model.variables:
        if v.shape:
            result[v.name] = list(range(next_vr, next_vr + v.size))
            next_vr += v.size
    return result


def c_double(x: float) -> str:
    """A double as a C expression. INFINITY is not a constant expression under MSVC 19.42+ with the Windows SDK
    10.0.26100 (error C2099 in a static initializer), so this is for statements only; static data uses
    c_bound and c_static_double."""
    if math.isinf(x):
        return "INFINITY" if x > 0 else "-INFINITY"
    return repr(float(x))


def c_bound(x: float) -> str:
    """A range bound of the variable table, a static initializer: an unbounded side is -DBL_MAX/DBL_MAX, which
    allows every finite value as -INFINITY/INFINITY would (NaN and Inf are refused before the range check)."""
    if math.isnan(x):
        raise ValueError("a range bound cannot be NaN")
    if math.isinf(x):
        return "DBL_MAX" if x > 0 else "-DBL_MAX"
    return repr(float(x))


def c_static_double(name: str, x: float) -> str:
    """An element of a static const double array: finite only (see c_double)."""
    if not math.isfinite(x):
        raise ValueError(f"constant {name}: {x!r} in a tuple; the C arrays hold finite numbers only")
    return repr(float(x))


_C_TYPES = {"Float64": "double", "Int32": "int32_t", "Boolean": "bool", "String": "char"}
_TABLE_TYPES = {"Float64": "FMU_FLOAT64", "Int32": "FMU_INT32", "Boolean": "FMU_BOOLEAN", "String": "FMU_STRING"}


def _field(model: ModelDefinition, name: str) -> str:
    """The C lvalue of a variable or state of ``ModelVariables *v``."""
    return f"v->states.{name}" if any(s.name == name for s in model.states) else f"v->{name}"


def translate(model: ModelDefinition, function: ca.Function, arguments: list[str], results: list[str],
              extra_arguments: dict[str, str] | None = None) -> list[str]:
    """C statements evaluating ``function`` instruction by instruction: arguments are read from
    the fields of ``v`` (or ``extra_arguments``: name -> C expression), results are written to the
    fields named ``results`` after all of them are computed (a state may be read and written)."""
    extra = extra_arguments or {}
    kinds = {v.name: v.type for v in model.variables}
    lines: list[str] = []
    for k in range(function.n_instructions()):
        op = function.instruction_id(k)
        ins = function.instruction_input(k)
        outs = function.instruction_output(k)
        if op == ca.OP_INPUT:
            name = arguments[ins[0]]
            source = extra[name] if name in extra else _field(model, name)
            cast = "(double)" if kinds.get(name, "Float64") != "Float64" else ""
            lines.append(f"w[{outs[0]}] = {cast}{source};")
        elif op == ca.OP_OUTPUT:
            lines.append(f"result[{outs[0]}] = w[{ins[0]}];")
        elif op == ca.OP_CONST:
            lines.append(f"w[{outs[0]}] = {c_double(function.instruction_constant(k))};")
        elif op in _BINARY:
            lines.append(f"w[{outs[0]}] = " + _BINARY[op].format(*(f"w[{i}]" for i in ins)) + ";")
        elif op in _UNARY:
            lines.append(f"w[{outs[0]}] = " + _UNARY[op].format(f"w[{ins[0]}]") + ";")
        else:
            raise ValueError(f"{model.identifier}: casadi operation {op} has no C translation")
    for i, name in enumerate(results):
        kind = kinds.get(name, "Float64")
        value = f"(result[{i}] != 0.0)" if kind == "Boolean" else (
            f"(int32_t)result[{i}]" if kind == "Int32" else f"result[{i}]")
        lines.append(f"{_field(model, name)} = {value};")
    return lines


def _function_body(model: ModelDefinition, function: ca.Function, results: list[str],
                   extra_arguments: dict[str, str] | None = None) -> str:
    arguments = [v.name for v in model.arguments] + list(extra_arguments or {})
    lines = [f"double w[{max(1, function.sz_w())}];", f"double result[{max(1, len(results))}];"]
    lines += translate(model, function, arguments, results, extra_arguments)
    if not results:
        lines += ["(void)v;", "(void)w;", "(void)result;"]
    return "\n".join("    " + line for line in lines)


def _c_type(v: Variable) -> str:
    return _C_TYPES[v.type]


def _c_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _c_value(v: Variable) -> str:
    if v.type == "String":
        return _c_string(str(v.start))
    if v.type == "Boolean":
        return "true" if v.start else "false"
    if v.type == "Int32":
        return str(int(v.start))
    return c_double(v.start)


def generate_header(model: ModelDefinition, descriptions: str = "") -> str:
    """``descriptions``: a digest of the model descriptions, written into a comment so that a change of a description
    alone (e.g. its dependencies) rebuilds and repackages the FMU, whose packaging follows its binary."""
    vrs = value_references(model)
    enum = "\n".join(f"    VR_{v.name} = {vrs[v.name]}," for v in model.variables)
    fields = "\n".join(
        f"    {_c_type(v)} {v.name}{'[FMU_STRING_CAPACITY]' if v.type == 'String' else ''}"
        f"{f'[{v.size}]' if v.shape else ''}; /* [{v.unit or '1'}] {v.description}"
        f"{f' (array {v.shape}, row-major)' if v.shape else ''} */" for v in model.variables)
    sizes = "".join(f"#define SIZE_{v.name} {v.size}\n" for v in model.variables if v.shape)
    states = ""
    if model.states:
        state_fields = "\n".join(f"    double {s.name}; /* [{s.unit or '1'}] {s.description} */" for s in model.states)
        states = f"typedef struct {{\n{state_fields}\n}} ModelStates;\n\n"
        fields += "\n    ModelStates states; /* kept between steps, not FMI variables */"
    digest = f"/* Model descriptions: sha256 {descriptions} */\n" if descriptions else ""
    return f"""/* Generated by {GENERATION_TOOL} from models/ ({model.identifier}). Do not edit. */
{digest}#ifndef MODEL_GENERATED_H
#define MODEL_GENERATED_H

#include <stdbool.h>
#include <stdint.h>
#include "fmu_variables.h"

#define MODEL_IDENTIFIER_STRING "{model.identifier}"
#define INSTANTIATION_TOKEN "{model.instantiation_token()}"
#define FMU_STRING_CAPACITY {STRING_CAPACITY}
{sizes}
enum {{
    VR_time = 0,
{enum}
}};

{states}typedef struct {{
{fields}
}} ModelVariables;

/* The variable table of the FMI version being built (model_table_fmi2.c or model_table_fmi3.c):
 * row i describes value reference i; rows without a name are value references not in use. */
extern const FmuVariable MODEL_VARIABLE_TABLE[];
extern const unsigned int MODEL_VARIABLE_COUNT;

void model_set_start_values(ModelVariables *v);

/* Outputs from parameters, inputs and states: the equations of models/, translated. */
void model_evaluate_equations(ModelVariables *v);

/* States at the end of a step of size h, inputs held over the step: the update of models/. */
void model_update_states(ModelVariables *v, double h);

#endif
"""


def _constant_value(name: str, value: object) -> str:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"constant {name}: an int, a float or a tuple of floats, got {value!r}")
    text = str(value) if isinstance(value, int) else c_double(value)
    return f"({text})" if text.startswith("-") else text


def generate_constants(model: ModelDefinition) -> str:
    """model_constants.h: ints and floats as macros, tuples of floats as static const double arrays (Python's
    repr of a float reads back as the same double in C)."""
    lines = []
    for name, value in model.constants:
        if isinstance(value, tuple):
            items = ", ".join(c_static_double(name, float(x)) for x in value)
            lines.append(f"static const double {name}[{len(value)}] = {{{items}}};")
        else:
            lines.append(f"#define {name} {_constant_value(name, value)}")
    body = "\n".join(lines) or "/* none */"
    return f"""/* Generated by {GENERATION_TOOL} from models/ ({model.identifier}): the constants its C code shares with
 * the Python definition (ModelDefinition.constants), under their Python names. Do not edit. */
#ifndef MODEL_CONSTANTS_H
#define MODEL_CONSTANTS_H

{body}

#endif
"""


def generate_config(model: ModelDefinition) -> str:
    """config.h of a model that keeps nothing besides its variables and generated states."""
    return f"""/* Generated by {GENERATION_TOOL} from models/ ({model.identifier}). Do not edit. Variables, states and
 * equations are generated (model_generated.h); the model's hooks are fmus/common/generated_model.c and it keeps
 * nothing else between steps. */
#ifndef CONFIG_H
#define CONFIG_H

#include "model_generated.h"

typedef struct {{
    int unused;
}} ModelInternal;

#endif
"""


def _dims(v: Variable | None, element: bool = False) -> str:
    """The C initializer of a row's rank and dimensions (FMI 3 arrays; scalars and FMI 2 elements: rank 0)."""
    shape = v.shape if v is not None and v.shape and not element else ()
    if len(shape) > FMU_MAX_RANK:
        raise ValueError(f"{v.name}: arrays have at most {FMU_MAX_RANK} dimensions")
    dims = list(shape) + [0] * (FMU_MAX_RANK - len(shape))
    return f"{len(shape)}, {{ {', '.join(str(d) for d in dims)} }}"


def _table_row(model: ModelDefinition, v: Variable | None, vr: str = "", name: str = "", element: int = 0,
               count: int = 1, is_element: bool = False) -> str:
    if v is None:
        return ('    { VR_time, "time", FMU_FLOAT64, FMU_INDEPENDENT, FMU_CONTINUOUS, 0, 1, '
                f'-DBL_MAX, DBL_MAX, "s", {_dims(None)} }},')
    lo = c_bound(v.min if v.min is not None else -math.inf)
    hi = c_bound(v.max if v.max is not None else math.inf)
    offset = f"offsetof(ModelVariables, {v.name})" + (f" + {element} * sizeof(double)" if element else "")
    return (f'    {{ {vr or f"VR_{v.name}"}, "{name or v.name}", {_TABLE_TYPES[v.type]}, FMU_{v.causality.upper()}, '
            f'FMU_{v.effective_variability.upper()}, {offset}, {count}, {lo}, {hi}, "{v.unit}", '
            f'{_dims(v, is_element)} }},')


def generate_table(model: ModelDefinition, fmi: int) -> str:
    """The variable table of one FMI version: row i is value reference i."""
    rows = [_table_row(model, None)]
    for v in model.variables:
        if v.shape and fmi == 2:  # the array's FMI 3 value reference is not in use in FMI 2
            rows.append(f"    {{ VR_{v.name}, NULL, FMU_FLOAT64, FMU_{v.causality.upper()}, FMU_CONTINUOUS, 0, 0, "
                        f"0.0, 0.0, \"\", {_dims(None)} }},")
        else:
            rows.append(_table_row(model, v, count=max(1, v.size)))
    for v in model.variables:
        if v.shape and fmi == 2:
            for k, (vr, name) in enumerate(zip(fmi2_element_references(model)[v.name], v.element_names())):
                rows.append(_table_row(model, v, vr=str(vr), name=name, element=k, is_element=True))
    body = "\n".join(rows)
    return f"""/* Generated by {GENERATION_TOOL} from models/ ({model.identifier}): FMI {fmi} variables. Do not edit. */
#include <float.h>
#include <stddef.h>
#include "model_generated.h"

const FmuVariable MODEL_VARIABLE_TABLE[] = {{
{body}
}};

const unsigned int MODEL_VARIABLE_COUNT = sizeof MODEL_VARIABLE_TABLE / sizeof MODEL_VARIABLE_TABLE[0];
"""


def generate_source(model: ModelDefinition) -> str:
    starts = "\n".join(
        f"    snprintf(v->{v.name}, sizeof v->{v.name}, \"%s\", {_c_value(v)});" if v.type == "String"
        else f"    for (i = 0; i < SIZE_{v.name}; i++) v->{v.name}[i] = {_c_value(v)};" if v.shape
        else f"    v->{v.name} = {_c_value(v)};" for v in model.variables if v.start is not None)
    if any(v.shape and v.start is not None for v in model.variables):
        starts = "    int i;\n" + starts
    starts += "".join(f"\n    v->states.{s.name} = {c_double(s.start)};" for s in model.states)
    outputs = "\n".join(f"    v->{v.name} = 0;" for v in model.of("output") if v.type != "String" and not v.shape)
    outputs_computed = [v.name for v in model.computed_outputs]
    equations = _function_body(model, model.function(), outputs_computed)
    specialized = ""
    if model.specialize_on is not None:  # one copy per value, chosen at run time; the generic one otherwise
        # (with specialize_split, two per value: the split parameter below its threshold, suffix "", and at or above)
        sides = [("", model.split_values()[0]), ("_split", model.split_values()[1])] if model.specialize_split \
            else [("", None)]
        switches = {}
        for suffix, split in sides:
            for n in model.specialized_values():
                specialized += (f"static void evaluate_equations_{n}{suffix}(ModelVariables *v) {{\n"
                                f"{_function_body(model, model.function(n, split), outputs_computed)}\n}}\n\n")
            cases = "".join(f"    case {n}: evaluate_equations_{n}{suffix}(v); return;\n"
                            for n in model.specialized_values())
            switches[suffix] = (f"    switch (v->{model.specialize_on}) {{\n{cases}"
                                f"    default: evaluate_equations_generic(v); return;\n    }}")
        specialized += (f"static void evaluate_equations_generic(ModelVariables *v) {{\n{equations}\n}}\n\n")
        equations = switches[""]
        if model.specialize_split:
            name, threshold = model.specialize_split
            split_switch = switches["_split"].replace("\n    ", "\n        ").replace("    switch", "        switch", 1)
            equations = f"    if (v->{name} >= {threshold}) {{\n{split_switch}\n    }}\n{equations}"
        if model.specialize_fixed:  # the copies hold only while the fixed parameters have their values
            held = " || ".join(f"v->{name} != {value}" for name, value in model.specialize_fixed)
            equations = f"    if ({held}) {{\n        evaluate_equations_generic(v);\n        return;\n    }}\n{equations}"
    update = _function_body(model, model.update_function(), [s.name for s in model.updated_states], {"h": "h"})
    unused_h = "" if model.updated_states else "    (void)h;\n"
    return f"""/* Generated by {GENERATION_TOOL} from models/ ({model.identifier}). Do not edit. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include "model_generated.h"

void model_set_start_values(ModelVariables *v) {{
{starts}
{outputs}
}}

{specialized}void model_evaluate_equations(ModelVariables *v) {{
{equations}
}}

void model_update_states(ModelVariables *v, double h) {{
{unused_h}{update}
}}
"""


def _attr(name: str, value: object) -> str:
    return f" {name}={quoteattr(str(value))}"


def _number(x: float) -> str:
    return repr(float(x))


def description_unit(v: Variable) -> str:
    """The unit a Float64 variable has in the model descriptions: its own, or DIMENSIONLESS ("1") when it has none,
    so every Float64 variable has a unit defined in UnitDefinitions (Int32, Boolean, String: none)."""
    if v.type != "Float64":
        return ""
    return v.unit or DIMENSIONLESS


def _unit_definitions(model: ModelDefinition) -> str:
    used = sorted({description_unit(v) for v in model.variables if description_unit(v)} | {"s"})  # "s": time
    parts = ["  <UnitDefinitions>"]
    for unit in used:
        si = parse_unit(unit)
        if si.factor != 1.0 or si_unit_of(unit) != unit:
            raise ValueError(f"{model.identifier}: unit '{unit}' is not the SI unit of its dimension")
        base = {name: e for name, e in zip(BASE_DIMENSIONS, si.dimensions) if e != 0}
        displays = [v.display_unit for v in model.variables if description_unit(v) == unit and v.display_unit]
        parts.append(f"    <Unit{_attr('name', unit)}>")
        parts.append("      <BaseUnit" + "".join(_attr(k, e) for k, e in base.items()) + "/>")
        for name in dict.fromkeys([*displays, *DISPLAY_UNITS.get(unit, ())]):
            # FMI: display value = factor * value; models.units: SI value = factor * display value
            factor = _number(float(f"{1.0 / parse_unit(name).factor:.15g}"))
            parts.append(f"      <DisplayUnit{_attr('name', name)}{_attr('factor', factor)}/>")
        parts.append("    </Unit>")
    parts.append("  </UnitDefinitions>")
    return "\n".join(parts)


LOG_CATEGORIES = (
    ("logEvents", "Initialization, parameter checks and other events"),
    ("logStatusWarning", "Warnings"),
    ("logStatusError", "Errors: illegal call sequences, bad arguments, rejected values"),
)


def _log_categories() -> str:
    rows = "\n".join(f"    <Category{_attr('name', n)}{_attr('description', d)}/>" for n, d in LOG_CATEGORIES)
    return f"  <LogCategories>\n{rows}\n  </LogCategories>"


def _value_attrs(v: Variable, fmi: int) -> str:
    out = ""
    if v.type in ("Float64", "Int32"):
        if description_unit(v):
            out += _attr("unit", description_unit(v))
        if v.display_unit:
            out += _attr("displayUnit", v.display_unit)
        fmt = (lambda x: str(int(x))) if v.type == "Int32" else _number
        if v.min is not None:
            out += _attr("min", fmt(v.min))
        if v.max is not None:
            out += _attr("max", fmt(v.max))
    if v.start is not None and not (v.type == "String" and fmi == 3):  # FMI 3: a <Start> element
        start = str(v.start) if v.type == "String" else _c_value(v) if v.type != "Float64" else _number(v.start)
        if v.shape and fmi == 3:  # every element, row-major (FMI 2: each element's own start)
            start = " ".join([start] * v.size)
        out += _attr("start", start)
    return out


def generation_time() -> datetime:
    """When the sources were last changed, so that regenerating gives the same files: SOURCE_DATE_EPOCH if set (the
    reproducible-builds convention; a release build sets it), else the date of the last commit that touched models/
    in the repository the generator runs from, else the Unix epoch (no repository, e.g. an installed package)."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if epoch:
        try:
            return datetime.fromtimestamp(int(epoch), tz=timezone.utc)
        except ValueError:
            raise ValueError(f"SOURCE_DATE_EPOCH={epoch!r}: not an integer number of seconds") from None
    return _last_models_commit()


@lru_cache(maxsize=1)
def _last_models_commit() -> datetime:
    try:
        out = subprocess.run(["git", "-C", str(REPOSITORY), "log", "-1", "--format=%ct", "--", "models"],
                             capture_output=True, text=True, timeout=30, check=False).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        out = ""
    return datetime.fromtimestamp(int(out) if out.isdigit() else 0, tz=timezone.utc)


@lru_cache(maxsize=1)
def licence() -> str:
    """The project's licence: [project] license of the repository's pyproject.toml (a string, or a table with text
    or file), else the installed package's License-Expression / License, else NO_LICENCE."""
    pyproject = REPOSITORY / "pyproject.toml"
    if pyproject.is_file():
        declared = tomllib.loads(pyproject.read_text()).get("project", {}).get("license")
        if isinstance(declared, str) and declared.strip():
            return declared.strip()
        if isinstance(declared, dict) and (declared.get("text") or declared.get("file")):
            return str(declared.get("text") or f"see {declared['file']}")
        return NO_LICENCE
    try:
        meta = importlib.metadata.metadata("milling-twin")
    except importlib.metadata.PackageNotFoundError:
        return NO_LICENCE
    return meta.get("License-Expression") or meta.get("License") or NO_LICENCE


def description_metadata() -> dict[str, str]:
    """The attributes of <fmiModelDescription> that describe the FMU's origin, the same in FMI 2 and FMI 3."""
    when = generation_time()
    return {"author": AUTHOR, "version": __version__, "copyright": f"Copyright {when.year} {AUTHOR}",
            "license": licence(), "generationTool": GENERATION_TOOL,
            "generationDateAndTime": when.strftime("%Y-%m-%dT%H:%M:%SZ")}


def _common_header(model: ModelDefinition, fmi: int) -> str:
    token_attr = "instantiationToken" if fmi == 3 else "guid"
    extra = "" if fmi == 3 else _attr("numberOfEventIndicators", 0)
    metadata = "".join(_attr(k, v) for k, v in description_metadata().items())
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription'
            f'{_attr("fmiVersion", "3.0" if fmi == 3 else "2.0")}{_attr("modelName", model.identifier)}'
            f'{_attr("description", model.description)}{_attr(token_attr, model.instantiation_token())}'
            f'{metadata}{_attr("variableNamingConvention", "flat")}{extra}>')


def _dependency_attrs(references: list[int]) -> str:
    """dependencies (sorted, as FMI 2 requires of indices) and, when there are any, dependenciesKind: "dependent"
    (no particular structure claimed). An empty list says: depends on no known."""
    ordered = sorted(set(references))
    kinds = _attr("dependenciesKind", " ".join(["dependent"] * len(ordered))) if ordered else ""
    return _attr("dependencies", " ".join(str(r) for r in ordered)) + kinds


def output_knowns(model: ModelDefinition, fmi: int, initial: bool) -> dict[str, list[str]]:
    """Output -> the variables listed as its dependencies. At a communication point (<Outputs>/<Output>) the knowns
    are the inputs (FMI 2.0 2.2.8), and in FMI 3 the tunable parameters too (FMI 3.0 2.4.8: fixed ones are frozen
    there); in Initialization Mode (<InitialUnknowns>) the inputs and every parameter (initial = exact)."""
    def known(name: str) -> bool:
        v = model.variable(name)
        if v.causality == "input" or initial:
            return True
        return fmi == 3 and v.effective_variability == "tunable"
    return {output: [n for n in names if known(n)] for output, names in model.direct_dependencies(initial).items()}


def _default_experiment(model: ModelDefinition) -> str:
    return (f"  <DefaultExperiment{_attr('startTime', '0.0')}{_attr('stopTime', _number(model.default_stop_time))}"
            f"{_attr('stepSize', _number(model.default_step_size))}/>")


def model_description_fmi3(model: ModelDefinition) -> str:
    vrs = value_references(model)
    variables = ['    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"'
                 ' unit="s" description="Simulation time"/>']
    for v in model.variables:
        initial = _attr("initial", "calculated") if v.causality == "output" else ""
        opening = (f"    <{v.type}{_attr('name', v.name)}{_attr('valueReference', vrs[v.name])}"
                   f"{_attr('causality', v.causality)}{_attr('variability', v.effective_variability)}{initial}"
                   f"{_attr('description', v.description)}{_value_attrs(v, 3)}")
        if v.type == "String" and v.start is not None:
            variables.append(f"{opening}>\n      <Start{_attr('value', v.start)}/>\n    </String>")
        elif v.shape:
            dimensions = "".join(f"\n      <Dimension{_attr('start', n)}/>" for n in v.shape)
            variables.append(f"{opening}>{dimensions}\n    </{v.type}>")
        else:
            variables.append(f"{opening}/>")
    step, initial = output_knowns(model, 3, False), output_knowns(model, 3, True)
    outputs = [f"    <Output{_attr('valueReference', vrs[v.name])}{_dependency_attrs([vrs[n] for n in step[v.name]])}/>"
               for v in model.of("output")]
    initial_unknowns = [f"    <InitialUnknown{_attr('valueReference', vrs[v.name])}"
                        f"{_dependency_attrs([vrs[n] for n in initial[v.name]])}/>" for v in model.of("output")]
    return "\n".join([
        _common_header(model, 3),
        f"  <CoSimulation{_attr('modelIdentifier', model.identifier)}"
        ' canHandleVariableCommunicationStepSize="true" canGetAndSetFMUState="true"'
        ' canSerializeFMUState="true" canReturnEarlyAfterIntermediateUpdate="false"'
        ' providesIntermediateUpdate="false" hasEventMode="false" needsExecutionTool="false"/>',
        _unit_definitions(model), _log_categories(), _default_experiment(model),
        "  <ModelVariables>", *variables, "  </ModelVariables>",
        "  <ModelStructure>", *outputs, *initial_unknowns, "  </ModelStructure>",
        "</fmiModelDescription>", ""])


def build_description_fmi3(model: ModelDefinition, sources: list[str]) -> str:
    files = "\n".join(f"      <SourceFile{_attr('name', name)}/>" for name in sources)
    return "\n".join([
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<fmiBuildDescription fmiVersion="3.0">',
        f"  <BuildConfiguration{_attr('modelIdentifier', model.identifier)}>",
        '    <SourceFileSet language="C99">', files, "    </SourceFileSet>",
        "  </BuildConfiguration>", "</fmiBuildDescription>", ""])


def model_description_fmi2(model: ModelDefinition, sources: list[str]) -> str:
    vrs = value_references(model)
    variables = ['    <ScalarVariable name="time" valueReference="0" causality="independent"'
                 ' variability="continuous" description="Simulation time">\n      <Real unit="s"/>\n'
                 '    </ScalarVariable>']
    elements = fmi2_element_references(model)
    output_indices: list[tuple[str, int]] = []
    indices: dict[str, list[int]] = {}  # variable -> its scalars' 1-based indices in ModelVariables
    for v in model.variables:
        element = {"Float64": "Real", "Int32": "Integer", "Boolean": "Boolean", "String": "String"}[v.type]
        initial = _attr("initial", "calculated") if v.causality == "output" else ""
        scalars = list(zip(v.element_names(), elements[v.name])) if v.shape else [(v.name, vrs[v.name])]
        for name, vr in scalars:
            variables.append(
                f"    <ScalarVariable{_attr('name', name)}{_attr('valueReference', vr)}"
                f"{_attr('causality', v.causality)}{_attr('variability', v.effective_variability)}{initial}"
                f"{_attr('description', v.description)}>\n      <{element}{_value_attrs(v, 2)}/>\n"
                "    </ScalarVariable>")
            indices.setdefault(v.name, []).append(len(variables))  # 1-based index in ModelVariables
            if v.causality == "output":
                output_indices.append((v.name, len(variables)))
    step, initial = output_knowns(model, 2, False), output_knowns(model, 2, True)
    outputs = [f"      <Unknown{_attr('index', i)}{_dependency_attrs([k for n in step[name] for k in indices[n]])}/>"
               for name, i in output_indices]
    initial_unknowns = [f"      <Unknown{_attr('index', i)}"
                        f"{_dependency_attrs([k for n in initial[name] for k in indices[n]])}/>"
                        for name, i in output_indices]
    files = [f"      <File{_attr('name', name)}/>" for name in sources]
    return "\n".join([
        _common_header(model, 2),
        f"  <CoSimulation{_attr('modelIdentifier', model.identifier)}"
        ' canHandleVariableCommunicationStepSize="true" canGetAndSetFMUstate="true"'
        ' canSerializeFMUstate="true" canInterpolateInputs="false" canNotUseMemoryManagementFunctions="true">',
        "    <SourceFiles>", *files, "    </SourceFiles>", "  </CoSimulation>",
        _unit_definitions(model), _log_categories(), _default_experiment(model),
        "  <ModelVariables>", *variables, "  </ModelVariables>",
        "  <ModelStructure>", "    <Outputs>", *outputs, "    </Outputs>",
        "    <InitialUnknowns>", *initial_unknowns, "    </InitialUnknowns>", "  </ModelStructure>",
        "</fmiModelDescription>", ""])


def write_if_changed(path: Path, text: str) -> None:
    """Keep timestamps of unchanged files so the build does not recompile them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def generate(model: ModelDefinition, out_dir: Path, sources: list[str], config: bool = False) -> None:
    """``sources``: the C files (names inside the FMU's sources/ folder) that build the binary; ``config``: write
    config.h too (a model without hand-written state)."""
    fmi2_sources = sources + ["model_table_fmi2.c", "fmi2_api.c"]
    fmi3_sources = sources + ["model_table_fmi3.c", "fmi3_api.c"]
    descriptions = {"fmi2": model_description_fmi2(model, fmi2_sources), "fmi3": model_description_fmi3(model)}
    digest = hashlib.sha256((descriptions["fmi2"] + descriptions["fmi3"]).encode()).hexdigest()
    write_if_changed(out_dir / "model_generated.h", generate_header(model, digest))
    write_if_changed(out_dir / "model_constants.h", generate_constants(model))
    if config:
        write_if_changed(out_dir / "config.h", generate_config(model))
    write_if_changed(out_dir / "model_generated.c", generate_source(model))
    for fmi in (2, 3):
        write_if_changed(out_dir / f"model_table_fmi{fmi}.c", generate_table(model, fmi))
    for fmi, text in descriptions.items():
        write_if_changed(out_dir / fmi / "modelDescription.xml", text)
    write_if_changed(out_dir / "fmi3" / "buildDescription.xml", build_description_fmi3(model, fmi3_sources))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help=f"model identifier, one of: {', '.join(MODELS)}")
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--sources", nargs="*", default=[],
                        help="C files shared by both FMI versions (the FMI-version API file is added)")
    parser.add_argument("--config", action="store_true",
                        help="write config.h too (a model whose folder has none: nothing kept besides its variables)")
    args = parser.parse_args(argv)
    if args.model not in MODELS:
        print(f"error: unknown model '{args.model}'; known: {', '.join(MODELS)}", file=sys.stderr)
        return 2
    generate(MODELS[args.model], args.out_dir, ["model_generated.c", *args.sources], config=args.config)
    return 0


if __name__ == "__main__":
    sys.exit(main())

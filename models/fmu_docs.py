"""The FMU's documentation/index.html, written from its ModelDefinition at build time (fmus/CMakeLists.txt, add_fmu):
one self-contained HTML page per FMI version (inline style, no links, no scripts, no images) with the model's
description, every variable of its modelDescription.xml (value reference, causality, variability, type, unit and
display unit, start, min and max, description; an array as one row, with its FMI 2 scalars named), the parts its
C code computes itself, and the Python source of its equations and state update (the module in models/ they are
generated from).

    python -m milling_twin.models.fmu_docs MODEL OUT_DIR   ->  OUT_DIR/fmi2/documentation/index.html, fmi3/...
"""
from __future__ import annotations

import argparse
import html
import inspect
import sys
import textwrap
from pathlib import Path
from typing import Callable

from milling_twin import __version__
from milling_twin.models import MODELS
from milling_twin.models.codegen import fmi2_element_references, value_references
from milling_twin.models.definition import ModelDefinition, Variable

STYLE = """body { font-family: sans-serif; margin: 2em; max-width: 80em; color: #222; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.5em; text-align: left; vertical-align: top; }
th { background: #eee; }
pre { background: #f6f6f6; padding: 0.75em; overflow-x: auto; font-size: 0.85em; }
code { font-size: 0.95em; }"""

COLUMNS = ("Name", "Value reference", "Causality", "Variability", "Type", "Unit", "Display unit", "Start", "Min",
           "Max", "Description")


def _text(value: object) -> str:
    return html.escape(str(value), quote=True)


def _number(value: object) -> str:
    return "" if value is None else repr(value) if isinstance(value, float) else str(value)


def _unit(v: Variable) -> str:
    if v.type != "Float64":
        return ""
    return v.unit or "1"  # dimensionless


def _name_cell(v: Variable, fmi: int) -> str:
    if not v.shape:
        return f"<code>{_text(v.name)}</code>"
    names = v.element_names()
    dims = " x ".join(str(d) for d in v.shape)
    where = (f"FMI 2: {len(names)} scalars <code>{_text(names[0])}</code> .. <code>{_text(names[-1])}</code>, "
             "row-major" if fmi == 2 else "one array variable")
    return f"<code>{_text(v.name)}</code> [{dims}]<br>{where}"


def _references(model: ModelDefinition, v: Variable, fmi: int) -> str:
    if fmi == 2 and v.shape:
        refs = fmi2_element_references(model)[v.name]
        return f"{refs[0]} .. {refs[-1]}"
    return str(value_references(model)[v.name])


def _row(cells: list[str]) -> str:
    return "<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>"


def variable_rows(model: ModelDefinition, fmi: int) -> list[str]:
    rows = [_row(["<code>time</code>", "0", "independent", "continuous", "Float64", "s", "", "", "", "",
                  "Simulation time"])]
    for v in model.variables:
        start = v.start if v.start is not None else ""
        rows.append(_row([_name_cell(v, fmi), _references(model, v, fmi), v.causality, v.effective_variability,
                          v.type, _text(_unit(v)), _text(v.display_unit), _text(_number(start)),
                          _text(_number(v.min)), _text(_number(v.max)), _text(v.description)]))
    return rows


def _source(function: Callable | None) -> str:
    if function is None:
        return ""
    try:
        return textwrap.dedent(inspect.getsource(function))
    except (OSError, TypeError):
        return ""


def _module_file(model: ModelDefinition) -> str:
    """models/<module>.py of the definition (where its equations are), as a repository path."""
    function = model.equations or model.update
    module = sys.modules.get(function.__module__) if function is not None else None
    path = Path(getattr(module, "__file__", "") or "")
    parts = path.parts
    return "/".join(parts[parts.index("models"):]) if "models" in parts else path.name


def page(model: ModelDefinition, fmi: int) -> str:
    """The HTML page of ``model`` in its FMI ``fmi`` (2 or 3) FMU."""
    counts = {c: sum(1 for v in model.variables if v.causality == c) for c in ("parameter", "input", "output")}
    native = ", ".join(f"<code>{_text(n)}</code>" for n in model.native_outputs + model.native_states)
    sections = [
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        f"<title>{_text(model.identifier)} (FMI {fmi}.0)</title>", f"<style>\n{STYLE}\n</style>", "</head>", "<body>",
        f"<h1>{_text(model.identifier)}</h1>",
        f"<p>{_text(model.description)}</p>",
        f"<p>FMI {fmi}.0 co-simulation FMU of milling-twin {_text(__version__)}. "
        f"{counts['parameter']} parameters, {counts['input']} inputs, {counts['output']} outputs; default step "
        f"{_number(model.default_step_size)} s, default stop time {_number(model.default_stop_time)} s. Values are "
        "in SI units (the unit column); the display unit is what tools show.</p>",
    ]
    if model.states:
        states = ", ".join(f"<code>{_text(s.name)}</code> ({_text(s.description)})" for s in model.states)
        sections.append(f"<p>States kept between steps: {states}.</p>")
    if native:
        sections.append(f"<p>Computed by the FMU's own C code (model.c, in sources/), not by the generated "
                        f"equations: {native}.</p>")
    sections += ["<h2>Variables</h2>", "<table>", "<tr>" + "".join(f"<th>{c}</th>" for c in COLUMNS) + "</tr>",
                 *variable_rows(model, fmi), "</table>"]
    module = _module_file(model)
    for title, function in (("Equations", model.equations), ("State update over one step of size h", model.update)):
        source = _source(function)
        if source:
            sections += [f"<h2>{title}</h2>", f"<p>From <code>{_text(module)}</code> (casadi expressions; the "
                         "C code in sources/ is generated from them):</p>", f"<pre>{_text(source)}</pre>"]
    doc = inspect.getdoc(sys.modules.get(model.equations.__module__)) if model.equations else None
    if doc:
        sections += ["<h2>Model</h2>", f"<p>The documentation of <code>{_text(module)}</code>:</p>",
                     f"<pre>{_text(doc)}</pre>"]
    sections += ["</body>", "</html>", ""]
    return "\n".join(sections)


def write(model: ModelDefinition, out_dir: Path) -> list[Path]:
    """OUT_DIR/fmi{2,3}/documentation/index.html (rewritten only when changed); returns their paths."""
    paths = []
    for fmi in (2, 3):
        path = out_dir / f"fmi{fmi}" / "documentation" / "index.html"
        text = page(model, fmi)
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help=f"model identifier, one of: {', '.join(MODELS)}")
    parser.add_argument("out_dir", type=Path)
    args = parser.parse_args(argv)
    if args.model not in MODELS:
        print(f"error: unknown model '{args.model}'; known: {', '.join(MODELS)}", file=sys.stderr)
        return 2
    write(MODELS[args.model], args.out_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())

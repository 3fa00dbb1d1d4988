"""Calibrated values as a parameter set: the TOML a scenario applies by name
(``[scenario] parameter_sets = [...]``, see orchestrator.scenario) and an SSP 1.0 ``.ssv`` copy.

Values are SI (the FMU variables' units), written by tomli-w (as ``repr``) so that they read back bit for
bit; every key and string (a multi-line ``description``, paths, the command) is written by tomli-w too, so
any text round-trips, and the file is parsed back before it replaces the old one; standard errors, 95 %
intervals and flags go into comments (control characters there become spaces). Nuisance estimates (spindle
phases) are not model parameters and are left out. The content depends only on the fit and on
where the file is written (provenance paths are relative to its folder; no time stamps), so
re-running a calibration rewrites the same file. A calibration writes the set into its output
folder; the committed copy beside the spec changes only when asked (``calibrate(..., write_set=...)``).
"""
from __future__ import annotations

import math
import os
import re
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import tomli_w

from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.calibrate.parameters import Parameter
from milling_twin.orchestrator.calibrate.statistics import ParameterStatistics
from milling_twin.orchestrator.ssp.ssv import SsvValue, parameter_set

__all__ = ["write_parameter_set", "write_ssv"]


def _entry(key: str, value: Any) -> str:
    """One ``key = value`` line written by tomli-w (the key quoted when it has to be, strings escaped)."""
    return tomli_w.dumps({key: value}).strip()


def _comment(text: str) -> str:
    """``text`` as the rest of one comment line: control characters (a newline would end it) become spaces."""
    return re.sub(r"[\x00-\x1f\x7f]", " ", text)


def _num(x: float) -> str:
    return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf") if math.isinf(x) else f"{x:.4g}"


def write_parameter_set(path: Path, parameters: Sequence[Parameter], estimates: Sequence[float],
                        statistics: Sequence[ParameterStatistics], description: str,
                        source: Mapping[str, str | Path], command: str) -> Path:
    """Write the TOML parameter set (atomically) and return its path. ``source``: provenance; a Path value
    (the spec, scenario, recording) is written relative to the folder of ``path``, so that the same
    call gives the same file wherever it is written from, and a copy elsewhere names the same files."""
    lines = [_comment(f"# Parameter set written by `{command}`; do not edit by hand, re-run the calibration."),
             "# Apply it by name from a scenario: [scenario] parameter_sets = [\"<path relative to the scenario>\"].",
             "# Values in SI units (the FMU variables' own units); standard error, 95 % confidence interval and",
             "# flags of each estimate in its comment.",
             _entry("description", description), "", "[source]"]
    lines += [_entry(k, os.path.relpath(v, path.parent) if isinstance(v, Path) else str(v))
              for k, v in source.items()]
    by_instance: dict[str, list[str]] = {}
    for q, value, st in zip(parameters, estimates, statistics):
        if q.nuisance:
            continue
        instance, variable = q.ref.instance, q.ref.variable
        value = min(max(float(value), q.lower), q.upper)
        comment = (f"{q.unit or '1'}; se {_num(st.standard_error)}, 95 % CI [{_num(st.ci_low)}, {_num(st.ci_high)}]"
                   + (f"; {'; '.join(st.flags)}" if st.flags else ""))
        by_instance.setdefault(instance, []).append(f"{_entry(variable, value)}  # {_comment(comment)}")
    for instance, entries in by_instance.items():
        header = tomli_w.dumps({"parameters": {instance: {}}}).strip()  # [parameters.<instance>], quoted if need be
        lines += ["", header, *entries]
    text = "\n".join(lines) + "\n"
    try:
        tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:  # a bug here, never the user's input: say so before writing
        raise RuntimeError(f"{path}: the parameter set written would not parse ({exc})") from exc
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OSError(exc.errno, f"cannot write the parameter set {path}: {exc.strerror or exc}") from exc
    return path


def write_ssv(path: Path, name: str, parameters: Sequence[Parameter], estimates: Sequence[float]) -> Path:
    """The same values as an SSP 1.0 parameter set (SystemStructureParameterValues), names
    "instance.variable", SI values with the FMU variable's unit (the SSP export's writer; its archives bind such
    a set to the components through a parameter mapping, docs/ssp.md)."""
    values = [SsvValue(q.name, min(max(float(v), q.lower), q.upper), q.unit)
              for q, v in zip(parameters, estimates) if not q.nuisance]
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_files.write_bytes(path, parameter_set(name, values))

"""Calibrated values as a parameter set: the TOML a scenario applies by name
(``[scenario] parameter_sets = [...]``, see orchestrator.scenario) and an SSP 1.0 ``.ssv`` copy.

Values are SI (the FMU variables' units), written with ``repr`` so that they read back bit for
bit; standard errors, 95 % intervals and flags go into comments. Nuisance estimates (spindle
phases) are not model parameters and are left out. The content depends only on the fit and on
where the file is written (provenance paths are relative to its folder; no time stamps), so
re-running a calibration rewrites the same file. A calibration writes the set into its output
folder; the committed copy beside the spec changes only when asked (``calibrate(..., write_set=...)``).
"""
from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.calibrate.parameters import Parameter
from milling_twin.orchestrator.calibrate.statistics import ParameterStatistics
from milling_twin.orchestrator.ssp.ssv import SsvValue, parameter_set

__all__ = ["write_parameter_set", "write_ssv"]


def _toml_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _num(x: float) -> str:
    return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf") if math.isinf(x) else f"{x:.4g}"


def write_parameter_set(path: Path, parameters: Sequence[Parameter], estimates: Sequence[float],
                        statistics: Sequence[ParameterStatistics], description: str,
                        source: Mapping[str, str | Path], command: str) -> Path:
    """Write the TOML parameter set (atomically) and return its path. ``source``: provenance; a Path value
    (the spec, scenario, recording) is written relative to the folder of ``path``, so that the same
    call gives the same file wherever it is written from, and a copy elsewhere names the same files."""
    lines = [f"# Parameter set written by `{command}`; do not edit by hand, re-run the calibration.",
             "# Apply it by name from a scenario: [scenario] parameter_sets = [\"<path relative to the scenario>\"].",
             "# Values in SI units (the FMU variables' own units); standard error, 95 % confidence interval and",
             "# flags of each estimate in its comment.",
             f"description = {_toml_string(description)}", "", "[source]"]
    lines += [f"{k} = {_toml_string(os.path.relpath(v, path.parent) if isinstance(v, Path) else str(v))}"
              for k, v in source.items()]
    by_instance: dict[str, list[str]] = {}
    for q, value, st in zip(parameters, estimates, statistics):
        if q.nuisance:
            continue
        instance, variable = q.ref.instance, q.ref.variable
        value = min(max(float(value), q.lower), q.upper)
        comment = (f"{q.unit or '1'}; se {_num(st.standard_error)}, 95 % CI [{_num(st.ci_low)}, {_num(st.ci_high)}]"
                   + (f"; {'; '.join(st.flags)}" if st.flags else ""))
        by_instance.setdefault(instance, []).append(f"{variable} = {value!r}  # {comment}")
    for instance, entries in by_instance.items():
        lines += ["", f"[parameters.{instance}]", *entries]
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def write_ssv(path: Path, name: str, parameters: Sequence[Parameter], estimates: Sequence[float]) -> Path:
    """The same values as an SSP 1.0 parameter set (SystemStructureParameterValues), names
    "instance.variable", SI values with the FMU variable's unit (the SSP export's writer; its archives bind such
    a set to the components through a parameter mapping, docs/ssp.md)."""
    values = [SsvValue(q.name, min(max(float(v), q.lower), q.upper), q.unit)
              for q, v in zip(parameters, estimates) if not q.nuisance]
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_files.write_bytes(path, parameter_set(name, values))

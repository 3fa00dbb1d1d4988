"""``milling-twin run twin.ssp``: an SSP 1.0 archive read back as the scenario it describes (docs/ssp.md).

:func:`opened` unpacks the archive into a temporary folder and writes the scenario there: the components become
``[fmus.<name>]`` (their FMU in the archive, the values of their parameter bindings, through a parameter mapping
when there is one, as parameters or, bound to an input connector, constant inputs), the connections
``[[connections]]``, the default experiment the start and stop time; the project's annotations (written by
``export-ssp``) restore what SSP 1.0 cannot say: step sizes, ``delay``, the output interval and record list,
``[stepping]``, ``[[on_change]]``, the recording and its inputs. Without them (an SSP from another tool) a
component's step is libcosim's ``osp:StepSizeHint`` or the base step of its ``osp:FixedStepAlgorithm``, and every
connection is delayed (the FMUs step in parallel, as in libcosim).
Every error is an :class:`SspError` naming the archive, the member file, its line and the element.
"""
from __future__ import annotations

import re
import tempfile
import tomllib
import zipfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path, PurePosixPath
from typing import Any, NoReturn

import tomli_w
from fmpy import read_model_description
from lxml import etree

from milling_twin.orchestrator.safe_names import name_problem
from milling_twin.orchestrator.scenario import Scenario, ScenarioError, _Ctx, with_values
from milling_twin.orchestrator.scenario import load_scenario as load
from milling_twin.orchestrator.ssp.common import (MT_TYPE, OSP_TYPE, SSD_NAME, SspError, describe, find_annotation, q,
                                                  schema_errors)

__all__ = ["load_scenario", "opened", "scenario_document"]

_VALUE_TYPES = ("Real", "Integer", "Boolean", "String")
SCENARIO_FILE = "milling-twin.scenario.toml"  # the scenario written from the archive, at the unpacked archive's root
PART_FILE = "milling-twin.part.toml"  # a whole part's [part], beside it


class _Reader:
    """The archive's members, every error naming the archive and the member."""

    def __init__(self, path: Path, zf: zipfile.ZipFile) -> None:
        self.path, self.zf = path, zf
        self.names = set(zf.namelist())

    def fail(self, member: str, message: str) -> NoReturn:
        raise SspError(f"{self.path}: {member}: {message}")

    def xml(self, member: str, kind: str) -> Any:
        """A member parsed and checked against its SSP 1.0 schema (``kind`` "ssd", "ssv" or "ssm")."""
        if member not in self.names:
            self.fail(member, f"not in the archive (it holds: {', '.join(sorted(self.names))})")
        try:
            root = etree.fromstring(self.zf.read(member))
        except etree.XMLSyntaxError as exc:
            self.fail(member, f"invalid XML: {exc.msg}")  # the message gives the line and column
        errors = schema_errors(root, kind)
        if errors:
            self.fail(member, f"does not follow the SSP 1.0 schema: {'; '.join(errors[:5])}")
        return root


def _member(reader: _Reader, where: str, element: Any, source: str) -> str:
    """An archive member named by a ``source`` URI relative to the SSD (the archive's root)."""
    name = PurePosixPath(source.removeprefix("./"))
    if name.is_absolute() or ".." in name.parts or ":" in source:
        reader.fail(where, f"{describe(element)}: source {source!r} is not a path inside the archive")
    if str(name) not in reader.names:
        found = ", ".join(sorted(n for n in reader.names if n.endswith(PurePosixPath(source).suffix))) or "none"
        reader.fail(where, f"{describe(element)}: {source} is not in the archive (files of its kind: {found})")
    return str(name)


def _value(reader: _Reader, member: str, parameter: Any) -> tuple[str, Any, str | None]:
    """An ssv:Parameter's type, value and unit."""
    for kind in _VALUE_TYPES:
        element = parameter.find(q("ssv", kind))
        if element is None:
            continue
        raw = element.get("value")
        if kind == "Real":
            return kind, float(raw), element.get("unit")
        if kind == "Integer":
            return kind, int(raw), None
        if kind == "Boolean":
            return kind, raw in ("true", "1"), None
        return kind, raw, None
    reader.fail(member, f"{describe(parameter)}: only Real, Integer, Boolean and String values are supported")


def _mapping(reader: _Reader, binding: Any) -> dict[str, str]:
    """A parameter binding's SSM: parameter name -> connector name (empty without one)."""
    mapping = binding.find(q("ssd", "ParameterMapping"))
    if mapping is None:
        return {}
    if mapping.get("source"):
        member = _member(reader, SSD_NAME, mapping, mapping.get("source"))
        root = reader.xml(member, "ssm")
    else:
        root = mapping.find(q("ssm", "ParameterMapping"))
        if root is None:
            reader.fail(SSD_NAME, f"{describe(mapping)}: neither a source nor an inline ssm:ParameterMapping")
    return {entry.get("source"): entry.get("target") for entry in root.findall(q("ssm", "MappingEntry"))}


def _bindings(reader: _Reader, component: Any, connectors: dict[str, str], files: set[str]) -> tuple[dict, dict]:
    """The parameter values and constant inputs a component's parameter bindings give, later bindings winning; of a
    binding with a parameter mapping the entries the mapping names, of one with a prefix those that start with it."""
    parameters: dict[str, Any] = {}
    inputs: dict[str, Any] = {}
    name = component.get("name")
    for binding in component.findall(f"{q('ssd', 'ParameterBindings')}/{q('ssd', 'ParameterBinding')}"):
        if binding.get("source"):
            member = _member(reader, SSD_NAME, binding, binding.get("source"))
            root = reader.xml(member, "ssv")
        else:
            member = SSD_NAME
            root = binding.find(f"{q('ssd', 'ParameterValues')}/{q('ssv', 'ParameterSet')}")
            if root is None:
                reader.fail(SSD_NAME, f"{describe(binding)}: neither a source nor inline ssd:ParameterValues")
        mapping, prefix = _mapping(reader, binding), binding.get("prefix", "")
        for parameter in root.findall(f"{q('ssv', 'Parameters')}/{q('ssv', 'Parameter')}"):
            target = parameter.get("name")
            if mapping:  # a set with a mapping (a calibration's, "instance.variable"): the entries it maps
                if target not in mapping:
                    continue
                target = mapping[target]
            elif prefix:  # the entries named with the prefix, without it
                if not target.startswith(prefix):
                    continue
                target = target[len(prefix):]
            kind, value, unit = _value(reader, member, parameter)
            if target not in connectors:
                reader.fail(member, f"{describe(parameter)}: no connector {target!r} in component {name!r}; its "
                                    f"connectors: {', '.join(connectors) or 'none'}")
            if connectors[target] not in ("parameter", "calculatedParameter", "input"):
                reader.fail(member, f"{describe(parameter)}: connector {name}.{target} is an {connectors[target]}: "
                                    "only parameters and inputs take values")
            entry: Any = {"value": value, "unit": unit} if unit else value
            if target in files:
                entry = {"path": value}
            (inputs if connectors[target] == "input" else parameters)[target] = entry
    return parameters, inputs


def _step(reader: _Reader, component: Any, base: float | None) -> float:
    own = find_annotation(component, "ssd", MT_TYPE, q("mt", "Component"))
    if own is not None and own.get("stepSize"):
        return float(own.get("stepSize"))
    hint = find_annotation(component, "ssd", OSP_TYPE, q("osp", "StepSizeHint"))
    if hint is not None and hint.get("value"):
        return float(hint.get("value"))
    if base is None:
        reader.fail(SSD_NAME, f"{describe(component)}: no step size: give the component an osp:StepSizeHint or "
                              "the default experiment an osp:FixedStepAlgorithm baseStepSize")
    return base


def scenario_document(reader: _Reader, folder: Path) -> dict[str, Any]:
    """The scenario (a TOML document, paths relative to ``folder`` where the archive is unpacked) the SSD says."""
    root = reader.xml(SSD_NAME, "ssd")
    system = root.find(q("ssd", "System"))
    experiment = root.find(q("ssd", "DefaultExperiment"))
    if experiment is None or experiment.get("stopTime") is None:
        reader.fail(SSD_NAME, "no <ssd:DefaultExperiment stopTime=...>: the stop time is needed to run it")
    algorithm = find_annotation(experiment, "ssd", OSP_TYPE, q("osp", "Algorithm"))
    fixed = algorithm.find(q("osp", "FixedStepAlgorithm")) if algorithm is not None else None
    base = float(fixed.get("baseStepSize")) if fixed is not None and fixed.get("baseStepSize") else None
    own = find_annotation(system, "ssd", MT_TYPE, q("mt", "Scenario"))
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", root.get("name")) or "ssp"
    if name_problem(name) is not None:  # the name of the run's folder <out>/<name>/
        reader.fail(SSD_NAME, f"<ssd:SystemStructureDescription name={root.get('name')!r}>: {name!r} "
                              f"{name_problem(name)}: it names the run's folder <out>/<name>/")
    header: dict[str, Any] = {"name": name, "start_time": float(experiment.get("startTime", "0")),
                              "stop_time": float(experiment.get("stopTime"))}
    if system.get("description"):
        header["description"] = system.get("description")
    doc: dict[str, Any] = {"scenario": header, "fmus": {}}
    connectors: dict[str, dict[str, str]] = {}
    elements = system.find(q("ssd", "Elements"))
    for element in elements if elements is not None else ():
        if element.tag is etree.Comment:
            continue
        if element.tag != q("ssd", "Component"):
            reader.fail(SSD_NAME, f"{describe(element)}: only FMU components are supported (no nested systems or "
                                  "signal dictionaries)")
        name = element.get("name")
        source = _member(reader, SSD_NAME, element, element.get("source"))
        if not source.endswith(".fmu"):
            reader.fail(SSD_NAME, f"{describe(element)}: {source} is not an FMU (.fmu)")
        own_component = find_annotation(element, "ssd", MT_TYPE, q("mt", "Component"))
        if own_component is not None and own_component.get("fmiVersion"):
            fmi = int(own_component.get("fmiVersion"))
        else:
            fmi = int(read_model_description(str(folder / source)).fmiVersion[0])
        files = {f.get("parameter") for f in own_component.findall(q("mt", "File"))} \
            if own_component is not None else set()
        connectors[name] = {c.get("name"): c.get("kind")
                            for c in element.findall(f"{q('ssd', 'Connectors')}/{q('ssd', 'Connector')}")}
        parameters, inputs = _bindings(reader, element, connectors[name], files)
        table: dict[str, Any] = {"fmu": source, "fmi": fmi, "step_size": _step(reader, element, base)}
        if parameters:
            table["parameters"] = parameters
        if inputs:
            table["inputs"] = inputs
        doc["fmus"][name] = table
    if not doc["fmus"]:
        reader.fail(SSD_NAME, "the system has no components")
    connections = []
    for connection in system.findall(f"{q('ssd', 'Connections')}/{q('ssd', 'Connection')}"):
        ends = []
        for side in ("start", "end"):
            element, connector = connection.get(f"{side}Element"), connection.get(f"{side}Connector")
            if element not in connectors:
                reader.fail(SSD_NAME, f"{describe(connection)}: {side}Element {element!r} is not a component "
                                      f"(components: {', '.join(connectors)})")
            if connector not in connectors[element]:
                reader.fail(SSD_NAME, f"{describe(connection)}: no connector {connector!r} in component "
                                      f"{element!r}; its connectors: {', '.join(connectors[element])}")
            ends.append(f"{element}.{connector}")
        if len(connection) and any(child.tag not in (q("ssd", "Annotations"), q("ssd", "ConnectionGeometry"))
                                   for child in connection):
            reader.fail(SSD_NAME, f"{describe(connection)}: transformations on connections are not supported")
        mark = find_annotation(connection, "ssd", MT_TYPE, q("mt", "Connection"))
        # without the project's annotations (another tool's SSD) every connection is delayed, as a master that
        # steps all FMUs in parallel (libcosim) runs it
        delay = own is None or (mark is not None and mark.get("delay") == "true")
        connections.append({"from": ends[0], "to": ends[1], "delay": delay})
    if connections:
        doc["connections"] = connections
    steps = [table["step_size"] for table in doc["fmus"].values()]
    header["output_interval"] = float(own.get("outputInterval")) if own is not None and own.get("outputInterval") \
        else (base if base is not None else min(steps))
    if own is not None:
        outputs = [o.get("ref") for o in own.findall(f"{q('mt', 'Outputs')}/{q('mt', 'Output')}")]
        if outputs:
            doc["outputs"] = {"record": outputs}
        part = own.find(q("mt", "Part"))
        if part is not None and part.text:
            (folder / PART_FILE).write_text(part.text, encoding="utf-8")
        text = own.find(q("mt", "Toml"))
        if text is not None and text.text:
            try:
                doc.update(tomllib.loads(text.text))
            except tomllib.TOMLDecodeError as exc:
                reader.fail(SSD_NAME, f"{describe(text)}: invalid TOML: {exc}")
    return doc


def _extract(reader: _Reader, folder: Path) -> None:
    for name in reader.names:
        parts = PurePosixPath(name).parts
        if PurePosixPath(name).is_absolute() or ".." in parts:
            reader.fail(name, "a member outside the archive's folder")
    reader.zf.extractall(folder)


def load_scenario(path: Path, fmu_dir: str | Path | None = None, *, parameter_sets: Sequence[str | Path] = (),
                  overrides: Mapping[str, Any] | None = None, recording: str | Path | None = None) -> Scenario:
    """The scenario :func:`opened` wrote, loaded as :func:`milling_twin.api.load_scenario` loads a file (the FMUs
    are the archive's: ``fmu_dir`` is not used); a whole part's with its Part read again from the archive's
    ``[part]`` (the process report of the run needs it)."""
    from milling_twin.orchestrator.part.expand import expand_document

    scenario = load(path, path.parent, parameter_sets=parameter_sets, recording=recording)
    if overrides:
        scenario = with_values(scenario, overrides)
    part_file = path.parent / PART_FILE
    if not part_file.is_file():
        return scenario
    ctx = _Ctx(part_file)
    _, doc = ctx.parse("part")
    _, part = expand_document(ctx, doc, path.parent / "resources")
    return replace(scenario, part=part)


@contextmanager
def opened(path: str | Path) -> Iterator[Path]:
    """The scenario file of an SSP archive, written with the unpacked archive into a temporary folder that is
    removed on leaving the ``with`` block (the FMUs and files stay there while it runs)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: SSP archive not found")
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile as exc:
        raise SspError(f"{path}: not an SSP archive (a zip file): {exc}") from exc
    with zf, tempfile.TemporaryDirectory(prefix="milling-twin-ssp-") as tmp:
        folder = Path(tmp)
        reader = _Reader(path, zf)
        _extract(reader, folder)
        doc = scenario_document(reader, folder)
        scenario = folder / SCENARIO_FILE
        scenario.write_text(f"# {path}: the scenario its {SSD_NAME} describes\n" + tomli_w.dumps(doc),
                            encoding="utf-8")
        try:
            yield scenario
        except ScenarioError as exc:  # the generated file's name means nothing to the user: name the archive
            raise SspError(f"{path}: {SSD_NAME} as a scenario: {exc.key + ': ' if exc.key else ''}{exc.detail}") \
                from exc

"""``milling-twin export-ssp SCENARIO -o twin.ssp``: a scenario as an SSP 1.0 archive (docs/ssp.md).

The archive holds ``SystemStructure.ssd`` (one ssd:Component per instance, its connectors with units, the
connections, the start and stop time), one parameter set per instance (``resources/<instance>.ssv``: the parameters
and constant inputs as the scenario resolves them, SI values with units), the FMUs (``resources/*.fmu``) and the
files the scenario reads (the recording, file-valued String parameters). What SSP 1.0 cannot say is written into
annotations of type :data:`~milling_twin.orchestrator.ssp.common.MT_TYPE` (and libcosim's own ones for the base and
per-component steps) and reported as warnings: :func:`export_ssp` returns them, the command prints them.
"""
from __future__ import annotations

import argparse
import sys
import tomllib
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w
from lxml import etree

from milling_twin.orchestrator.part.model import INTERPOLATOR
from milling_twin.orchestrator.scenario import FmuInstance, Scenario, Variable
from milling_twin.orchestrator.ssp.common import (FMU_MIME, MT_TYPE, NSMAP, OSP_TYPE, SSD_NAME, SspError, annotation,
                                                  q, schema_errors, ssp_unit, unit_element)
from milling_twin.orchestrator.ssp.ssv import SsvValue, parameter_mapping, parameter_set

__all__ = ["ExportResult", "command", "export_ssp", "ssd_tree"]

_KINDS = ("input", "output", "parameter", "calculatedParameter")  # the causalities that are SSP connector kinds
_SSC_TYPES = {"real": "Real", "real[]": "Real", "int": "Integer", "bool": "Boolean", "string": "String"}
_BESIDE = ("recorded", "inputs", "compare", "alignment")  # scenario tables carried as TOML in the annotation


@dataclass(frozen=True)
class ExportResult:
    path: Path
    warnings: tuple[str, ...]  # what SSP 1.0 cannot express, each carried by an annotation
    components: int
    connections: int


@dataclass
class _Archive:
    """The archive's members: name -> bytes (SSD, SSVs) or a file to copy."""

    members: dict[str, bytes | Path]

    def add_file(self, folder: str, path: Path) -> str:
        """``path`` as ``folder/<name>`` (a second file of the same name gets a numbered one); its member name."""
        for k in range(1000):
            stem = path.name if k == 0 else f"{path.stem}_{k}{path.suffix}"
            name = f"{folder}/{stem}"
            if self.members.get(name) in (None, path):
                self.members[name] = path
                return name
        raise SspError(f"{path}: too many files named {path.name}")

    def add_bytes(self, folder: str, name: str, content: bytes) -> str:
        member = f"{folder}/{name}"
        if member in self.members:
            raise SspError(f"two archive members would be called {member}")
        self.members[member] = content
        return member


def _connectors(inst: FmuInstance) -> list[Variable]:
    """The connectors of an instance: its inputs, outputs and parameters, FMI 3 arrays whole (SSP 1.0 connectors
    are scalars: an array's shape goes into an annotation), FMI 2 arrays as their scalars."""
    out = []
    for var in inst.variables.values():
        if var.causality not in _KINDS or var.type not in _SSC_TYPES or var.array:
            continue  # locals, the independent time, the elements of an FMI 3 array
        if var.type == "real[]" and var.value_reference < 0:
            continue  # an FMI 2 group of scalars: the scalars are the connectors
        out.append(var)
    return out


def _parameter_set(inst: FmuInstance, values: Mapping[str, Any]) -> bytes:
    """The SSV of an instance: its parameters and constant inputs, named as the FMU names them."""
    return parameter_set(inst.name, [SsvValue(name, value, inst.variables[name].unit)
                                     for name, value in values.items()])


def _applied_sets(scenario: Scenario, archive: _Archive, elements: Any) -> None:
    """The scenario's parameter sets (a calibration's, say) as SSVs named as such a set names its values
    ("instance.variable", the calibration's .ssv), bound to each component they set through an SSM that maps the
    names to its connectors; the values are those the scenario runs with (also in the component's own SSV)."""
    for set_path in scenario.parameter_sets:
        tables = tomllib.loads(set_path.read_text(encoding="utf-8")).get("parameters", {})
        values = [(inst, var) for inst, table in tables.items() for var in table]
        member = archive.add_bytes("resources/sets", f"{set_path.stem}.ssv", parameter_set(set_path.stem, [
            SsvValue(f"{inst}.{var}", scenario.instance(inst).parameters[var],
                     scenario.instance(inst).variables[var].unit) for inst, var in values]))
        for inst in tables:
            mapping = archive.add_bytes("resources/sets", f"{set_path.stem}.{inst}.ssm", parameter_mapping(
                {f"{inst}.{var}": var for i, var in values if i == inst}))
            component = elements.find(f"{q('ssd', 'Component')}[@name='{inst}']")
            bindings = component.find(q("ssd", "ParameterBindings"))
            if bindings is None:
                bindings = etree.Element(q("ssd", "ParameterBindings"))
                component.find(q("ssd", "Connectors")).addnext(bindings)
            binding = etree.SubElement(bindings, q("ssd", "ParameterBinding"), source=member)
            etree.SubElement(binding, q("ssd", "ParameterMapping"), source=mapping)


def _is_file(value: Any) -> bool:
    return isinstance(value, str) and Path(value).is_absolute() and Path(value).is_file()


def _scenario_toml(scenario: Scenario, archive: _Archive) -> tuple[str, list[str]]:
    """The scenario tables SSP 1.0 has no place for, as TOML (paths into the archive), and the warnings."""
    doc: dict[str, Any] = {}
    warnings = []
    raw = tomllib.loads(scenario.path.read_text(encoding="utf-8"))
    for table in _BESIDE:
        if table in raw:
            doc[table] = raw[table]
    if "recorded" in doc:
        recorded = dict(doc["recorded"])
        recorded["file"] = archive.add_file("resources/recorded", scenario.recorded.path)
        doc["recorded"] = recorded
        warnings.append(f"recorded inputs: [recorded] ({Path(recorded['file']).name}, packed in the archive) and "
                        f"{len(scenario.inputs)} [[inputs]] from it have no SSP 1.0 form (an SSP importer sees "
                        "those inputs unconnected)")
    if "compare" in doc or "alignment" in doc:
        warnings.append("[[compare]] / [alignment]: the comparison with the recording is not part of SSP 1.0")
    if scenario.stepping is not None:
        st = scenario.stepping
        doc["stepping"] = {"coarse_step": st.coarse_step, "variable": list(st.variable),
                           "fine_when": [{"output": str(f.output),
                                          f.sense: (f.threshold != 0.0) if f.sense == "is" else f.threshold}
                                         for f in st.fine_when]}
        if st.hold_intervals > 1:
            doc["stepping"]["hold"] = st.hold_intervals * st.coarse_step  # read back as as many intervals
        warnings.append(f"[stepping]: the engagement-driven variable step ({', '.join(st.variable)} take one "
                        f"{st.coarse_step:g} s step in air) has no SSP 1.0 form; an SSP importer steps them at "
                        "their own step size throughout")
    if scenario.on_change:
        doc["on_change"] = [entry.table() for entry in scenario.on_change]
        warnings.append(f"[[on_change]]: {len(scenario.on_change)} parameter change(s) at events (tool changes) "
                        "have no SSP 1.0 form")
    return tomli_w.dumps(doc), warnings


def _part_toml(scenario: Scenario, archive: _Archive) -> str:
    """A whole part's ``[part]`` (its program and tool table in the archive) with the ``[scenario]`` keys and the
    tables beside it that its reading depends on: what the importer reads the part from again (for the process
    report), not what it runs (the components are the expansion)."""
    raw = tomllib.loads(scenario.path.read_text(encoding="utf-8"))
    part = dict(raw["part"])
    part["program"] = archive.add_file(f"resources/files/{INTERPOLATOR}", scenario.part.program)
    if scenario.part.tool_table is not None:
        part["tool_table"] = archive.add_file(f"resources/files/{INTERPOLATOR}", scenario.part.tool_table)
    doc: dict[str, Any] = {"scenario": {k: v for k, v in raw["scenario"].items() if k != "parameter_sets"},
                           "part": part}
    if "recorded" in raw:  # its presence decides the stop time; the part does not read the recording
        doc["recorded"] = {"file": archive.add_file("resources/recorded", scenario.recorded.path)}
    if "inputs" in raw:
        doc["inputs"] = raw["inputs"]
    return tomli_w.dumps(doc)


def ssd_tree(scenario: Scenario, archive: _Archive) -> tuple[Any, list[str]]:
    """The SSD of ``scenario`` (FMUs, SSVs and files added to ``archive``) and the export's warnings."""
    warnings: list[str] = []
    root = etree.Element(q("ssd", "SystemStructureDescription"), nsmap=NSMAP, version="1.0", name=scenario.name)
    system = etree.SubElement(root, q("ssd", "System"), name=scenario.name)
    if scenario.description:
        system.set("description", scenario.description)
    elements = etree.SubElement(system, q("ssd", "Elements"))
    units: dict[str, dict[str, str]] = {}
    fmu_names: dict[Path, str] = {}
    arrays = []
    steps = {inst.step_size for inst in scenario.instances}
    for inst in scenario.instances:
        if inst.path not in fmu_names:
            fmu_names[inst.path] = archive.add_file("resources", inst.path)
        component = etree.SubElement(elements, q("ssd", "Component"), name=inst.name, source=fmu_names[inst.path],
                                     type=FMU_MIME, implementation="CoSimulation")
        connectors = etree.SubElement(component, q("ssd", "Connectors"))
        for var in _connectors(inst):
            connector = etree.SubElement(connectors, q("ssd", "Connector"), name=var.name, kind=var.causality)
            kind = _SSC_TYPES[var.type]
            unit = ssp_unit(var.unit) if kind == "Real" else None
            etree.SubElement(connector, q("ssc", kind), **({"unit": unit[0]} if unit else {}))
            if unit:
                units[unit[0]] = unit[1]
            if var.shape:
                arrays.append(f"{inst.name}.{var.name}")
                etree.SubElement(annotation(connector, "ssd", MT_TYPE), q("mt", "Array"),
                                 shape=",".join(str(n) for n in var.shape))
        values: dict[str, Any] = {**inst.parameters, **inst.inputs}
        file_parameters = [name for name, value in values.items() if _is_file(value)]
        for name in file_parameters:  # a file-valued String parameter: the file goes into the archive
            values[name] = archive.add_file(f"resources/files/{inst.name}", Path(values[name]))
        if values:
            archive.members[f"resources/{inst.name}.ssv"] = _parameter_set(inst, values)
            bindings = etree.SubElement(component, q("ssd", "ParameterBindings"))
            etree.SubElement(bindings, q("ssd", "ParameterBinding"), source=f"resources/{inst.name}.ssv")
        own = etree.SubElement(annotation(component, "ssd", MT_TYPE), q("mt", "Component"),
                               stepSize=repr(inst.step_size), fmiVersion=str(inst.fmi_version))
        for name in file_parameters:
            etree.SubElement(own, q("mt", "File"), parameter=name)
        etree.SubElement(annotation(component, "ssd", OSP_TYPE), q("osp", "StepSizeHint"),
                         value=repr(inst.step_size))
    if len(steps) > 1:
        warnings.append("per-FMU step sizes (" + ", ".join(f"{i.name} {i.step_size:g} s" for i in scenario.instances)
                        + ") have no SSP 1.0 form: they are in annotations (the project's and libcosim's "
                          "osp:StepSizeHint)")
    if files := [f"{i.name}.{n}" for i in scenario.instances for n, v in {**i.parameters, **i.inputs}.items()
                 if _is_file(v)]:
        warnings.append(f"file-valued String parameters ({', '.join(files)}): the files are in the archive under "
                        "resources/files/, their values are paths relative to the archive's root")
    if arrays:
        warnings.append(f"FMI 3 arrays ({', '.join(arrays)}): SSP 1.0 connectors are scalars; each array is one "
                        "connector of its name with its shape in an annotation")
    _applied_sets(scenario, archive, elements)
    delayed = _connections(scenario, system)
    if delayed:
        warnings.append(f"delay = true ({', '.join(delayed)}): SSP 1.0 connections have no delay; it is in the "
                        "connections' annotations (an SSP importer that steps all FMUs in parallel delays every "
                        "connection)")
    if scenario.part is not None:
        warnings.append("[part]: the whole-part scenario is exported as the explicit scenario it expands to "
                        "(`milling-twin expand`); its [part] is in an annotation, for the process report")
    toml_text, more = _scenario_toml(scenario, archive)
    warnings += more
    own = etree.SubElement(annotation(system, "ssd", MT_TYPE), q("mt", "Scenario"),
                           outputInterval=repr(scenario.output_interval), source=scenario.path.name,
                           part="true" if scenario.part is not None else "false")
    outputs = etree.SubElement(own, q("mt", "Outputs"))
    for ref in scenario.outputs:
        etree.SubElement(outputs, q("mt", "Output"), ref=str(ref))
    if toml_text:
        etree.SubElement(own, q("mt", "Toml")).text = etree.CDATA(toml_text)
    if scenario.part is not None:
        etree.SubElement(own, q("mt", "Part")).text = etree.CDATA(_part_toml(scenario, archive))
    unit_element(root, "ssd", units)
    experiment = etree.SubElement(root, q("ssd", "DefaultExperiment"), startTime=repr(scenario.start_time),
                                  stopTime=repr(scenario.stop_time))
    algorithm = etree.SubElement(annotation(experiment, "ssd", OSP_TYPE), q("osp", "Algorithm"))
    etree.SubElement(algorithm, q("osp", "FixedStepAlgorithm"), baseStepSize=repr(scenario.base_step))
    if any(inst.fmi_version == 3 for inst in scenario.instances):
        warnings.append("FMI 3 FMUs: SSP 1.0 (2019) predates FMI 3; importers without FMI 3 (libcosim) cannot run "
                        "them (export a scenario with fmi = 2 for those)")
    return root, warnings


def _connections(scenario: Scenario, system: Any) -> list[str]:
    """ssd:Connections of the scenario's connections (an FMI 3 array's elements as one connection of the arrays);
    the delayed ones."""
    seen: dict[tuple[str, str, str, str], bool] = {}
    for conn in scenario.connections:
        src, dst = scenario.variable(conn.source), scenario.variable(conn.target)
        if bool(src.array) != bool(dst.array):
            raise SspError(f"{scenario.path}: the connection {conn.source} -> {conn.target} joins an element of an "
                           "FMI 3 array with a scalar of an FMI 2 FMU: SSP 1.0 cannot express it (use FMUs of one "
                           "FMI version)")
        key = (conn.source.instance, src.array or conn.source.variable,
               conn.target.instance, dst.array or conn.target.variable)
        seen.setdefault(key, conn.delay)
    if not seen:
        return []
    holder = etree.SubElement(system, q("ssd", "Connections"))
    delayed = []
    for (start, start_connector, end, end_connector), delay in seen.items():
        connection = etree.SubElement(holder, q("ssd", "Connection"), startElement=start,
                                      startConnector=start_connector, endElement=end, endConnector=end_connector)
        if delay:
            delayed.append(f"{start}.{start_connector} -> {end}.{end_connector}")
            etree.SubElement(annotation(connection, "ssd", MT_TYPE), q("mt", "Connection"), delay="true")
    return delayed


def export_ssp(scenario: Scenario, output: str | Path) -> ExportResult:
    """Write ``scenario`` (loaded, overrides and parameter sets applied) as an SSP 1.0 archive at ``output``."""
    output = Path(output)
    archive = _Archive({})
    root, warnings = ssd_tree(scenario, archive)
    errors = schema_errors(root, "ssd")
    if errors:
        raise SspError(f"{SSD_NAME} does not follow the SSP 1.0 schema: {'; '.join(errors)}")
    members = {SSD_NAME: etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True),
               **archive.members}
    output.parent.mkdir(parents=True, exist_ok=True)
    tmp = output.with_name(f".{output.name}.tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, content in members.items():
            if isinstance(content, Path):
                zf.write(content, name)
            else:
                zf.writestr(name, content)
    tmp.replace(output)
    n_connections = len(root.findall(f".//{q('ssd', 'Connection')}"))
    return ExportResult(output, tuple(warnings), len(scenario.instances), n_connections)


def command(args: argparse.Namespace) -> int:
    """``milling-twin export-ssp``."""
    from milling_twin import api
    from milling_twin.cli import overrides_of

    scenario = api.load_scenario(args.scenario, args.fmu_dir, parameter_sets=args.parameter_set,
                                 overrides=overrides_of(args))
    result = export_ssp(scenario, args.output)
    for warning in result.warnings:
        print(f"warning: SSP 1.0 cannot express {warning}", file=sys.stderr)
    print(f"wrote {result.path}: {result.components} components, {result.connections} connections"
          + (f"; {len(result.warnings)} thing{'s' if len(result.warnings) > 1 else ''} SSP 1.0 cannot express "
             f"{'are' if len(result.warnings) > 1 else 'is'} in its annotations" if result.warnings else ""))
    return 0

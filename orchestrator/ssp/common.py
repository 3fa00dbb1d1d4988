"""What the SSP export and import share: the namespaces, the project's annotation, units as SSP base units, the
schema check and the error type.

The SSP 1.0 schemas (SystemStructureCommon, -Description, -ParameterValues, -ParameterMapping; Modelica Association
Project "SSP", BSD-2-Clause) are those fmpy ships in ``fmpy/ssp/schema``; tests/data/ssp holds a copy for the tests.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from lxml import etree

from milling_twin.models.units import UnitError, parse_unit

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
SSM = "http://ssp-standard.org/SSP1/SystemStructureParameterMapping"
MT = "urn:milling-twin:ssp:1"  # the project's annotations: what SSP 1.0 cannot say, to run the scenario again
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"  # libcosim's: base step, per-component step
NSMAP = {"ssd": SSD, "ssc": SSC, "ssv": SSV, "ssm": SSM, "mt": MT, "osp": OSP}
MT_TYPE = "org.milling-twin.scenario"  # ssc:Annotation type of the project's annotations
OSP_TYPE = "com.opensimulationplatform"  # read by libcosim's SSP parser
SSD_NAME = "SystemStructure.ssd"
SCHEMAS = {"ssd": "SystemStructureDescription.xsd", "ssv": "SystemStructureParameterValues.xsd",
           "ssm": "SystemStructureParameterMapping.xsd"}
FMU_MIME = "application/x-fmu-sharedlibrary"
# SSP base units (ssc:BaseUnit attributes) of models.units' dimension vector (kg, m, s, A, rad)
BASE_UNIT_ATTRIBUTES = ("kg", "m", "s", "A", "rad")


class SspError(ValueError):
    """An SSP archive the importer cannot run (or a scenario the export cannot write); the message names the file
    and, inside the archive, the member file, its line and the element."""


def q(prefix: str, name: str) -> str:
    """``{namespace}name`` of ``prefix:name``."""
    return f"{{{NSMAP[prefix]}}}{name}"


def schema_dir() -> Path:
    """fmpy's copy of the SSP 1.0 schemas."""
    import fmpy.ssp

    return Path(fmpy.ssp.__file__).parent / "schema"


def schema_errors(root: Any, kind: str, folder: Path | None = None) -> list[str]:
    """The XSD errors of an SSD/SSV/SSM tree (``kind`` "ssd", "ssv" or "ssm"), each "line N: message"."""
    schema = etree.XMLSchema(etree.parse(str((folder or schema_dir()) / SCHEMAS[kind])))
    if schema.validate(root):
        return []
    return [f"line {e.line}: {e.message}" for e in schema.error_log]


def ssp_unit(unit: str) -> tuple[str, dict[str, str]] | None:
    """An FMU unit as an ssc:Unit: its name and the ssc:BaseUnit attributes (exponents, factor); None for "", "1",
    "bool" and units that models.units does not know (the connector then carries no unit)."""
    if unit in ("", "1", "bool"):
        return None
    try:
        known = parse_unit(unit)
    except UnitError:
        return None
    attributes = {name: str(exp) for name, exp in zip(BASE_UNIT_ATTRIBUTES, known.dimensions) if exp}
    if known.factor != 1.0:
        attributes["factor"] = repr(known.factor)
    return unit, attributes


def unit_element(parent: Any, prefix: str, units: dict[str, dict[str, str]]) -> None:
    """``<prefix:Units>`` with one ssc:Unit per entry of ``units`` (name -> BaseUnit attributes), if any."""
    if not units:
        return
    element = etree.SubElement(parent, q(prefix, "Units"))
    for name, attributes in sorted(units.items()):
        unit = etree.SubElement(element, q("ssc", "Unit"), name=name)
        etree.SubElement(unit, q("ssc", "BaseUnit"), **attributes)


def annotation(parent: Any, prefix: str, kind: str) -> Any:
    """An ssc:Annotation of type ``kind`` in ``parent``'s ``<prefix:Annotations>`` (made when missing)."""
    holder = parent.find(q(prefix, "Annotations"))
    if holder is None:
        holder = etree.SubElement(parent, q(prefix, "Annotations"))
    return etree.SubElement(holder, q("ssc", "Annotation"), type=kind)


def find_annotation(element: Any, prefix: str, kind: str, child: str) -> Any:
    """The ``child`` element (``mt:Component``, ``osp:StepSizeHint``, ...) of ``element``'s annotation of type
    ``kind``, or None."""
    holder = element.find(q(prefix, "Annotations"))
    if holder is None:
        return None
    for item in holder.findall(q("ssc", "Annotation")):
        if item.get("type") == kind:
            found = item.find(child)
            if found is not None:
                return found
    return None


def describe(element: Any) -> str:
    """``<ssd:Component name="force">`` (line N): an element as an error message names it."""
    prefix = next((p for p, uri in NSMAP.items() if element.tag.startswith(f"{{{uri}}}")), "")
    local = etree.QName(element).localname
    attributes = "".join(f' {k}="{v}"' for k, v in element.attrib.items()
                         if k in ("name", "startElement", "startConnector", "endElement", "endConnector", "source"))
    return f"line {element.sourceline}: <{prefix}:{local}{attributes}>"

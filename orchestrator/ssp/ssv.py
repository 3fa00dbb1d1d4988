"""SSP 1.0 parameter sets (``.ssv``) and parameter mappings (``.ssm``) as bytes, checked against their schemas.

One writer for the SSP export (one set per instance, one per applied parameter set) and the calibration's ``.ssv``
copy of a calibrated parameter set (orchestrator/calibrate/paramset.py). Values are written with ``repr``, so they
read back bit for bit; a Real carries its unit (defined in the set's ``ssv:Units``) when models.units knows it.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from lxml import etree

from milling_twin.orchestrator.ssp.common import NSMAP, SspError, q, schema_errors, ssp_unit, unit_element

__all__ = ["SsvValue", "parameter_mapping", "parameter_set"]


@dataclass(frozen=True)
class SsvValue:
    """A parameter of a set: its name, its value (bool: Boolean, int: Integer, float: Real, str: String) and, for a
    Real, the unit of the value ("" none)."""

    name: str
    value: float | int | bool | str
    unit: str = ""


def _xml(root: etree._Element, kind: str, what: str) -> bytes:
    errors = schema_errors(root, kind)
    if errors:
        raise SspError(f"{what} does not follow the SSP 1.0 schema: {'; '.join(errors)}")
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def parameter_set(name: str, values: Sequence[SsvValue]) -> bytes:
    """An ``ssv:ParameterSet`` called ``name`` holding ``values`` in their order."""
    root = etree.Element(q("ssv", "ParameterSet"), nsmap={"ssv": NSMAP["ssv"], "ssc": NSMAP["ssc"]},
                         version="1.0", name=name)
    parameters = etree.SubElement(root, q("ssv", "Parameters"))
    units: dict[str, dict[str, str]] = {}
    for item in values:
        parameter = etree.SubElement(parameters, q("ssv", "Parameter"), name=item.name)
        value = item.value
        if isinstance(value, bool):
            etree.SubElement(parameter, q("ssv", "Boolean"), value="true" if value else "false")
        elif isinstance(value, int):
            etree.SubElement(parameter, q("ssv", "Integer"), value=str(value))
        elif isinstance(value, str):
            etree.SubElement(parameter, q("ssv", "String"), value=value)
        else:
            attributes = {"value": repr(float(value))}
            unit = ssp_unit(item.unit)
            if unit is not None:
                attributes["unit"] = unit[0]
                units[unit[0]] = unit[1]
            etree.SubElement(parameter, q("ssv", "Real"), **attributes)
    unit_element(root, "ssv", units)
    return _xml(root, "ssv", f"parameter set {name!r}")


def parameter_mapping(entries: Mapping[str, str]) -> bytes:
    """An ``ssm:ParameterMapping``: each parameter name of a set (key) to the connector it sets (value)."""
    root = etree.Element(q("ssm", "ParameterMapping"), nsmap={"ssm": NSMAP["ssm"], "ssc": NSMAP["ssc"]},
                         version="1.0")
    for source, target in entries.items():
        etree.SubElement(root, q("ssm", "MappingEntry"), source=source, target=target)
    return _xml(root, "ssm", "parameter mapping")

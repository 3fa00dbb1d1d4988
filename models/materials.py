"""Named work materials: the cutting-force coefficients of the linear edge/shear law (``models/cutting_force.py``),
with where each set comes from. A whole-part scenario names one (``[part].material = "Al7075-T6"``) or gives
the six coefficients itself.

Coefficients are SI: ``Ktc``, ``Krc``, ``Kac`` in N/m^2 (cutting, per chip area), ``Kte``, ``Kre``, ``Kae`` in N/m
(edge, per cut length). Each set belongs to a pair of work material and cutter (here carbide end mills, dry): the
same alloy cut with another tool has other coefficients.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from milling_twin.models.cutting_force import AL7075_CARBIDE

COEFFICIENTS = ("Ktc", "Krc", "Kac", "Kte", "Kre", "Kae")
_REVIEW = ("\"Milling Force Model for Aviation Aluminum Alloy: Academic Insight and Perspective Analysis\", "
           "Chinese Journal of Mechanical Engineering 34 (2021), doi:10.1186/s10033-021-00536-9, Table 5")

# Machining wax: no measured coefficients are known to us. The estimate scales every Al7075-T6 coefficient by the
# ratio of typical ultimate tensile strengths of high-density polyethylene (about 25 MPa) and Al7075-T6 (572 MPa),
# 0.044. Machinable wax is paraffin blended with polyethylene and is weaker than the polyethylene alone, so the
# estimate is meant as an upper bound of the right order of magnitude; calibrate it against force or power
# recordings before trusting a force. (The UMich spindle-power recordings of wax milling show the cutting power
# below the drive's +-20 W noise, docs/calibration.md: consistent with coefficients this small.)
WAX_SCALE = 25.0 / 572.0


@dataclass(frozen=True)
class MaterialPreset:
    """A named set of cutting-force coefficients (SI), the cutter it was measured with and its source."""
    name: str
    coefficients: Mapping[str, float]
    source: str
    estimate: bool = False      # True: not measured (an estimate; the source says how it was made)


MATERIALS: Mapping[str, MaterialPreset] = MappingProxyType({p.name: p for p in (
    MaterialPreset("Al7075-T6", dict(AL7075_CARBIDE),
                   f"Al7075-T6, cemented-carbide end mill, dry: row [190] of {_REVIEW} (the CuttingForce FMU's "
                   f"defaults)"),
    MaterialPreset("Al6061-T6", {"Ktc": 243.77e6, "Krc": 113.5e6, "Kac": 0.0, "Kte": 7.53e3, "Kre": 7.83e3,
                                 "Kae": 0.0},
                   f"Al6061-T6, cemented-carbide end mill, dry: row [160] of {_REVIEW}; that row gives no axial "
                   f"coefficients, so Kac = Kae = 0 (no axial force Fz)"),
    MaterialPreset("machining-wax", {k: v * WAX_SCALE for k, v in AL7075_CARBIDE.items()},
                   "machinable wax (paraffin and polyethylene): an ESTIMATE, not measured: the Al7075-T6 "
                   "coefficients times 25/572, the ratio of the typical tensile strengths of HDPE (about 25 MPa) "
                   "and Al7075-T6 (572 MPa); an upper bound of the right order, calibrate before use",
                   estimate=True),
)})


def material(name: str) -> MaterialPreset:
    """The preset called ``name``; a KeyError listing the presets otherwise."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise KeyError(f"unknown material {name!r}; presets: {', '.join(MATERIALS)}") from None

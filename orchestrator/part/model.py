"""What a whole-part scenario describes, in SI units: the program, the stock, the tool, the material, the
machine and the stepping. ``[part]`` in a scenario file is read into a :class:`Part` (``orchestrator/part/spec.py``)
and expanded into the explicit instances and connections (``orchestrator/part/expand.py``); the process report
(``orchestrator/part/report.py``) reads the same :class:`Part` to know the tool, the modes and the stock.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from milling_twin.models.interpolator.parser import Tool
from milling_twin.models.stability import Mode

# The five instances a part expands to; the report and the benchmarks read their columns by these names.
INTERPOLATOR, WORKPIECE, FORCE, VIBRATION, POWER = "interp", "workpiece", "force", "vibration", "power"


@dataclass(frozen=True)
class Stock:
    """A block: the corner with the smallest coordinates, its size, and the Z-map cell size (m)."""
    origin: tuple[float, float, float]
    size: tuple[float, float, float]
    resolution: float

    @property
    def top(self) -> float:
        return self.origin[2] + self.size[2]

    @property
    def volume(self) -> float:
        return self.size[0] * self.size[1] * self.size[2]


@dataclass(frozen=True)
class Material:
    """Cutting-force coefficients of the linear edge/shear law (N/m^2 and N/m), with where they come from."""
    name: str
    coefficients: dict[str, float]       # Ktc, Krc, Kac, Kte, Kre, Kae
    source: str = ""


@dataclass(frozen=True)
class CutTool:
    """A tool that cuts the part: its table entry, its tip modes, its flute length and where its tip is."""
    tool: Tool
    modes_x: tuple[Mode, ...]
    modes_y: tuple[Mode, ...]
    flute_length: float                   # m
    # m: how far the Workpiece's tool_z (the machine Z) is above this tool's tip, beyond the program zero: the
    # differences of the G43 length offsets the program gives its tools (0 for the tool whose offset is smallest)
    length: float = 0.0


@dataclass(frozen=True)
class Part:
    """A whole-part scenario's ``[part]`` section, resolved: paths absolute, values SI."""
    program: Path
    dialect: str
    tool_table: Path | None
    tool: Tool                            # the (first) tool that cuts (from the tool table)
    stock: Stock
    material: Material
    modes_x: tuple[Mode, ...]             # the first tool's modes (the others': later_tools)
    modes_y: tuple[Mode, ...]
    force_model: str = "CuttingForce"    # or "ForceNet"
    cutting_power: str = "force"         # "force": torque x omega of the force model; "mrr": the MRR term
    fine_step: float = 1e-5              # s: force and vibration in and near material
    coarse_step: float = 1e-3            # s: the interpolation period, also force and vibration in air
    lookahead: float = 0.0               # m: also step finely this close to material (the Workpiece's clearance; 0: no)
    hold: float | None = None            # s: step finely this long after material (None: the modes' ring-down)
    machine: dict[str, float] = field(default_factory=dict)   # Interpolator parameters (limits, start), SI
    spindle: dict[str, float] = field(default_factory=dict)   # SpindlePower parameters, SI
    feed_override: float = 1.0           # the Interpolator's feed override (1: 100 %)
    flute_length: float = 0.0            # m: the tool's cutting length (stick_out of its tool table entry)
    # m: the machine position of the program zero while a tool cuts (work offset, G52, G43 tool length): the stock is
    # given in program coordinates, the Workpiece (fed with the machine position) holds it at stock + this. With
    # several tools, the tool whose zero is lowest; each tool's own zero is this + (0, 0, its CutTool.length)
    program_zero: tuple[float, float, float] = (0.0, 0.0, 0.0)
    machining_time: float = 0.0          # s: the program's duration at 100 % override (0: [scenario].stop_time given)
    warnings: tuple[str, ...] = ()       # what the checks before the run found (orchestrator/part/checks.py)
    tools: tuple[Tool, ...] = ()         # every tool of the tool table, read once (read_part)
    tool_length: float = 0.0             # m: the first tool's CutTool.length
    later_tools: tuple[CutTool, ...] = ()  # the tools that cut after the first (tool changes), in order of first cut

    @property
    def cutting_tools(self) -> tuple[CutTool, ...]:
        """Every tool that cuts the part, in the order of its first cut; the first is ``tool``."""
        first = CutTool(self.tool, self.modes_x, self.modes_y, self.flute_length, self.tool_length)
        return (first, *self.later_tools)

    def cutting_tool(self, number: int) -> CutTool | None:
        """The cutting tool of tool number ``number`` (None: a tool that does not cut the part, or 0)."""
        return next((c for c in self.cutting_tools if c.tool.number == number), None)

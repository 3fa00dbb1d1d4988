"""Workpiece and cutter engagement: a Z-map of the stock cut by a flat, bull-nose or ball end mill.

The stock is a block ``[stock_x_min, +stock_length] x [stock_y_min, +stock_width] x
[stock_z_min, +stock_height]``, represented as a height field (Z-map): ``nx x ny`` cells of
``dx x dy`` with ``nx = ceil(stock_length / resolution)`` (so ``dx <= resolution``; the grid fits the
block exactly), each holding the height of the material above its centre. Heights only decrease;
a cell cut down to the bottom of the block is empty.

Per step (the tool tip held at its previous position at the start and moved in a straight line to the
current one; the tip is the controlled point of the inputs ``tool_x, tool_y, tool_z`` lowered by
``tool_length``, 0 by default: the inputs are the tip) the FMU (``fmus/workpiece/model.c``) and
:class:`ZMap` below, the same algorithm in numpy, do:

1. **Removal** under the swept tool: the move is split into ``n`` sub-segments so that none descends
   more than ``min(dx, dy)/4`` (``n = 1`` for a move without horizontal travel: a plunge is exact).
   For each sub-segment a -> b, every cell whose centre c lies within the tool radius ``R`` of the
   horizontal segment is lowered to the tool's lower surface there: ``z(t*) + g(d)``, where ``t*``
   is the segment parameter of the point closest to c, ``d`` the distance to it and ``g`` the
   profile of the end (0 on the flat bottom ``d <= R - r_c``, ``r_c - sqrt(r_c^2 - (d - R + r_c)^2)``
   on the corner of radius ``r_c``). Only cells in the bounding box of the sub-segment widened by
   ``R`` are visited: the cost per step is proportional to the area swept, never to the stock.
   The removed volume is the sum of the height drops times ``dx*dy``; ``mrr`` = volume / step size.
   A cell is cut whole when its centre enters the tool: when the feed per step is below a cell,
   ``mrr`` alternates between 0 and a few cells' worth from step to step; its running mean, and
   the removed volume (the sum of ``mrr * h``), are right. Average over ``dx / feed per step`` steps
   (or step the FMU less often) where a smooth value is wanted.

2. **Engagement** at the new position, against the stock after the removal, in the tool frame of
   Altintas (Manufacturing Automation): feed along +x_t (the direction of the last horizontal move,
   +x before the first), the immersion angle phi measured clockwise from +y_t seen from above (the
   rotation of an M3 spindle), a point of the circle of radius r at ``r (sin phi, cos phi)`` in
   (x_t, y_t). An edge element at angle phi and height z above the tip (where the cutter radius is
   ``r(z)``) is *in material* when the stock column one cell outside the cutting circle, at radius
   ``r(z) + delta`` (``delta = min(dx, dy)``) in the direction phi, reaches above it. The offset
   keeps the test out of the cells this and earlier steps lowered (cells are cut by their centres,
   which may lie up to ``delta/sqrt(2)`` inside the circle). Only the front half ``0 <= phi <= pi`` is
   tested: behind the cutter is the surface it has just cut. A test point (an angle and a profile
   height) is *cutting* when it is in material and lies laterally (across the feed) inside the
   cutter's circle at its height by more than half a cell diagonal, so in a cell whose centre is
   inside it; a point in material but not cutting lies on a wall parallel to the feed that the
   cutter merely touches. A run of consecutive engaged angle samples counts only if it holds a
   cutting point (a pass retracing an earlier one cuts nothing and is not engaged), and only
   cutting points' heights make its engaged height: the walls an earlier level left at the tool
   radius, standing above the layer now cut (a slot or pocket cut again deeper, a side cut along
   such a wall), touch the cutter over their whole height, but only the layer is cut. Along an arc
   of path radius rho such a wall meets the test circle ``delta (R + delta/2) / rho`` farther inside
   the radius than along a straight path, so the height is that of the run's *deep* points, cutting
   points inside the circle by more than ``arc_margin = half diagonal + 2 delta (1 + delta / 2R)``
   (such walls along arcs down to ``rho = R/2``; 0.69 mm on a 0.25 mm grid), and only a run without
   deep points (a cut narrower than about ``arc_margin``: a finishing pass) takes its cutting points'
   heights. The price: a sliver narrower than ``arc_margin`` at the flank, standing above a wider
   cut of a lower layer (a second level whose path strays from the first), is left out of the
   height.

   The **cut top** then bounds that height by the material the tool removes. The tip's travel (the
   length of each step's move, vertical moves included) is divided into *stretches*: a stretch ends
   with the step that brings its travel to ``R`` or more. The cut top is the highest height, before
   the cut, of the cells the removal (step 1) lowered in the current stretch, this step included, and
   in the previous one: the material cut within the last ``R`` to ``2R`` of travel (plus up to a step's).
   When there is one, the engaged height is at most ``cut top - z`` (z the tip's height), and the tool
   is not engaged at all when that is not above 0 (all it cut lies below the tip: it has risen from
   its cut). When there is none (no cell lowered in the two stretches: a move through air, or a pass
   that has cut nothing for that long), the tool is not engaged: it removes nothing, whatever the test
   circle sees (the walls a retrace runs along, the end wall of the cut it retraces, the uncut fillet of
   a corner it runs into). A contact after air therefore counts from the step that lowers its first
   cell, when the cutter covers that cell's centre: up to ``delta`` plus half a cell diagonal of travel
   after the test circle first sees the material (0.43 mm on a 0.25 mm grid), where the Z-map's
   material begins (heights stand for cell centres). A cut narrower than a cell that lowers no cell
   centre is not seen either (a finer grid resolves it). A step that rises more than it moves sideways
   and lowers no cell (a retract) is not engaged either: its flanks slide up the walls they touch. So
   the walls an earlier level left that a deeper level approaches but does not
   cut (the wall ahead as it runs into a corner of the earlier path, the end wall of an earlier cut, the
   walls around the tool where it stops or retracts after the cut) are left out while it cuts the
   layer, and material higher than all it cut in the window counts from the step that lowers its first
   cell (a step-down into material of the full height: within about a cell of travel after the cutter
   reaches it, where the test points saw it earlier, 0.7 mm with a 10 mm tool on a 0.25 mm grid). The
   cut top bounds the height only: the angles and the radial depth stay the test points', and the map's
   rows divide the bounded height. What remains: within the window after a cut (the first ``R`` to
   ``2R`` of a retrace that follows it, a tool stopped where it has just cut) the walls the test circle
   sees still count, up to the cut top; a pass that cuts a sliver of the full height
   (a second level that strays from the first, along arcs tighter than ``R/2``) reports the sliver's
   height.

   - ``entry_angle`` / ``exit_angle``: the first and last engaged angle. ``M + 1`` angles
     ``phi_m = m pi / M`` (``M = ceil(pi R / delta)``, about one cell of arc) are each tested over
     ``K + 1`` heights of the profile (``K = ceil(pi/2 r_c / delta)`` points along the corner arc plus
     the cylinder above it); the first and last engaged sample are refined by 10 bisections towards
     their non-engaged neighbour. The test circle lies ``delta`` outside the cutter, so an angle phi
     found there is taken back to the cutter's circle at the same lateral position (exact for a
     wall parallel to the feed): ``cos(angle) = clamp((r_top + delta) / r_top * cos(phi), -1, 1)``.
     Slotting gives exactly (0, pi); half immersion down milling (pi/2, pi).
   - ``axial_depth``: the largest height of the counted runs, each run's that of its deep points, or of
     its cutting points when it has no deep point, and at most ``cut top - z`` (exact where the material
     cut is flat-topped: the column's height, not a sample height; the layer's thickness on a second
     level of a flat end mill: 1.5 mm for a slot at 1.5 mm cut again at 3 mm). A ball or bull-nose end
     mill cut again deeper along its earlier path also widens the groove at its top edges, so there it
     reports the height up to the material it cuts there (for a ball: up to the stock top).
   - ``radial_depth``: ``r_top (cos(entry) - cos(exit))``, the width across the feed of the cutter's
     circle between entry and exit, ``r_top`` its radius at the top of the cut (``axial_depth``).
   - the **engagement map** ``engagement`` (``N_Z x N_THETA`` = 8 x 24 values, 0 or 1; an FMI 3
     array variable, in FMI 2 the scalars ``engagement[i,j]`` with 1-based indices): row i is the
     height ``(i + 1/2) axial_depth / N_Z`` above the tip (the rows divide the engaged height, so the
     force model's slice height is ``axial_depth / N_Z``), column j the angle
     ``(j + 1/2) 2 pi / N_THETA``; columns of the back half are 0. (The reference below names the
     elements ``engagement_z{i}_a{jj}``, 0-based, in the same row-major order.)

3. **Clearance** at the new position, against the stock after the removal: the distance from the tool,
   taken as a cylinder of radius ``R`` with a flat end at the tip (the corner radius is ignored: for a
   bull-nose or ball end mill the distance is the one to that cylinder, up to ``(sqrt(2) - 1) r_c`` short
   near the corner, never more than the distance to the tool), to the material of the cells, each cell's
   material a vertical segment at its centre c from the bottom of the block up to its height h(c). Per
   cell not cut to the bottom (h(c) > ``stock_z_min``: an empty cell has no material), with the tool tip
   at (x, y, z):
   the horizontal gap ``gh = max(0, |c - (x, y)| - R)``, the vertical gap ``gv = max(0, z - h(c))`` and the
   distance ``sqrt(gh^2 + gv^2)``; ``clearance`` is the smallest of these and ``clearance_range``, so
   ``clearance_range`` when no material is that near and 0 when the tool is in material (a cell under the
   tool reaches up to the tip or above; every cell the step cut does). Only the cells whose centre lies
   within ``R + clearance_range`` (plus ``delta/16``) of the axis in x and in y are searched (the others
   are farther than ``clearance_range``), and the FMU leaves out the rows and cells that cannot be
   nearer than the nearest found so far: a few thousand cells at most per step at the default 5 mm,
   none when the tip is ``clearance_range`` or more above the stock.

4. **Removed volume**: ``removed_volume`` is the sum of all height drops since the start times
   ``dx*dy`` (exact for the Z-map: the sum of ``mrr * h`` over the steps up to rounding).

Warnings (the FMU's log, once per run each; the reference lists them in ``ZMap.warnings``): material
removed while the spindle stands still (``spindle``), an engaged height above ``flute_length``
(``shank``), and the tool tip at the end of a step below the stock bottom ``stock_z_min`` while the
tool's footprint (the disc of radius R about its axis) overlaps the block seen from above: the program
plunges through the part, into the fixture (``bottom``).

**A tool change**: ``tool_diameter``, ``corner_radius``, ``tool_length`` and ``flute_length`` are tunable
(a master sets them between steps at a tool change of the program: T2 M6, G43 H2). When any of the first
three differs at a doStep from the tool the last step used, the new tool is in the spindle from the step's
start: the tip at the start is the previous controlled point lowered by the *new* ``tool_length`` (a change
of length alone moves no tip, so it removes nothing and the ``max_tool_speed`` guard sees only the
controlled point's motion), the tool's radius, corner, ``arc_margin`` and its angle and profile samples are
derived again, the Z-map is kept, the cut top is forgotten (the old tool's cuts do not bound the new tool's
engaged height: the next contact is a first contact) and the shank warning is re-armed (a new
``flute_length`` alone re-arms it too). The checks of initialization on the tool (``corner_radius`` at most
``tool_diameter``/2, the tool no larger than the stock, at least 4 cells across it) are made for the new
tool: a tool they reject fails the doStep with their message after ``tool change:``. :meth:`ZMap.change_tool`
does the same between steps; ``flute_count`` and ``helix_angle`` (not used by the Z-map) stay fixed.

**The final Z-map** (``zmap_file``, a String parameter; empty: none): in fmi2Terminate /
fmi3Terminate the FMU writes the heights to that file (a relative path is relative to the process's
working directory), as an ESRI ASCII grid, the heightmap format GIS tools and GDAL read: the lines
``ncols``, ``nrows``, ``xllcorner``, ``yllcorner`` (the block's corner), ``cellsize`` when ``dx == dy``
or else ``dx`` and ``dy`` (GDAL's extension for cells that are not square), ``NODATA_value -9999`` (never
used), then ``nrows`` lines of ``ncols`` heights in m from north (largest y) to south, each cell's
material top printed with ``%.17g`` (read back, the same double); every number has a ``.`` as its decimal
point whatever the process's locale (C's printf follows ``LC_NUMERIC``: the FMU replaces the locale's decimal
point, so an importer running in a decimal-comma locale writes the same file); a cell cut to the bottom has the
height ``stock_z_min``. It is written to ``<zmap_file>.tmp`` and renamed, so a failed write never leaves a
truncated file under the final name; a failure (missing folder, disk full, ...) makes Terminate return
Error with a message naming ``zmap_file``, the path and the system's reason. :func:`read_zmap` reads
such a file back.

The map is in the feed frame and does not rotate with the spindle, so the spindle angle is not
needed: the force model places the flutes (``flute_count``, ``helix_angle``: carried here so that the
tool is described in one place) on it. ``spindle_speed`` is used only to warn (once) when material
is removed while the spindle stands still. Angles assume M3 (clockwise); for M4 the same engagement
in the convention mirrored for counter-clockwise rotation is entry' = pi - exit, exit' = pi - entry.

All outputs are those of the last step: zero in initialization mode and until the first doStep.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from milling_twin.models.definition import ModelDefinition, Variable

N_Z = 8                 # rows of the engagement map (slices of the engaged height)
N_THETA = 24            # columns of the engagement map (15 degree sectors of the full circle)
MAX_CELLS = 20_000_000  # memory cap of the Z-map: 160 MB of heights (and as much per FMU state)
MIN_CELLS_ACROSS_TOOL = 4.0  # resolution <= tool_diameter / 4
DESCEND_PER_SUBSEGMENT = 0.25  # times min(dx, dy)
FEED_DIRECTION_MIN_TRAVEL = 1e-3  # times min(dx, dy): shorter horizontal moves keep the feed direction
SPINDLE_STOPPED = 2 * math.pi / 60  # rad/s (1 rpm): slower counts as stopped for the warning
N_BISECTIONS = 10  # refinement of entry and exit between two angle samples (to 1/1024 of their spacing)

_MM = "mm"


def map_name(i: int, j: int) -> str:
    return f"engagement_z{i}_a{j:02d}"


MAP_NAMES = tuple(map_name(i, j) for i in range(N_Z) for j in range(N_THETA))
SCALAR_OUTPUTS = ("axial_depth", "radial_depth", "entry_angle", "exit_angle", "mrr", "clearance", "removed_volume")
OUTPUTS = SCALAR_OUTPUTS + MAP_NAMES


def _variables() -> tuple[Variable, ...]:
    def length(name, description, start, lo, hi, causality="parameter", variability="fixed"):
        return Variable(name, "Float64", causality, description, unit="m", display_unit=_MM, start=start,
                        min=lo, max=hi, variability=variability if causality == "parameter" else None)

    variables = [
        length("stock_x_min", "Stock block: smallest x (corner of the block)", 0.0, -10.0, 10.0),
        length("stock_y_min", "Stock block: smallest y", 0.0, -10.0, 10.0),
        length("stock_z_min", "Stock block: bottom z", 0.0, -10.0, 10.0),
        length("stock_length", "Stock block: size in x", 0.1, 1e-3, 2.0),
        length("stock_width", "Stock block: size in y", 0.06, 1e-3, 2.0),
        length("stock_height", "Stock block: size in z", 0.03, 1e-3, 2.0),
        length("resolution", "Z-map cell size (largest; cells are fitted to the block, dx <= resolution)",
               0.25e-3, 1e-5, 0.02),
        length("tool_diameter", "Cutter diameter D (tunable: a change is a tool change)", 0.01, 1e-4, 0.1,
               variability="tunable"),
        length("corner_radius", "Corner radius of the end: 0 flat end mill, D/2 ball end mill (tunable)", 0.0, 0.0,
               0.05, variability="tunable"),
        length("tool_length", "How far the controlled point (tool_x, tool_y, tool_z) is above the tool tip: the tip "
               "is at tool_z - tool_length; 0: the inputs are the tip (tunable)", 0.0, 0.0, 1.0,
               variability="tunable"),
        Variable("flute_count", "Int32", "parameter", "Number of flutes (for the force model; not used by the Z-map)",
                 start=2, min=1, max=20, variability="fixed"),
        Variable("helix_angle", "Float64", "parameter",
                 "Helix angle of the flutes (for the force model; not used by the Z-map)",
                 unit="rad", display_unit="deg", start=math.radians(30.0), min=0.0, max=math.radians(70.0),
                 variability="fixed"),
        length("flute_length", "Cutting length of the flutes: deeper engagement warns (the shank rubs; tunable)",
               0.022, 1e-4, 0.3, variability="tunable"),
        length("clearance_range", "How far clearance searches for material: clearance is at most this", 5e-3, 0.0,
               0.1),
        Variable("zmap_file", "String", "parameter",
                 "File the final Z-map is written to at terminate (ESRI ASCII grid, heights in m; a relative path is "
                 "relative to the working directory); empty: none", start="", variability="fixed"),
        Variable("max_tool_speed", "Float64", "parameter",
                 "Fastest plausible tool motion: a faster jump between steps is an error (glitch or wrong units)",
                 unit="m/s", display_unit="mm/min", start=2.0, min=1e-3, max=100.0),
        length("tool_x", "The controlled point x: the tool tip (lowest point of the cutter) when tool_length is 0",
               0.0, -10.0, 10.0, causality="input"),
        length("tool_y", "The controlled point y: the tool tip when tool_length is 0", 0.0, -10.0, 10.0,
               causality="input"),
        length("tool_z", "The controlled point z: the tool tip when tool_length is 0 (the tip is at tool_z - "
               "tool_length)", 0.05, -10.0, 10.0, causality="input"),
        Variable("spindle_speed", "Float64", "input",
                 "Spindle speed (only checked: removing material with the spindle stopped warns)",
                 unit="rad/s", display_unit="rpm", start=0.0, min=-1e4, max=1e4),
        Variable("axial_depth", "Float64", "output", "Axial depth of cut: engaged height above the tool tip",
                 unit="m", display_unit=_MM),
        Variable("radial_depth", "Float64", "output", "Radial depth of cut: engaged width across the feed",
                 unit="m", display_unit=_MM),
        Variable("entry_angle", "Float64", "output",
                 "First engaged immersion angle (clockwise from +y of the feed frame; slotting 0)",
                 unit="rad", display_unit="deg"),
        Variable("exit_angle", "Float64", "output", "Last engaged immersion angle (slotting pi)",
                 unit="rad", display_unit="deg"),
        Variable("mrr", "Float64", "output", "Material removal rate: volume removed in the last step / step size",
                 unit="m3/s", display_unit="cm3/min"),
        Variable("clearance", "Float64", "output",
                 "Distance from the tool to the nearest material (0: in material; at most clearance_range)",
                 unit="m", display_unit=_MM),
        Variable("removed_volume", "Float64", "output", "Volume removed since the start", unit="m3",
                 display_unit="cm3"),
    ]
    variables.append(Variable(
        "engagement", "Float64", "output",
        f"Engagement map, {N_Z} heights x {N_THETA} angles: element [i, j] is 1 if the edge at height "
        f"(i+1/2)/{N_Z} of axial_depth and immersion angle (j+1/2)*{360 // N_THETA} deg is in material, else 0",
        shape=(N_Z, N_THETA)))
    return tuple(variables)


WORKPIECE = ModelDefinition(
    identifier="Workpiece",
    description="Z-map stock cut by a flat, bull-nose or ball end mill: depths, angles, MRR and engagement map",
    default_step_size=1e-3,
    default_stop_time=10.0,
    equations=None,
    variables=_variables(),
    native_outputs=SCALAR_OUTPUTS + ("engagement",),
    # model.c computes every output in doStep, from the inputs held over the step: none depends directly on an
    # input set at the communication point (nor, in Initialization Mode, on anything: they are 0 until the first step)
    native_dependencies=tuple((n, ()) for n in SCALAR_OUTPUTS + ("engagement",)),
    # model.c and config.h read these from the generated model_constants.h
    constants=(("N_Z", N_Z), ("N_THETA", N_THETA), ("N_BISECTIONS", N_BISECTIONS), ("MAX_CELLS", float(MAX_CELLS)),
               ("MIN_CELLS_ACROSS_TOOL", MIN_CELLS_ACROSS_TOOL), ("DESCEND_PER_SUBSEGMENT", DESCEND_PER_SUBSEGMENT),
               ("FEED_DIRECTION_MIN_TRAVEL", FEED_DIRECTION_MIN_TRAVEL), ("SPINDLE_STOPPED", SPINDLE_STOPPED),
               ("PI", math.pi)),
)

PARAMETERS = tuple(v.name for v in WORKPIECE.of("parameter") if v.type != "String")  # zmap_file: the FMU's only
INPUTS = tuple(v.name for v in WORKPIECE.of("input"))


class WorkpieceError(ValueError):
    """A parameter set or a step the FMU rejects; the message is the one the FMU logs (after its prefix)."""


def _g(number: float) -> str:
    """A number as the FMU's messages print it (C's %g)."""
    return "%g" % number


def validate(p: Mapping[str, float]) -> tuple[int, int]:
    """The checks of exitInitializationMode beyond the variable ranges; returns the grid (nx, ny)."""
    validate_tool(p)
    resolution = p["resolution"]
    nx_real = _cell_count(p["stock_length"], resolution)
    ny_real = _cell_count(p["stock_width"], resolution)
    if nx_real * ny_real > MAX_CELLS:
        finest = _finest_resolution(p["stock_length"], p["stock_width"])
        raise WorkpieceError(
            f"resolution = {_g(resolution)} m is too fine for the stock: {nx_real:.0f} x {ny_real:.0f} cells, more "
            f"than the limit of {MAX_CELLS} cells ({MAX_CELLS * 8 / 1e6:.0f} MB); use resolution >= {_g(finest)} m")
    return int(nx_real), int(ny_real)


def validate_tool(p: Mapping[str, float]) -> None:
    """The checks of the tool against the stock and the grid: those of exitInitializationMode, made again at
    a tool change (the FMU's doStep then fails with the message after "tool change: ")."""
    diameter, corner = p["tool_diameter"], p["corner_radius"]
    if corner > 0.5 * diameter:
        raise WorkpieceError(
            f"corner_radius = {_g(corner)} m is larger than tool_diameter/2 = {_g(0.5 * diameter)} m "
            "(0: flat end mill, tool_diameter/2: ball end mill)")
    if diameter > p["stock_length"] or diameter > p["stock_width"]:
        raise WorkpieceError(
            f"the tool is larger than the stock: tool_diameter = {_g(diameter)} m, stock_length = "
            f"{_g(p['stock_length'])} m, stock_width = {_g(p['stock_width'])} m")
    resolution = p["resolution"]
    if diameter < MIN_CELLS_ACROSS_TOOL * resolution:
        raise WorkpieceError(
            f"resolution = {_g(resolution)} m is too coarse for tool_diameter = {_g(diameter)} m: the Z-map needs "
            f"at least {MIN_CELLS_ACROSS_TOOL:g} cells across the tool (resolution <= "
            f"{_g(diameter / MIN_CELLS_ACROSS_TOOL)} m)")


def _finest_resolution(length: float, width: float) -> float:
    """The finest resolution whose grid (cells rounded up per side) fits MAX_CELLS, with a margin."""
    even = math.sqrt(length * width / MAX_CELLS)
    return even * (1.0 + ((length + width) / even + 1.0) / MAX_CELLS)


def _cell_count(size: float, resolution: float) -> float:
    """Cells along one side: the fewest of at most ``resolution`` (a millionth of a cell of slack)."""
    return math.ceil(size / resolution - 1e-6)


class ZMap:
    """The FMU's algorithm in numpy (see the module docstring), operation for operation: the FMU's
    outputs equal these to the last bit on the same inputs."""

    def __init__(self, parameters: Mapping[str, float], position: Sequence[float]):
        p = {**WORKPIECE.defaults(), **parameters}
        unknown = set(parameters) - set(PARAMETERS) - set(INPUTS)
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)}")
        self.p = p
        self.nx, self.ny = validate(p)
        self.x0, self.y0, self.z0 = p["stock_x_min"], p["stock_y_min"], p["stock_z_min"]
        self.dx = p["stock_length"] / self.nx
        self.dy = p["stock_width"] / self.ny
        self.top = self.z0 + p["stock_height"]
        self.delta = min(self.dx, self.dy)
        self.half_diagonal = 0.5 * math.sqrt(self.dx * self.dx + self.dy * self.dy)
        self.heights = np.full((self.ny, self.nx), self.top)
        self._derive_tool()
        column = 2.0 * math.pi / N_THETA
        front = [j for j in range(N_THETA) if (j + 0.5) * column < math.pi]
        self.map_columns = np.array(front)
        self.map_angles = np.array([(j + 0.5) * column for j in front])
        self.map_cos = np.array([math.cos((j + 0.5) * column) for j in front])
        self.map_sin = np.array([math.sin((j + 0.5) * column) for j in front])
        x, y, z = (float(c) for c in position)
        self.point_z = z  # the controlled point's z (tool_z) at the end of the last step
        self.position = (x, y, z - p["tool_length"])  # the tool tip
        self.feed = (1.0, 0.0)
        self.removed_height = 0.0  # the sum of all height drops so far [m]
        self._forget_the_cut_top()
        self._step_top = -math.inf  # of the cells the step lowers
        self.removed_volume = 0.0
        self.warnings: list[str] = []
        self._warned_spindle = self._warned_shank = self._warned_bottom = False
        self.outputs = dict.fromkeys(OUTPUTS, 0.0)

    def _derive_tool(self) -> None:
        """The tool's geometry and samples from ``self.p`` (at initialization and at a tool change)."""
        p = self.p
        self.radius = 0.5 * p["tool_diameter"]
        self.corner = p["corner_radius"]
        self.flat = self.radius - self.corner
        # how far inside the cutter's radius the test circle meets an earlier level's wall along an arc
        # of path radius R/2: the engaged height comes from points farther in (module docstring, step 2)
        self.arc_margin = self.half_diagonal + 2.0 * self.delta * (1.0 + 0.5 * self.delta / self.radius)
        # angle samples of the front half and profile samples (height, radius) along the corner arc
        self.n_angles = math.ceil(math.pi * self.radius / self.delta)
        self.cos_phi = np.array([math.cos(self._angle(m)) for m in range(self.n_angles + 1)])
        self.sin_phi = np.array([math.sin(self._angle(m)) for m in range(self.n_angles + 1)])
        self.n_corner = math.ceil(0.5 * math.pi * self.corner / self.delta) if self.corner > 0 else 0
        arc = 0.5 * math.pi / self.n_corner if self.n_corner else 0.0
        self.profile_z = np.array([self.corner * (1.0 - math.cos(k * arc)) for k in range(self.n_corner)]
                                  + [self.corner])
        self.profile_r = np.array([self.flat + self.corner * math.sin(k * arc) for k in range(self.n_corner)]
                                  + [self.radius])
        self.profile_next = np.append(self.profile_z[1:], math.inf)

    def _forget_the_cut_top(self) -> None:
        """No material cut in the current and the previous stretch (at the start, and at a tool change: the old
        tool's cuts do not bound the new tool's engaged height)."""
        # the cut top (module docstring, step 2): the highest height before the cut of the cells lowered in
        # the current stretch of travel and in the previous one (-inf: none), the current stretch's travel
        self.stretch_top = -math.inf
        self.previous_stretch_top = -math.inf
        self.stretch_travel = 0.0

    def change_tool(self, tool_diameter: float, corner_radius: float, tool_length: float,
                    flute_length: float) -> bool:
        """The tool for the next step (the values of the tunable parameters before it, as the FMU reads them at
        its doStep): a tool change when the diameter, corner radius or length differ from the tool's (module
        docstring, tool change); a new ``flute_length`` alone re-arms the shank warning. Returns whether the
        tool changed; raises :class:`WorkpieceError` (nothing changed) for a tool the stock or grid rejects."""
        p = self.p
        changed = (tool_diameter != p["tool_diameter"] or corner_radius != p["corner_radius"]
                   or tool_length != p["tool_length"])
        if changed:
            new = {**p, "tool_diameter": tool_diameter, "corner_radius": corner_radius, "tool_length": tool_length}
            try:
                validate_tool(new)
            except WorkpieceError as error:
                raise WorkpieceError(f"tool change: {error}") from None
            self.p = new
            self._derive_tool()
            x, y, _ = self.position
            self.position = (x, y, self.point_z - tool_length)  # the new tool in the spindle from the step's start
            self._forget_the_cut_top()
            self._warned_shank = False
        if changed or flute_length != self.p["flute_length"]:
            self.p = {**self.p, "flute_length": flute_length}
            self._warned_shank = False
        return changed

    # ---- removal ----

    def _remove_segment(self, a: tuple[float, float, float], b: tuple[float, float, float], volume: float) -> float:
        ax, ay, az = a
        bx, by, bz = b
        sx, sy, sz = bx - ax, by - ay, bz - az
        length2 = sx * sx + sy * sy
        if min(az, bz) >= self.top:
            return volume
        r = self.radius
        i_lo = max(math.floor((min(ax, bx) - r - self.x0) / self.dx - 0.5), 0)
        i_hi = min(math.ceil((max(ax, bx) + r - self.x0) / self.dx - 0.5), self.nx - 1)
        j_lo = max(math.floor((min(ay, by) - r - self.y0) / self.dy - 0.5), 0)
        j_hi = min(math.ceil((max(ay, by) + r - self.y0) / self.dy - 0.5), self.ny - 1)
        if i_lo > i_hi or j_lo > j_hi:
            return volume
        cx = self.x0 + (np.arange(i_lo, i_hi + 1, dtype=float) + 0.5) * self.dx
        cy = self.y0 + (np.arange(j_lo, j_hi + 1, dtype=float) + 0.5) * self.dy
        cx, cy = np.broadcast_arrays(cx[None, :], cy[:, None])
        if length2 > 0.0:
            t = ((cx - ax) * sx + (cy - ay) * sy) / length2
            t = np.where(t < 0.0, 0.0, np.where(t > 1.0, 1.0, t))
            qx, qy, zt = ax + t * sx, ay + t * sy, az + t * sz
        else:
            qx, qy, zt = np.full(cx.shape, ax), np.full(cx.shape, ay), np.full(cx.shape, min(az, bz))
        ex, ey = cx - qx, cy - qy
        d2 = ex * ex + ey * ey
        inside = d2 <= r * r
        zc = zt
        if self.corner > 0.0:
            on_corner = d2 > self.flat * self.flat
            e = np.sqrt(np.where(on_corner, d2, 0.0)) - self.flat
            lift = self.corner - np.sqrt(np.maximum(self.corner * self.corner - e * e, 0.0))
            zc = np.where(on_corner, zt + lift, zt)
        zc = np.where(zc < self.z0, self.z0, zc)
        block = self.heights[j_lo:j_hi + 1, i_lo:i_hi + 1]
        cut = inside & (zc < block)
        drops = np.where(cut, block - zc, 0.0).ravel()
        if drops.size:
            volume = float(np.cumsum(np.concatenate(([volume], drops)))[-1])  # the C loop's order
        if np.any(cut):
            self._step_top = max(self._step_top, float(block[cut].max()))
        block[cut] = zc[cut]
        return volume

    def _remove(self, start: tuple[float, float, float], end: tuple[float, float, float]) -> float:
        sx, sy, sz = (e - s for s, e in zip(start, end))
        n = 1
        if sx * sx + sy * sy > 0.0:
            n = max(1, math.ceil(abs(sz) / (DESCEND_PER_SUBSEGMENT * self.delta)))
        volume, a = 0.0, start
        for k in range(1, n + 1):
            f = k / n
            b = end if k == n else (start[0] + sx * f, start[1] + sy * f, start[2] + sz * f)
            volume = self._remove_segment(a, b, volume)
            a = b
        return volume

    # ---- engagement ----

    def _height_minus(self, px: np.ndarray, py: np.ndarray, z: float) -> np.ndarray:
        """Stock height at the points minus z; -inf outside the block."""
        fi = np.floor((px - self.x0) / self.dx)
        fj = np.floor((py - self.y0) / self.dy)
        inside = (fi >= 0) & (fi < self.nx) & (fj >= 0) & (fj < self.ny)
        i = np.where(inside, fi, 0).astype(np.int64)
        j = np.where(inside, fj, 0).astype(np.int64)
        return np.where(inside, self.heights[j, i] - z, -np.inf)

    def _direction(self, cos_a: np.ndarray, sin_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fx, fy = self.feed
        return sin_a * fx - cos_a * fy, sin_a * fy + cos_a * fx

    def _angle(self, m: int) -> float:
        """Angle sample m of the front half (m / n_angles of pi: exactly 0 and pi at the ends)."""
        return m / self.n_angles * math.pi

    def _engaged_at(self, phi: float) -> bool:
        """Any profile sample at angle phi in material (the test of the scan, at one angle)."""
        x, y, z = self.position
        ux, uy = self._direction(math.cos(phi), math.sin(phi))
        rho = self.profile_r + self.delta
        return bool(np.any(self._height_minus(x + rho * ux, y + rho * uy, z) > self.profile_z))

    def _boundary(self, inside: float, outside: float) -> float:
        """The engaged angle next to the boundary between samples ``inside`` (engaged) and ``outside``."""
        for _ in range(N_BISECTIONS):
            middle = 0.5 * (inside + outside)
            if self._engaged_at(middle):
                inside = middle
            else:
                outside = middle
        return inside

    def _engagement(self, cut_top: float) -> dict[str, float]:
        """The engagement at the tool's position (module docstring, step 2). ``cut_top``: the highest height before
        the cut of the cells lowered in the current and the previous stretch of travel (-inf: none)."""
        x, y, z = self.position
        out = dict.fromkeys(OUTPUTS, 0.0)
        if z >= self.top or cut_top == -math.inf:  # above the stock, or no material cut in the window
            return out
        ux, uy = self._direction(self.cos_phi, self.sin_phi)           # angles
        rho = self.profile_r + self.delta                              # profile samples
        px = x + rho[None, :] * ux[:, None]
        py = y + rho[None, :] * uy[:, None]
        height = self._height_minus(px, py, z)
        engaged = height > self.profile_z[None, :]
        any_engaged = np.any(engaged, axis=1)
        # a test point beside the cutter's circle (its lateral offset within half a cell diagonal of the
        # radius, or beyond) only touches a wall: runs without a cutting point are no cut, and the
        # heights such points see (a wall an earlier pass left at the radius, standing above the layer
        # now cut) are not engaged heights; nor those within arc_margin of the radius when the run has
        # points farther in (such a wall along an arc reaches that far in)
        lateral = np.abs(rho[None, :] * self.cos_phi[:, None])
        cutting = engaged & (lateral < self.profile_r[None, :] - self.half_diagonal)
        deep = engaged & (lateral < self.profile_r[None, :] - self.arc_margin)
        capped = np.minimum(height, self.profile_next[None, :])
        top = np.where(cutting, capped, -np.inf).max(axis=1)
        deep_top = np.where(deep, capped, -np.inf).max(axis=1)
        first, last, axial, m = -1, -1, -math.inf, 0
        while m <= self.n_angles:  # runs of consecutive engaged samples
            if not any_engaged[m]:
                m += 1
                continue
            start, run_top, run_deep = m, -math.inf, -math.inf
            while m <= self.n_angles and any_engaged[m]:
                run_top = max(run_top, float(top[m]))
                run_deep = max(run_deep, float(deep_top[m]))
                m += 1
            if run_top > -math.inf:  # the run has a cutting point
                first = start if first < 0 else first
                last = m - 1
                axial = max(axial, run_deep if run_deep > -math.inf else run_top)
        if first < 0:
            return out
        if not cut_top - z > 0.0:  # all it cut lies below the tip: it has risen from its cut
            return out
        if cut_top - z < axial:  # the engaged height is no more than that of the material the tool cuts
            axial = cut_top - z
        entry, exit_ = self._angle(first), self._angle(last)
        if first > 0:
            entry = self._boundary(entry, self._angle(first - 1))
        if last < self.n_angles:
            exit_ = self._boundary(exit_, self._angle(last + 1))
        # the test circle is delta outside the cutter: where it meets a wall parallel to the feed, the
        # cutter meets it at the same lateral position
        r_top = self._radius_at(axial)
        widen = (r_top + self.delta) / r_top
        cos_entry = min(max(widen * math.cos(entry), -1.0), 1.0)
        cos_exit = min(max(widen * math.cos(exit_), -1.0), 1.0)
        out["axial_depth"] = axial
        out["entry_angle"] = math.acos(cos_entry)
        out["exit_angle"] = math.acos(cos_exit)
        out["radial_depth"] = r_top * (cos_entry - cos_exit)
        zi = (np.arange(N_Z, dtype=float) + 0.5) * (axial / N_Z)
        ri = np.array([self._radius_at(float(h)) for h in zi]) + self.delta
        mx, my = self._direction(self.map_cos, self.map_sin)
        height = self._height_minus(x + ri[:, None] * mx[None, :], y + ri[:, None] * my[None, :], z)
        in_window = (self.map_angles >= out["entry_angle"]) & (self.map_angles <= out["exit_angle"])
        in_material = (height > zi[:, None]) & in_window[None, :]
        for i in range(N_Z):
            for k, j in enumerate(self.map_columns):
                out[map_name(i, int(j))] = 1.0 if in_material[i, k] else 0.0
        return out

    def _radius_at(self, height: float) -> float:
        """Cutter radius at ``height`` above the tip."""
        if height >= self.corner:
            return self.radius
        rise = self.corner - height
        return self.flat + math.sqrt(max(self.corner * self.corner - rise * rise, 0.0))

    # ---- clearance ----

    def _clearance(self) -> float:
        """Distance from the tool at its position to the nearest material (module docstring, step 3)."""
        x, y, z = self.position
        reach = self.radius + self.p["clearance_range"]
        limit = self.p["clearance_range"]
        if z - self.top >= limit:
            return limit
        margin = self.delta / 16.0
        i_lo = max(math.floor((x - reach - margin - self.x0) / self.dx - 0.5), 0)
        i_hi = min(math.ceil((x + reach + margin - self.x0) / self.dx - 0.5), self.nx - 1)
        j_lo = max(math.floor((y - reach - margin - self.y0) / self.dy - 0.5), 0)
        j_hi = min(math.ceil((y + reach + margin - self.y0) / self.dy - 0.5), self.ny - 1)
        if i_lo > i_hi or j_lo > j_hi:
            return limit
        ex = self.x0 + (np.arange(i_lo, i_hi + 1, dtype=float) + 0.5) * self.dx - x
        ey = self.y0 + (np.arange(j_lo, j_hi + 1, dtype=float) + 0.5) * self.dy - y
        heights = self.heights[j_lo:j_hi + 1, i_lo:i_hi + 1]
        gh = np.maximum(np.sqrt(ex[None, :] * ex[None, :] + ey[:, None] * ey[:, None]) - self.radius, 0.0)
        gv = np.maximum(z - heights, 0.0)
        distance = np.where(heights > self.z0, np.sqrt(gh * gh + gv * gv), math.inf)
        return min(limit, float(distance.min()))

    def _over_the_stock(self) -> bool:
        """The tool's footprint (the disc of radius R about its axis) overlaps the block seen from above."""
        x, y, _ = self.position
        gap_x = max(self.x0 - x, 0.0, x - (self.x0 + self.p["stock_length"]))
        gap_y = max(self.y0 - y, 0.0, y - (self.y0 + self.p["stock_width"]))
        return gap_x * gap_x + gap_y * gap_y < self.radius * self.radius

    # ---- one step ----

    def step(self, position: Sequence[float], step_size: float, spindle_speed: float = 0.0,
             max_tool_speed: float | None = None) -> dict[str, float]:
        """Move the tool in a straight line to the controlled point ``position`` (tool_x, tool_y, tool_z) over
        ``step_size``; returns the outputs."""
        x, y, z = (float(c) for c in position)
        end = (x, y, z - self.p["tool_length"])
        start = self.position
        sx, sy, sz = (e - s for s, e in zip(start, end))
        travel = math.sqrt(sx * sx + sy * sy + sz * sz)
        limit = self.p["max_tool_speed"] if max_tool_speed is None else max_tool_speed
        if travel > limit * step_size:
            raise WorkpieceError(
                f"the tool tip moved {_g(travel)} m in {_g(step_size)} s ({_g(travel / step_size)} m/s), faster than "
                f"max_tool_speed = {_g(limit)} m/s: a jump in tool_x, tool_y, tool_z (a glitch, or not in m?)")
        self._step_top = -math.inf
        volume = self._remove(start, end)
        stretch_top = max(self.stretch_top, self._step_top)
        self.stretch_travel += travel
        horizontal = math.sqrt(sx * sx + sy * sy)
        if horizontal > FEED_DIRECTION_MIN_TRAVEL * self.delta:
            self.feed = (sx / horizontal, sy / horizontal)
        self.position = end
        self.point_z = z
        self.removed_height += volume
        self.removed_volume = self.removed_height * (self.dx * self.dy)
        # a step that rises more than it moves sideways and lowers no cell cuts nothing (a retract: the flanks
        # slide up the walls they touch): not engaged, as without a cut top (module docstring, step 2)
        retracting = sz > horizontal and volume == 0.0
        out = self._engagement(-math.inf if retracting else max(stretch_top, self.previous_stretch_top))
        if self.stretch_travel >= self.radius:  # the stretch ends with this step
            self.previous_stretch_top, self.stretch_top, self.stretch_travel = stretch_top, -math.inf, 0.0
        else:
            self.stretch_top = stretch_top
        out["mrr"] = volume * (self.dx * self.dy) / step_size
        out["clearance"] = self._clearance()
        out["removed_volume"] = self.removed_volume
        if volume > 0.0 and abs(spindle_speed) < SPINDLE_STOPPED and not self._warned_spindle:
            self._warned_spindle = True
            self.warnings.append("spindle")
        if out["axial_depth"] > self.p["flute_length"] and not self._warned_shank:
            self._warned_shank = True
            self.warnings.append("shank")
        if end[2] < self.z0 and self._over_the_stock() and not self._warned_bottom:
            self._warned_bottom = True
            self.warnings.append("bottom")
        self.outputs = out
        return out


# ---- the final Z-map as a file ----

NODATA = -9999.0


class ZMapFileError(ValueError):
    """A Z-map file that is not an ESRI ASCII grid; the message names the file and the line."""


def read_zmap(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An ESRI ASCII grid (the FMU's ``zmap_file``): the x of the cell centres (nx), the y of the cell
    centres (ny, increasing) and the heights [ny, nx] (row 0 the southmost, as ``ZMap.heights``; NaN
    for NODATA). Accepts ``xllcorner``/``xllcenter``, ``cellsize`` or ``dx`` and ``dy``, an optional
    ``NODATA_value``; header keys in any case. Raises :class:`ZMapFileError` naming the file and line."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ZMapFileError(f"{path}: cannot read the Z-map: {exc}") from exc
    header: dict[str, float] = {}
    number = 0
    keys = ("ncols", "nrows", "xllcorner", "yllcorner", "xllcenter", "yllcenter", "cellsize", "dx", "dy",
            "nodata_value")
    while number < len(lines):
        words = lines[number].split()
        if not words or words[0].lower() not in keys:
            break
        if len(words) != 2:
            raise ZMapFileError(f"{path} line {number + 1}: '{lines[number]}': a header line is a key and a number")
        key = words[0].lower()
        if key in header:
            raise ZMapFileError(f"{path} line {number + 1}: '{words[0]}' given twice")
        header[key] = _header_number(path, number, words[1])
        number += 1
    for required in ("ncols", "nrows"):
        if required not in header:
            raise ZMapFileError(f"{path} line {number + 1}: the header has no '{required}' (an ESRI ASCII grid?)")
    nx, ny = header["ncols"], header["nrows"]
    if nx != int(nx) or ny != int(ny) or nx < 1 or ny < 1:
        raise ZMapFileError(f"{path}: ncols = {nx:g} and nrows = {ny:g} must be whole numbers >= 1")
    nx, ny = int(nx), int(ny)
    if "cellsize" in header:
        if "dx" in header or "dy" in header:
            raise ZMapFileError(f"{path}: the header has both 'cellsize' and 'dx'/'dy'")
        dx = dy = header["cellsize"]
    elif "dx" in header and "dy" in header:
        dx, dy = header["dx"], header["dy"]
    else:
        raise ZMapFileError(f"{path} line {number + 1}: the header has neither 'cellsize' nor 'dx' and 'dy'")
    if not (dx > 0 and dy > 0):
        raise ZMapFileError(f"{path}: the cell size must be positive (dx = {dx:g}, dy = {dy:g})")
    x_centres = _centres(path, header, "x", nx, dx)
    y_centres = _centres(path, header, "y", ny, dy)
    rows = []
    for k in range(ny):
        line = number + k
        if line >= len(lines):
            raise ZMapFileError(f"{path} line {line + 1}: the file ends after {k} of nrows = {ny} rows")
        words = lines[line].split()
        if len(words) != nx:
            raise ZMapFileError(f"{path} line {line + 1}: {len(words)} values, ncols = {nx}")
        try:
            rows.append([float(w) for w in words])
        except ValueError:
            bad = next(w for w in words if not _is_number(w))
            raise ZMapFileError(f"{path} line {line + 1}: '{bad}' is not a number") from None
    extra = [n for n in range(number + ny, len(lines)) if lines[n].strip()]
    if extra:
        raise ZMapFileError(f"{path} line {extra[0] + 1}: more than nrows = {ny} rows")
    heights = np.array(rows[::-1], dtype=float).reshape(ny, nx)
    if "nodata_value" in header:
        heights[heights == header["nodata_value"]] = np.nan
    return x_centres, y_centres, heights


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _header_number(path: Path, index: int, word: str) -> float:
    try:
        value = float(word)
    except ValueError:
        raise ZMapFileError(f"{path} line {index + 1}: '{word}' is not a number") from None
    if not math.isfinite(value):
        raise ZMapFileError(f"{path} line {index + 1}: '{word}' is not a finite number")
    return value


def _centres(path: Path, header: Mapping[str, float], axis: str, count: int, size: float) -> np.ndarray:
    corner, centre = header.get(f"{axis}llcorner"), header.get(f"{axis}llcenter")
    if (corner is None) == (centre is None):
        raise ZMapFileError(f"{path}: the header needs one of '{axis}llcorner' and '{axis}llcenter'")
    if corner is not None:
        return corner + (np.arange(count, dtype=float) + 0.5) * size
    return centre + np.arange(count, dtype=float) * size


# ---- what the generic FMU tests (tests/fmu_helpers.py) use for this model ----


def initial_outputs(values: Mapping[str, float | np.ndarray]) -> np.ndarray:
    """Outputs in initialization mode (before any step): all 0 (points x outputs)."""
    count = max([np.size(v) for v in values.values()] + [1])
    return np.zeros((count, len(OUTPUTS)))


def reference_trajectory(points: Sequence[Mapping[str, float]], step_size: float) -> np.ndarray:
    """What the FMU gives when initialized with points[0] and, for each point, set to it and stepped
    by ``step_size`` (points x outputs, in the order of OUTPUTS)."""
    first = {**WORKPIECE.defaults(), **points[0]}
    zmap = ZMap({n: first[n] for n in PARAMETERS}, (first["tool_x"], first["tool_y"], first["tool_z"]))
    rows = []
    for point in points:
        point = {**first, **{n: v for n, v in point.items() if WORKPIECE.variable(n).effective_variability != "fixed"}}
        zmap.change_tool(point["tool_diameter"], point["corner_radius"], point["tool_length"], point["flute_length"])
        out = zmap.step((point["tool_x"], point["tool_y"], point["tool_z"]), step_size, point["spindle_speed"],
                        point["max_tool_speed"])
        rows.append([out[n] for n in OUTPUTS])
    return np.array(rows)


def random_arguments(count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Random valid operating points for the generic FMU tests (random points of the whole box of
    ranges are not valid for this model: the tool must fit the stock and the path must be a path).
    A random small block, tool (flat, ball or bull-nose) and depth; the tool ramps into the block
    from its -x side, then slots back and forth inside it in passes 1.1 tool diameters apart, with a
    random feed of 0.05 .. 0.4 mm per point (at most 0.4 m/s at 1 ms steps). Parameters other than
    max_tool_speed are constant columns (no tool change); the tool's length is 0 or random (tool_z the
    controlled point that far above the tip). The ramp starts 2 mm beside the block, so the first 5 points
    are in air with a clearance well above 0. (A test holding the tool at one point through fmpy's master,
    which interpolates the inputs and may move them by an ulp, would otherwise compare a clearance of
    exactly 0 in the reference with the 1e-18 m an ulp's lift gives, where no relative tolerance helps.)"""
    diameter = rng.uniform(4e-3, 8e-3)
    parameters = {
        "stock_x_min": rng.uniform(-0.05, 0.05), "stock_y_min": rng.uniform(-0.05, 0.05),
        "stock_z_min": rng.uniform(-0.05, 0.05), "stock_length": rng.uniform(0.02, 0.04),
        "stock_width": rng.uniform(0.015, 0.03), "stock_height": rng.uniform(0.008, 0.015),
        "resolution": rng.uniform(0.4e-3, 0.8e-3), "tool_diameter": diameter,
        "corner_radius": float(rng.choice([0.0, 0.5 * diameter, rng.uniform(0.0, 0.5 * diameter)])),
        "flute_count": float(rng.integers(2, 5)), "helix_angle": rng.uniform(0.0, 0.8),
        "flute_length": 3 * diameter, "clearance_range": rng.uniform(0.5e-3, 8e-3),
        "tool_length": float(rng.choice([0.0, rng.uniform(0.02, 0.1)])),
    }
    radius = 0.5 * diameter
    top = parameters["stock_z_min"] + parameters["stock_height"]
    depth = rng.uniform(0.2, 0.9) * min(diameter, parameters["stock_height"])
    x_lo = parameters["stock_x_min"] + radius + 0.5e-3
    x_hi = parameters["stock_x_min"] + parameters["stock_length"] - radius - 0.5e-3
    x, y = parameters["stock_x_min"] - radius - 2e-3, parameters["stock_y_min"] + rng.uniform(0.7, 1.5) * radius
    z, direction, phase, target = top, 1.0, "ramp", 0.0
    path = []
    for _ in range(count):
        path.append((x, y, z))
        feed = rng.uniform(0.05e-3, 0.4e-3)
        if phase == "ramp":  # into the block from the -x side, descending
            z = max(z - 0.5 * feed, top - depth)
            x += feed
            phase = "pass" if z == top - depth else phase
        elif phase == "pass":
            x += direction * feed
            if (x >= x_hi) if direction > 0 else (x <= x_lo):
                phase, target = "shift", y + 1.1 * diameter
        else:  # across to the next pass
            y += feed
            if y >= target:
                phase, direction = "pass", -direction
    values = {n: np.full(count, float(v)) for n, v in parameters.items()}
    values["max_tool_speed"] = rng.uniform(1.0, 3.0, count)
    values["tool_x"] = np.array([p[0] for p in path])
    values["tool_y"] = np.array([p[1] for p in path])
    values["tool_z"] = np.array([p[2] for p in path]) + parameters["tool_length"]  # the controlled point
    values["spindle_speed"] = rng.uniform(500.0, 2000.0, count)
    return values


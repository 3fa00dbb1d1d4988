"""Force net: the milling force of a flat end mill from a neural network that predicts the load on each
cutting-edge element from the cutting geometry (the data-driven alternative to models/cutting_force.py).

This module holds everything the FMU (``fmus/forcenet/``) and the orchestrator need, without torch: the
model definition, the cutting geometry, the weights file format, and the inference in numpy in the very
operations and order of the FMU's C code (the reference the tests hold the FMU to). Training, export and
fine-tuning are in :mod:`milling_twin.training.force_net` (torch, the optional ``train`` extra).

Conventions: those of :mod:`milling_twin.models.cutting_force` (Altintas): z towards the spindle, clockwise spindle
(M3), the immersion angle ``phi`` of an edge point clockwise from +y, entry/exit angles relative to the feed
direction, ``Fx, Fy, Fz`` the force **on the tool**, ``torque`` the cutting torque. Inputs, parameters and
outputs carry the names, units and ranges of the CuttingForce FMU, so a scenario swaps one for the other by
changing ``fmu = "CuttingForce"`` into ``fmu = "ForceNet"``; ForceNet has no cutting coefficients (its network
learnt them). The regenerative chip and runout are CuttingForce's: the displacement inputs go into the same
displacement history (``fmus/common/displacement_history.c``, :class:`milling_twin.models.cutting_force.DisplacementHistory`)
and the chip of flute m is ``h = min over k = 1..N of (k T_tooth (v_x sin(phi) + v_y cos(phi)) + r_m - r_(m-k)) +
dx sin(phi) + dy cos(phi)`` with ``(dx, dy)`` the displacement now minus one tooth period ago and ``r_m =
runout_offset cos(runout_angle - m 2 pi / N)``; the network reads that h (trained on static chips only, it follows
CuttingForce in the chatter loop: tests/test_forcenet.py).

1. **Cutting geometry image.** Over the tool envelope, a grid of H rows (heights ``z_k = (k + 1/2) a_p / H``,
   ``k = 0 .. H-1``, ``H = ELEMENTS_PER_FLUTE = 16``) by W columns (angles around the axis). Per pixel the
   cutting-element matrix ``C = [h; v; theta0]``: the undeformed chip thickness
   ``h = step(engaged) * f . n = step(engaged) * T_tooth * (v_x sin(phi) + v_y cos(phi))`` (the feed per
   tooth projected on the envelope normal ``n = (sin phi, cos phi, 0)`` of a flat end mill; 0 where the
   pixel is not in material or where that chip is not positive), the cutting speed ``v = omega * r(z) = omega * D/2``
   and the current tool angle ``theta0`` (the spindle angle of flute 0 at the tip). **Material** comes from the
   Workpiece FMU's engagement map, the input ``engagement`` (8 heights x 24 angles, row i the heights
   ``[i, i+1) a_p / 8``, column j the feed-frame angles ``[15 j, 15 (j+1))`` deg): edge element k (of every
   flute) at feed-frame angle ``theta`` reads the cell that holds it, row ``k * 8 // 16`` (the map's rows halve
   the H = 16 element heights: elements 2i and 2i+1 share row i) and column ``floor(theta / 15 deg)``; it is in
   material when that cell is >= 0.5. A negative cell (the start value -1 in every cell: no map connected)
   leaves the element to the cutting-state window ``entry_angle .. exit_angle`` (measured from the feed
   direction), so a scenario written for CuttingForce (depth and window, no map) gives the same material
   with ForceNet, and a full-slot map gives exactly the slot window's elements. ``axial_depth`` still sets
   the element heights (the map's rows are fractions of it). The image is a continuous field: the network
   reads it at the exact position of each edge element (:func:`geometry_image` samples it on a W x H grid).
2. **Position encoding.** Each edge element has a horizontal angle ``theta`` (its immersion angle in the
   feed frame, ``phi + atan2(v_y, v_x)`` wrapped to [0, 2*pi)) and an axial angle ``psi = z tan(helix) / R``
   (the helix lag of the element behind the tip). They expand into four matrices
   ``M1 = sin(theta), M2 = cos(theta), M3 = sin(psi), M4 = cos(psi)``.
3. **Network**, per element, on the 7 features
   ``x = [h / h_ref, v / v_ref, theta0 / pi - 1, M1, M2, M3, M4]`` (``h_ref``, ``v_ref`` in the weights file):
   kernel-function block ``a1 = (BN(L1 x))^3`` (K units), linear-transform block ``a2 = relu(BN(L2 a1))``
   (W units), residual blocks ``a <- relu(a + BN(L4 relu(BN(L3 a))))`` (B blocks of W units), and a final
   linear layer giving the element's load per unit edge length ``load_ref * L_out a`` in N/m: tangential,
   radial, axial. Defaults K = 16, W = 32, B = 2 (:data:`DEFAULT_SIZES`). For inference BatchNorm is folded
   into the linear layer before it.
4. **Tool force.** Each of the ``n_flutes`` edges is divided into H elements of height ``dz = a_p / H``; flute
   m's element k lies at ``phi = theta0 + m 2 pi / N - psi_k``. Elements in contact (engaged, chip > 0,
   spindle turning) carry ``dF = F'(m, k) dz`` (others 0), projected as in CuttingForce:
   ``dFx = -dFt cos(phi) - dFr sin(phi)``, ``dFy = dFt sin(phi) - dFr cos(phi)``, ``dFz = dFa``; summed into
   ``Fx, Fy, Fz``, ``torque = sum(dFt) R_m`` (``R_m = R + r_m``, the radius of the element's flute) and the
   moment about the point ``(0, 0, moment_height)`` of the tool axis (``moment_height`` above the tip), with
   the element at ``(R_m sin(phi), R_m cos(phi), z)``:
   ``M = sum((p - (0, 0, z')) x dF)``, output ``Mx, My, Mz``. ``power = torque * omega``.

Weights file (``fmus/forcenet/resources/weights.bin``, packed into the FMU's resources/ and loaded when the
instance is created; format in :func:`encode_weights`): little-endian, a header with the sizes and scales,
the layers (BatchNorm folded) with their shapes, and an FNV-1a 64 checksum. It is regenerated reproducibly
by ``milling-twin train forcenet`` (which also rewrites the FMU's built-in copy
``fmus/forcenet/default_weights.h``, used only when an importer passes no resource location);
:func:`install_weights` puts another network into a built FMU without recompiling.
"""
from __future__ import annotations

import math
import shutil
import struct
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from milling_twin.models.cutting_force import AL7075_CARBIDE, CUTTING_FORCE, OMEGA_MIN, TWO_PI, DisplacementHistory, _tooth_period
from milling_twin.models.cutting_force import tooth_period as history_period
from milling_twin.models.cutting_force import update as _angle_update
from milling_twin.models.definition import ModelDefinition, State, Variable
from milling_twin.models.step_clock import StepClock
from milling_twin.models.workpiece import N_THETA as MAP_COLUMNS
from milling_twin.models.workpiece import N_Z as MAP_ROWS

ELEMENTS_PER_FLUTE = 16  # H: edge elements per flute (the rows of the geometry image)
MAX_FLUTES = 6
N_FEATURES = 7           # h, v, theta0, M1..M4
N_LOADS = 3              # tangential, radial, axial
DEFAULT_SIZES = {"kernel": 16, "width": 32, "blocks": 2}
MAX_WIDTH = 128          # the FMU's limit on K and W (written into its model_constants.h)
MAX_BLOCKS = 16          # the FMU's limit on B
REPO = Path(__file__).resolve().parents[1]
WEIGHTS_FILE = REPO / "fmus" / "forcenet" / "resources" / "weights.bin"
DEFAULT_WEIGHTS_HEADER = REPO / "fmus" / "forcenet" / "default_weights.h"
H_REF, V_REF, LOAD_REF = 1e-4, 10.0, 1e5  # default feature and load scales: 0.1 mm, 10 m/s, 100 N/mm
MAGIC = b"FORCENET"
FORMAT_VERSION = 1
FEATURE_NAMES = ("h/h_ref", "v/v_ref", "theta0/pi-1", "sin(theta)", "cos(theta)", "sin(psi)", "cos(psi)")


# ---- the model definition: shared variables are CuttingForce's own ----

def _equations(v):
    """The outputs generated into C: the spindle angle and the feed per tooth, as CuttingForce gives them."""
    turning, period = _tooth_period(v)
    return {"spindle_angle": v["angle"],
            "feed_per_tooth": ca.if_else(turning, period * ca.sqrt(v["feed_velocity_x"] ** 2
                                                                  + v["feed_velocity_y"] ** 2), 0)}


_SHARED_PARAMETERS = ("tool_diameter", "helix_angle", "n_flutes", "runout_offset", "runout_angle", "history_size")
_SHARED_INPUTS = ("spindle_speed", "feed_velocity_x", "feed_velocity_y", "axial_depth", "entry_angle", "exit_angle",
                  "displacement_x", "displacement_y")
_SHARED_OUTPUTS = ("Fx", "Fy", "Fz", "torque", "power", "spindle_angle", "feed_per_tooth")
NATIVE_OUTPUTS = ("Fx", "Fy", "Fz", "torque", "power", "Mx", "My", "Mz")
# what model.c hands the net for the native outputs (ForceNetCut)
_NET_INPUTS = (*_SHARED_INPUTS, "engagement")


def _net_parameters(output: str) -> tuple[str, ...]:
    """The tool parameters the net's output reads; the height of the moment point only matters to Mx and My."""
    tool = ("tool_diameter", "helix_angle", "n_flutes", "runout_offset", "runout_angle")
    return tool + (("moment_height",) if output in ("Mx", "My") else ())

FORCE_NET = ModelDefinition(
    identifier="ForceNet",
    description="Milling force of a flat end mill from a neural network of the per-element cutting load "
                "(weights in resources/weights.bin)",
    default_step_size=1e-5,
    default_stop_time=0.1,
    equations=_equations,
    update=_angle_update,
    native_outputs=NATIVE_OUTPUTS,
    native_states=("delayed_displacement_x", "delayed_displacement_y"),
    # the net reads the tool, the cut and the regenerative displacement (current minus delayed: none in
    # Initialization Mode, where there is no history and the delayed displacement is the current one)
    native_dependencies=(*((n, _net_parameters(n) + _NET_INPUTS) for n in NATIVE_OUTPUTS),
                         ("delayed_displacement_x", ("n_flutes", "spindle_speed", "displacement_x")),
                         ("delayed_displacement_y", ("n_flutes", "spindle_speed", "displacement_y"))),
    native_initial_dependencies=tuple(
        (n, _net_parameters(n) + tuple(i for i in _NET_INPUTS if not i.startswith("displacement_")))
        for n in NATIVE_OUTPUTS),
    native_initial_states=(("delayed_displacement_x", "displacement_x"), ("delayed_displacement_y", "displacement_y")),
    # model.c, forcenet.c and forcenet.h read these from the generated model_constants.h
    constants=(("OMEGA_MIN", OMEGA_MIN), ("TWO_PI", TWO_PI), ("PI", math.pi), ("N_FEATURES", N_FEATURES),
               ("N_LOADS", N_LOADS), ("MAX_WIDTH", MAX_WIDTH), ("MAX_BLOCKS", MAX_BLOCKS),
               ("ELEMENTS_PER_FLUTE", ELEMENTS_PER_FLUTE), ("MAX_FLUTES", MAX_FLUTES), ("MAP_ROWS", MAP_ROWS),
               ("MAP_COLUMNS", MAP_COLUMNS)),
    states=(State("angle", "Spindle angle: flute 0 at the tool tip, clockwise from +y", unit="rad"),
            State("delayed_displacement_x", "Tool displacement in x one tooth period ago (model.c)", unit="m"),
            State("delayed_displacement_y", "Tool displacement in y one tooth period ago (model.c)", unit="m")),
    variables=(
        *(CUTTING_FORCE.variable(n) for n in _SHARED_PARAMETERS),
        Variable("moment_height", "Float64", "parameter",
                 "Height above the tool tip of the point of the axis the moment Mx, My, Mz is taken about",
                 unit="m", display_unit="mm", start=0.0, min=-1.0, max=1.0),
        *(CUTTING_FORCE.variable(n) for n in _SHARED_INPUTS),
        Variable("engagement", "Float64", "input",
                 f"Engagement map of the Workpiece FMU, {MAP_ROWS} heights x {MAP_COLUMNS} angles (its output "
                 "'engagement'): a cell >= 0 says whether the edge elements in it are in material (from 0.5 on); "
                 "-1 (the start value: not connected) leaves the cell to the window entry_angle..exit_angle",
                 start=-1.0, min=-1.0, max=1.0, shape=(MAP_ROWS, MAP_COLUMNS)),
        *(CUTTING_FORCE.variable(n) for n in _SHARED_OUTPUTS[:5]),
        Variable("Mx", "Float64", "output", "Moment of the cutting forces on the tool about x, at moment_height",
                 unit="N.m"),
        Variable("My", "Float64", "output", "Moment of the cutting forces on the tool about y, at moment_height",
                 unit="N.m"),
        Variable("Mz", "Float64", "output", "Moment of the cutting forces on the tool about the axis "
                 "(equals the torque; opposes the clockwise rotation)", unit="N.m"),
        *(CUTTING_FORCE.variable(n) for n in _SHARED_OUTPUTS[5:]),
    ),
)

OUTPUTS = tuple(v.name for v in FORCE_NET.of("output"))


# ---- the weights file ----

class WeightsError(ValueError):
    """A weights file that cannot be used; the message says why (as the FMU's does)."""


@dataclass(frozen=True)
class Weights:
    """An exported network: linear layers in order (kernel, transform, 2 per residual block, output), each
    ``(W, b)`` with W of shape (out, in), BatchNorm folded in; the feature and load scales."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    h_ref: float = H_REF       # m: chip thickness scale of the first feature
    v_ref: float = V_REF       # m/s: cutting speed scale of the second feature
    load_ref: float = LOAD_REF  # N/m: the output layer gives the loads in this unit

    @property
    def kernel(self) -> int:
        return self.layers[0][0].shape[0]

    @property
    def width(self) -> int:
        return self.layers[1][0].shape[0]

    @property
    def blocks(self) -> int:
        return (len(self.layers) - 3) // 2

    def shapes(self) -> list[tuple[int, int]]:
        return [w.shape for w, _ in self.layers]

    @staticmethod
    def expected_shapes(kernel: int, width: int, blocks: int) -> list[tuple[int, int]]:
        return ([(kernel, N_FEATURES), (width, kernel)] + [(width, width)] * (2 * blocks) + [(N_LOADS, width)])


_HEADER = struct.Struct("<8sIIIIII3d")


def _fnv1a64(data: bytes) -> int:
    h = 0xcbf29ce484222325
    prime = 0x100000001b3
    arr = np.frombuffer(data, dtype=np.uint8)
    for byte in arr.tolist():  # ~50 kB: fast enough, and the same loop as the C code
        h = ((h ^ byte) * prime) & 0xFFFFFFFFFFFFFFFF
    return h


def encode_weights(weights: Weights) -> bytes:
    """The bytes of a weights file. Layout, little-endian:

    ======  ==========  ==============================================================
    offset  type        content
    ======  ==========  ==============================================================
    0       char[8]     magic ``FORCENET``
    8       uint32      format version (1)
    12      uint32      n_inputs (7: the features, in the order of FEATURE_NAMES)
    16      uint32      K, width of the kernel-function block
    20      uint32      W, width of the linear-transform and residual blocks
    24      uint32      B, number of residual blocks
    28      uint32      n_outputs (3: tangential, radial, axial load)
    32      float64     h_ref [m]
    40      float64     v_ref [m/s]
    48      float64     load_ref [N/m]
    56      layers      3 + 2B linear layers in order: kernel (K x 7), transform (W x K), per residual
                        block two (W x W), output (3 x W); each: uint32 rows, uint32 cols, then
                        float64 weight[rows][cols] (row-major, out x in), float64 bias[rows]
    end-8   uint64      FNV-1a 64 hash of every byte before it
    ======  ==========  ==============================================================

    BatchNorm is folded into the layer before it; the activations are fixed by position (cube after the
    kernel layer, ReLU after the transform layer and inside/after each residual block, none at the output).
    """
    shapes = weights.shapes()
    expected = Weights.expected_shapes(weights.kernel, weights.width, weights.blocks)
    if shapes != expected or len(weights.layers) != 3 + 2 * weights.blocks:
        raise WeightsError(f"layer shapes {shapes} are not those of the architecture {expected}")
    parts = [_HEADER.pack(MAGIC, FORMAT_VERSION, N_FEATURES, weights.kernel, weights.width, weights.blocks,
                          N_LOADS, weights.h_ref, weights.v_ref, weights.load_ref)]
    for w, b in weights.layers:
        w = np.ascontiguousarray(w, dtype="<f8")
        b = np.ascontiguousarray(b, dtype="<f8")
        if b.shape != (w.shape[0],) or not (np.all(np.isfinite(w)) and np.all(np.isfinite(b))):
            raise WeightsError("a layer has a bias of the wrong size or non-finite values")
        parts += [struct.pack("<II", *w.shape), w.tobytes(), b.tobytes()]
    body = b"".join(parts)
    return body + struct.pack("<Q", _fnv1a64(body))


def write_weights(weights: Weights, path: Path | str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(encode_weights(weights))
    return path


def decode_weights(data: bytes, name: str = "weights") -> Weights:
    """Parses and checks a weights file (the checks of the FMU's loader, with its messages)."""
    if len(data) < _HEADER.size + 8:
        raise WeightsError(f"{name}: truncated: {len(data)} bytes, shorter than the {_HEADER.size + 8}-byte "
                           "header and checksum")
    magic, version, n_in, kernel, width, blocks, n_out, h_ref, v_ref, load_ref = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise WeightsError(f"{name}: not a force-net weights file (magic {magic!r}, expected {MAGIC!r})")
    if version != FORMAT_VERSION:
        raise WeightsError(f"{name}: format version {version}, this reader knows {FORMAT_VERSION}")
    if n_in != N_FEATURES or n_out != N_LOADS:
        raise WeightsError(f"{name}: shape mismatch: the network has {n_in} inputs and {n_out} outputs, the model "
                           f"needs {N_FEATURES} and {N_LOADS}")
    if not (1 <= kernel <= MAX_WIDTH and 1 <= width <= MAX_WIDTH and blocks <= MAX_BLOCKS):
        raise WeightsError(f"{name}: sizes K = {kernel}, W = {width}, B = {blocks} outside 1..{MAX_WIDTH}, "
                           f"1..{MAX_WIDTH}, 0..{MAX_BLOCKS}")
    if not all(math.isfinite(x) and x > 0 for x in (h_ref, v_ref, load_ref)):
        raise WeightsError(f"{name}: scales h_ref, v_ref, load_ref must be positive and finite")
    shapes = Weights.expected_shapes(kernel, width, blocks)
    size = _HEADER.size + sum(8 + 8 * (r * c + r) for r, c in shapes) + 8
    if len(data) != size:
        raise WeightsError(f"{name}: {'truncated' if len(data) < size else 'trailing data'}: {len(data)} bytes, "
                           f"the header (K = {kernel}, W = {width}, B = {blocks}) needs {size}")
    (stored,) = struct.unpack_from("<Q", data, size - 8)
    if stored != _fnv1a64(data[:size - 8]):
        raise WeightsError(f"{name}: checksum mismatch (corrupted file)")
    offset, layers = _HEADER.size, []
    for i, (rows, cols) in enumerate(shapes):
        r, c = struct.unpack_from("<II", data, offset)
        if (r, c) != (rows, cols):
            raise WeightsError(f"{name}: shape mismatch: layer {i} is {r} x {c}, expected {rows} x {cols}")
        offset += 8
        w = np.frombuffer(data, "<f8", rows * cols, offset).reshape(rows, cols).astype(float)
        offset += 8 * rows * cols
        b = np.frombuffer(data, "<f8", rows, offset).astype(float)
        offset += 8 * rows
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(b))):
            raise WeightsError(f"{name}: layer {i} holds non-finite values")
        layers.append((w, b))
    return Weights(tuple(layers), h_ref, v_ref, load_ref)


def read_weights(path: Path | str = WEIGHTS_FILE) -> Weights:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise WeightsError(f"cannot open the weights file '{path}': {exc.strerror}") from exc
    return decode_weights(data, str(path))


_DEFAULT: dict[Path, Weights] = {}


def default_weights() -> Weights:
    """The network packed into the FMU (fmus/forcenet/resources/weights.bin), read once."""
    if WEIGHTS_FILE not in _DEFAULT:
        _DEFAULT[WEIGHTS_FILE] = read_weights(WEIGHTS_FILE)
    return _DEFAULT[WEIGHTS_FILE]


def weights_header(data: bytes) -> str:
    """fmus/forcenet/default_weights.h: the default weights file as bytes, used by the FMU only when the
    importer gives no resource location at all."""
    lines = [",".join(str(b) for b in data[i:i + 32]) for i in range(0, len(data), 32)]
    body = ",\n".join(lines)
    return ("/* Generated by `milling-twin train forcenet --header-only` from resources/weights.bin: the default\n"
            " * network, used only when the importer passes no resource location (tests check it is identical). */\n"
            "#ifndef FORCENET_DEFAULT_WEIGHTS_H\n#define FORCENET_DEFAULT_WEIGHTS_H\n\n"
            f"static const unsigned char FORCENET_DEFAULT_WEIGHTS[{len(data)}] = {{\n{body}\n}};\n\n#endif\n")


def install_weights(fmu: Path | str, weights: Weights | Path | str, out: Path | str) -> Path:
    """A copy of a built ForceNet FMU with ``weights`` (a Weights or a weights file) as its
    resources/weights.bin: a retrained network needs no recompilation."""
    data = encode_weights(weights) if isinstance(weights, Weights) else Path(weights).read_bytes()
    decode_weights(data, str(weights) if not isinstance(weights, Weights) else "weights")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=out.parent, suffix=".fmu", delete=False) as tmp:
        tmp_path = Path(tmp.name)
    try:
        with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(tmp_path, "w", zipfile.ZIP_DEFLATED) as dst:
            for item in src.infolist():
                if item.filename != "resources/weights.bin":
                    dst.writestr(item, src.read(item.filename))
            dst.writestr("resources/weights.bin", data)
        shutil.move(tmp_path, out)
    finally:
        tmp_path.unlink(missing_ok=True)
    return out


# ---- inference: the operations and order of fmus/forcenet/forcenet.c ----

def _dense(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> np.ndarray:
    """y = b + sum_i x[:, i] * W[:, i], accumulated over i in order (as the C loop does)."""
    y = np.repeat(b[None, :], x.shape[0], axis=0)
    for i in range(x.shape[1]):
        y += x[:, i:i + 1] * w[None, :, i]
    return y


def network(weights: Weights, features: np.ndarray) -> np.ndarray:
    """Element loads (elements x 3, tangential/radial/axial, N/m) from the features (elements x 7)."""
    x = np.asarray(features, dtype=float).reshape(-1, N_FEATURES)
    layers = weights.layers
    a = _dense(x, *layers[0])
    a = a * a * a
    a = np.maximum(_dense(a, *layers[1]), 0.0)
    for block in range(weights.blocks):
        t = np.maximum(_dense(a, *layers[2 + 2 * block]), 0.0)
        a = np.maximum(a + _dense(t, *layers[3 + 2 * block]), 0.0)
    return _dense(a, *layers[-1]) * weights.load_ref


@dataclass(frozen=True)
class Elements:
    """The edge elements in contact at one tool angle, in the order (flute, height)."""

    features: np.ndarray   # n x 7
    sin_phi: np.ndarray    # n (machine-frame immersion angle phi)
    cos_phi: np.ndarray
    z: np.ndarray          # n, height above the tip [m]
    h: np.ndarray          # n, chip thickness [m]
    dz: float
    radius: np.ndarray     # n, the radius of the element's flute (R + runout) [m]


def _in_material(engagement: np.ndarray | None, k: int, theta: float, in_window: bool) -> bool:
    """Edge element k (of any flute) at feed-frame angle theta in material: the map cell holding it (row
    k * MAP_ROWS // H, column floor(theta / 15 deg)) when given (>= 0; in material from 0.5 on), else the
    window (fmus/forcenet/forcenet.c in_material)."""
    if engagement is not None:
        row = k * MAP_ROWS // ELEMENTS_PER_FLUTE
        column = min(int(theta * (MAP_COLUMNS / TWO_PI)), MAP_COLUMNS - 1)
        value = float(engagement[row * MAP_COLUMNS + column])
        if value >= 0.0:
            return value >= 0.5
    return in_window


def engagement_of(values: Mapping[str, object]) -> np.ndarray | None:
    """The engagement map of ``values`` flattened row-major (None when not given)."""
    if values.get("engagement") is None:
        return None
    flat = np.asarray(values["engagement"], dtype=float).reshape(-1)
    if flat.size != MAP_ROWS * MAP_COLUMNS:
        raise ValueError(f"engagement: {flat.size} values, the map has {MAP_ROWS} x {MAP_COLUMNS}")
    return flat


def elements(values: Mapping[str, float], angle: float, weights: Weights | None = None,
             delayed: tuple[float, float] = (0.0, 0.0)) -> Elements:
    """The elements in contact, with the scalar libm functions (math) the C code calls, in its order: the
    sines and cosines of the helix lags per height and of each flute's angle, the elements' angles by the
    addition theorems. ``delayed``: the displacement one tooth period ago (the regenerative chip takes the
    displacement now minus it); no displacement inputs in ``values`` count as 0."""
    w = weights or default_weights()
    n = int(values["n_flutes"])
    omega = float(values["spindle_speed"])
    vx, vy = float(values["feed_velocity_x"]), float(values["feed_velocity_y"])
    radius = float(values["tool_diameter"]) / 2
    dz = float(values["axial_depth"]) / ELEMENTS_PER_FLUTE
    dx = float(values.get("displacement_x", 0.0)) - delayed[0]
    dy = float(values.get("displacement_y", 0.0)) - delayed[1]
    offset, direction = float(values.get("runout_offset", 0.0)), float(values.get("runout_angle", 0.0))
    engagement = engagement_of(values)
    rows: list[list[float]] = []
    trig: list[tuple[float, float, float, float, float]] = []
    if omega >= OMEGA_MIN and dz > 0.0:
        period = TWO_PI / (n * omega)
        feed_angle = math.atan2(vy, vx)
        sin_feed, cos_feed = math.sin(feed_angle), math.cos(feed_angle)
        lag_per_height = math.tan(float(values["helix_angle"])) / radius
        entry = float(values["entry_angle"])
        width = _wrap_scalar(float(values["exit_angle"]) - entry)
        pitch = TWO_PI / n
        v_feature = omega * radius / w.v_ref
        theta0_feature = angle / math.pi - 1.0
        z = [(k + 0.5) * dz for k in range(ELEMENTS_PER_FLUTE)]
        psi = [zk * lag_per_height for zk in z]
        sin_psi, cos_psi = [math.sin(p) for p in psi], [math.cos(p) for p in psi]
        for m in range(n):
            flute = angle + m * pitch
            sin_flute, cos_flute = math.sin(flute), math.cos(flute)
            # runout[back - 1] = r_m - r_(m-back) (CuttingForce's runout chip, models.cutting_force._runout_chip)
            runout, flute_radius = [0.0] * n, radius
            if offset != 0.0:
                own = math.cos(direction - m * pitch)
                runout = [offset * (own - math.cos(direction - (m - back) * pitch)) for back in range(1, n + 1)]
                flute_radius = radius + offset * own
            for k in range(ELEMENTS_PER_FLUTE):
                phi = flute - psi[k]
                s = sin_flute * cos_psi[k] - cos_flute * sin_psi[k]
                c = cos_flute * cos_psi[k] + sin_flute * sin_psi[k]
                static = period * (vx * s + vy * c)
                chip = static + runout[0]
                for back in range(2, n + 1):
                    chip = min(chip, back * static + runout[back - 1])
                h = chip + dx * s + dy * c
                if not (h > 0.0 and _in_material(engagement, k, _wrap_scalar(phi + feed_angle),
                                                 _wrap_scalar(phi + feed_angle - entry) < width)):
                    continue
                rows.append([h / w.h_ref, v_feature, theta0_feature, s * cos_feed + c * sin_feed,
                             c * cos_feed - s * sin_feed, sin_psi[k], cos_psi[k]])
                trig.append((s, c, z[k], h, flute_radius))
    t = np.array(trig, dtype=float).reshape(-1, 5)
    return Elements(np.array(rows, dtype=float).reshape(-1, N_FEATURES), t[:, 0], t[:, 1], t[:, 2], t[:, 3], dz,
                    t[:, 4])


def _wrap_scalar(a: float) -> float:
    return a - TWO_PI * math.floor(a / TWO_PI)


def tool_outputs(values: Mapping[str, float], angle: float, weights: Weights | None = None,
                 delayed: tuple[float, float] = (0.0, 0.0)) -> dict[str, float]:
    """The native outputs (NATIVE_OUTPUTS) at spindle angle ``angle``: element loads summed in the C order
    (``delayed``: the displacement one tooth period ago, see :func:`elements`)."""
    w = weights or default_weights()
    e = elements(values, angle, w, delayed)
    out = dict.fromkeys(NATIVE_OUTPUTS, 0.0)
    if len(e.features) == 0:
        return out
    loads = network(w, e.features)
    zp = float(values.get("moment_height", 0.0))
    fx = fy = fz = torque = mx = my = mz = 0.0
    for i in range(len(loads)):
        ft, fr, fa = loads[i, 0] * e.dz, loads[i, 1] * e.dz, loads[i, 2] * e.dz
        s, c, r = e.sin_phi[i], e.cos_phi[i], e.radius[i]
        dfx = -ft * c - fr * s
        dfy = ft * s - fr * c
        px, py, pz = r * s, r * c, e.z[i] - zp
        fx += dfx
        fy += dfy
        fz += fa
        torque += ft * r
        mx += py * fa - pz * dfy
        my += pz * dfx - px * fa
        mz += px * dfy - py * dfx
    out.update(Fx=fx, Fy=fy, Fz=fz, torque=torque, Mx=mx, My=my, Mz=mz,
               power=torque * float(values["spindle_speed"]))
    return out


def geometry_image(values: Mapping[str, float], angle: float, columns: int = 72) -> dict[str, np.ndarray]:
    """The cutting-geometry image and position encoding on an ELEMENTS_PER_FLUTE x ``columns`` grid over
    the envelope (row k at height z_k, column j at the feed-frame angle (j + 1/2) 2 pi / columns): chip
    thickness ``h`` [m], cutting speed ``v`` [m/s], tool angle ``theta0`` [rad], and M1..M4 with the axial
    angle psi of flute 0's edge at that height. For illustration; the network reads the same field at the
    elements' positions (:func:`elements`)."""
    theta = (np.arange(columns) + 0.5) * TWO_PI / columns
    radius = float(values["tool_diameter"]) / 2
    omega = float(values["spindle_speed"])
    n = int(values["n_flutes"])
    z = (np.arange(ELEMENTS_PER_FLUTE) + 0.5) * float(values["axial_depth"]) / ELEMENTS_PER_FLUTE
    psi = z * math.tan(float(values["helix_angle"])) / radius
    feed = math.hypot(float(values["feed_velocity_x"]), float(values["feed_velocity_y"]))
    ft = feed * TWO_PI / (n * max(omega, OMEGA_MIN)) if omega >= OMEGA_MIN else 0.0
    entry = float(values["entry_angle"])
    width = _wrap_scalar(float(values["exit_angle"]) - entry)
    engaged = np.mod(theta - entry, TWO_PI) < width
    h = np.where(engaged, ft * np.sin(theta), 0.0)
    h = np.repeat(np.maximum(h, 0.0)[None, :], ELEMENTS_PER_FLUTE, axis=0)
    shape = h.shape
    return {"h": h, "v": np.full(shape, omega * radius), "theta0": np.full(shape, angle),
            "M1": np.repeat(np.sin(theta)[None, :], ELEMENTS_PER_FLUTE, 0),
            "M2": np.repeat(np.cos(theta)[None, :], ELEMENTS_PER_FLUTE, 0),
            "M3": np.repeat(np.sin(psi)[:, None], columns, 1), "M4": np.repeat(np.cos(psi)[:, None], columns, 1)}


# The sampled cutting conditions (the network's domain): uniform unless "log" (log-uniform).
DOMAIN = {
    "n_flutes": (1, 6),                 # integer, uniform
    "tool_diameter": (3e-3, 32e-3),     # m, log
    "helix_angle": (0.0, math.radians(50)),
    "feed_per_tooth": (0.01e-3, 0.3e-3),  # m, log
    "axial_depth": (0.1, 1.5),          # times the tool diameter, at most 30 mm
    "spindle_rpm": (1000.0, 24000.0),   # log
    "radial_immersion": (0.05, 1.0),    # a_e / D of up- and down-milling (a third each; a third slotting)
}



# ---- training and test data: cutting conditions and geometry (vectorized numpy, the formulas of elements) ----

def sample_conditions(count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    d = DOMAIN
    log = lambda lo, hi: np.exp(rng.uniform(math.log(lo), math.log(hi), count))  # noqa: E731
    c = {"n_flutes": rng.integers(d["n_flutes"][0], d["n_flutes"][1] + 1, count).astype(float),
         "tool_diameter": log(*d["tool_diameter"]),
         "helix_angle": rng.uniform(*d["helix_angle"], count),
         "feed_per_tooth": log(*d["feed_per_tooth"])}
    c["axial_depth"] = np.minimum(rng.uniform(*d["axial_depth"], count) * c["tool_diameter"], 0.03)
    rpm = log(*d["spindle_rpm"])
    c["spindle_speed"] = rpm * TWO_PI / 60
    direction = rng.uniform(0.0, TWO_PI, count)
    feed = c["feed_per_tooth"] * c["n_flutes"] * rpm / 60
    c["feed_velocity_x"], c["feed_velocity_y"] = feed * np.cos(direction), feed * np.sin(direction)
    kind = rng.integers(0, 3, count)  # 0 slot, 1 down-milling, 2 up-milling
    alpha = np.arccos(1.0 - 2.0 * rng.uniform(*d["radial_immersion"], count))
    c["entry_angle"] = np.where(kind == 1, math.pi - alpha, 0.0)
    c["exit_angle"] = np.where(kind == 2, alpha, math.pi)
    return c


def repeat_angles(conditions: dict[str, np.ndarray], angles: int, rng: np.random.Generator
                  ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Samples: each condition at ``angles`` random tool angles. Returns (values per sample, angle per
    sample, condition index per sample)."""
    count = len(conditions["n_flutes"])
    index = np.repeat(np.arange(count), angles)
    return ({k: v[index] for k, v in conditions.items()}, rng.uniform(0.0, TWO_PI, len(index)), index)


def element_arrays(values: dict[str, np.ndarray], angle: np.ndarray, weights: Weights | None = None) -> dict:
    """Per sample and element slot (S x MAX_FLUTES*H): contact mask, the 7 features, sin/cos(phi), z, dz, R
    and the chip h, with the formulas of models.force_net.elements (numpy's vectorized trig)."""
    h_ref, v_ref = (weights.h_ref, weights.v_ref) if weights else (H_REF, V_REF)
    n = values["n_flutes"][:, None, None]
    omega = values["spindle_speed"][:, None, None]
    vx, vy = values["feed_velocity_x"][:, None, None], values["feed_velocity_y"][:, None, None]
    radius = values["tool_diameter"][:, None, None] / 2
    dz = values["axial_depth"][:, None, None] / ELEMENTS_PER_FLUTE
    period = TWO_PI / (n * omega)
    feed_angle = np.arctan2(vy, vx)
    lag = np.tan(values["helix_angle"])[:, None, None] / radius
    entry = values["entry_angle"][:, None, None]
    width = np.mod(values["exit_angle"][:, None, None] - entry, TWO_PI)
    m = np.arange(MAX_FLUTES)[None, :, None]
    z = (np.arange(ELEMENTS_PER_FLUTE)[None, None, :] + 0.5) * dz
    psi = z * lag
    phi = angle[:, None, None] + m * (TWO_PI / n) - psi
    s, c = np.sin(phi), np.cos(phi)
    h = period * (vx * s + vy * c)
    theta = np.mod(phi + feed_angle, TWO_PI)
    mask = (m < n) & (np.mod(phi + feed_angle - entry, TWO_PI) < width) & (h > 0) & (omega >= 1.0)
    shape = mask.shape
    features = np.stack([h / h_ref, np.broadcast_to(omega * radius / v_ref, shape),
                         np.broadcast_to(angle[:, None, None] / math.pi - 1.0, shape),
                         np.sin(theta), np.cos(theta), np.broadcast_to(np.sin(psi), shape),
                         np.broadcast_to(np.cos(psi), shape)], axis=-1)
    flat = lambda a: np.broadcast_to(a, shape).reshape(len(angle), -1)  # noqa: E731
    return {"mask": flat(mask), "features": features.reshape(len(angle), -1, N_FEATURES),
            "sin": flat(s), "cos": flat(c), "z": flat(z), "dz": flat(dz), "radius": flat(radius), "h": flat(h)}


def mechanistic_forces(values: dict[str, np.ndarray], angle: np.ndarray,
                       coefficients: dict[str, float] | None = None) -> np.ndarray:
    """Fx, Fy, Fz (S x 3) of the mechanistic model (CuttingForce's generated equations)."""
    out = CUTTING_FORCE.evaluate(**{k: values[k] for k in ("n_flutes", "tool_diameter", "helix_angle",
                                                            "spindle_speed", "feed_velocity_x", "feed_velocity_y",
                                                            "axial_depth", "entry_angle", "exit_angle")},
                                 **(coefficients or AL7075_CARBIDE), angle=angle, delayed_displacement_x=0.0,
                                 delayed_displacement_y=0.0)
    return np.column_stack([out["Fx"], out["Fy"], out["Fz"]])


def projection(arrays: dict) -> np.ndarray:
    """... x 3 x 3 matrices taking an element's load per length (t, r, a) to its force on the tool."""
    s, c, dz = arrays["sin"], arrays["cos"], arrays["dz"]
    zero = np.zeros_like(s)
    rows = [np.stack([-c, -s, zero], -1), np.stack([s, -c, zero], -1), np.stack([zero, zero, np.ones_like(s)], -1)]
    return np.stack(rows, -2) * dz[..., None, None]



# ---- what the generic FMU tests (tests/fmu_helpers.py) use for this model ----

def _all_outputs(values: Mapping[str, float], angle: float, weights: Weights | None = None,
                 delayed: tuple[float, float] = (0.0, 0.0)) -> list[float]:
    native = tool_outputs(values, angle, weights, delayed)
    generated = FORCE_NET.evaluate(**{k: v for k, v in values.items() if k in _ARGUMENTS}, angle=angle,
                                   delayed_displacement_x=delayed[0], delayed_displacement_y=delayed[1])
    return [native[n] if n in native else float(generated[n]) for n in OUTPUTS]


_ARGUMENTS = {v.name for v in FORCE_NET.arguments if isinstance(v, Variable)}  # not the map (C reads it)


class ForceNetReference:
    """The FMU step by step: the displacement history of CuttingForce (:class:`DisplacementHistory`), the
    spindle angle advanced by the generated update, the outputs at the angle reached (:func:`tool_outputs`);
    both advance by the FMU's step clock (:class:`StepClock`), ``time`` is the importer's."""

    def __init__(self, values: Mapping[str, float], weights: Weights | None = None, start_time: float = 0.0):
        self.names = {v.name for v in FORCE_NET.of("parameter") + FORCE_NET.of("input")}
        self.values = {k: x for k, x in {**FORCE_NET.defaults(), **values}.items() if k in self.names}
        self.angle = 0.0
        self.start_time = self.time = start_time
        self.clock = StepClock()
        self.history = DisplacementHistory(int(self.values["history_size"]))
        self.weights = weights

    def set(self, values: Mapping[str, float]) -> None:
        self.values.update({k: x for k, x in values.items() if k in self.names})

    def clock_time(self) -> float:
        return self.start_time + self.clock.seconds()

    def delayed(self) -> tuple[float, float]:
        return self.history.delayed(self.clock_time(), history_period(self.values), self.values["displacement_x"],
                                    self.values["displacement_y"])

    def outputs(self) -> np.ndarray:
        return np.array(_all_outputs(self.values, self.angle, self.weights, self.delayed()))

    def step(self, h: float) -> np.ndarray:
        v = self.values
        start = self.clock_time()
        taken = self.clock.advance(self.time, h)
        self.history.record(start, taken, v["displacement_x"], v["displacement_y"], history_period(v),
                            v["spindle_speed"] >= OMEGA_MIN and v["axial_depth"] > 0)
        scalars = {k: x for k, x in v.items() if k in _ARGUMENTS}
        self.angle = float(FORCE_NET.step(taken, **scalars, angle=self.angle, delayed_displacement_x=0.0,
                                          delayed_displacement_y=0.0)["angle"])
        self.time = self.time + h
        return self.outputs()


def reference_trajectory(points: Sequence[Mapping[str, float]], step_size: float) -> np.ndarray:
    reference = ForceNetReference(points[0])
    rows = []
    for point in points:
        reference.set(point)
        rows.append(reference.step(step_size))
    return np.array(rows)


def initial_outputs(values: Mapping[str, float | np.ndarray]) -> np.ndarray:
    """Outputs in initialization mode (points x outputs): at the start angle 0, no history yet (the delayed
    displacement is the current one: no regeneration)."""
    columns = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in values.items()}
    count = max([len(c) for c in columns.values()] + [1])
    rows = []
    for i in range(count):
        point = {**FORCE_NET.defaults(), **{k: float(c[min(i, len(c) - 1)]) for k, c in columns.items()}}
        rows.append(_all_outputs(point, 0.0, delayed=(point["displacement_x"], point["displacement_y"])))
    return np.array(rows)


def random_arguments(count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Valid operating points inside the training domain: a random tool (fixed), random feeds, depths,
    engagement windows and spindle speeds; the first row is slotting, the eighth a stopped spindle."""
    values: dict[str, np.ndarray] = {
        "tool_diameter": np.full(count, rng.uniform(0.006, 0.025)),
        "helix_angle": np.full(count, rng.uniform(0.0, math.radians(45))),
        "n_flutes": np.full(count, float(rng.integers(2, 5))),
        "moment_height": rng.uniform(-0.01, 0.03, count),
    }
    rpm = rng.uniform(2000, 15000, count)
    values["spindle_speed"] = rpm * TWO_PI / 60
    ft = rng.uniform(0.02e-3, 0.2e-3, count)
    direction = rng.uniform(0, TWO_PI, count)
    feed = ft * values["n_flutes"] * rpm / 60
    values["feed_velocity_x"] = feed * np.cos(direction)
    values["feed_velocity_y"] = feed * np.sin(direction)
    values["axial_depth"] = rng.uniform(0.2, 1.0, count) * values["tool_diameter"]
    entry = rng.uniform(0.0, 0.5 * math.pi, count)
    values["entry_angle"] = np.where(rng.random(count) < 0.5, 0.0, entry)
    values["exit_angle"] = np.where(rng.random(count) < 0.5, math.pi, rng.uniform(values["entry_angle"] + 0.3, math.pi))
    values["entry_angle"][0], values["exit_angle"][0] = 0.0, math.pi
    values["history_size"] = np.full(count, 16384.0)
    values["runout_offset"] = np.full(count, rng.uniform(0.0, 20e-6))  # a few um, like a real tool holder
    values["runout_angle"] = np.full(count, rng.uniform(0.0, TWO_PI))
    values["displacement_x"] = rng.uniform(-20e-6, 20e-6, count)  # a vibrating tool: the regenerative chip
    values["displacement_y"] = rng.uniform(-20e-6, 20e-6, count)
    if count > 7:  # a stopped spindle (no forces, a warning) late enough to follow the FMU-state tests' snapshot
        values["spindle_speed"][7] = 0.0
    return values

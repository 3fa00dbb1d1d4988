"""The force net (models/force_net.py, fmus/forcenet/) without torch: the weights file and its checks, the
FMU's loading at instantiation from FMI 2 URIs and FMI 3 paths (and the failures), a retrained network
installed without recompiling, the committed network against the mechanistic model on held-out conditions,
moments, the one-line scenario swap and the slot-milling validation on synthetic recordings (and on the
measured ones when present). The generic FMU tests (tests/test_fmu_*.py) hold the FMU to the numpy
reference to 1e-12; tests/test_forcenet_train.py covers training, export and C against torch."""
from __future__ import annotations

import ctypes
import math
import re
import shutil
import struct
import subprocess
import tomllib
import zipfile
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pytest
from fmpy.fmi2 import fmi2CoSimulation, fmi2False
from fmpy.fmi3 import fmi3False, fmi3InstanceEnvironment, fmi3IntermediateUpdateCallback, fmi3LogMessageCallback

from fmu_helpers import OK, Slave, assert_close, fmi2_callbacks, fmi3_logger, fmu_dir, generated_dir, require_fmu
from milling_twin import datasets
from milling_twin.models import force_net as fn
from milling_twin.models.cutting_force import AL7075_CARBIDE, CUTTING_FORCE

SLOT = {"n_flutes": 2, "tool_diameter": 0.025, "helix_angle": math.radians(30), "moment_height": 0.0,
        "spindle_speed": 6000 * 2 * math.pi / 60, "feed_velocity_x": 0.015, "feed_velocity_y": 0.0,
        "axial_depth": 0.003, "entry_angle": 0.0, "exit_angle": math.pi}
STEP = 1e-5


def fmu_path(version: int) -> Path:
    return require_fmu(fmu_dir() / ("ForceNet.fmu" if version == 3 else "ForceNet_fmi2.fmu"))


def unpack(version: int, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(fmu_path(version)) as z:
        z.extractall(folder)
    return folder


def expected_after_steps(values: dict, steps: int) -> np.ndarray:
    return fn.reference_trajectory([values] * steps, STEP)[-1]


def run_slot(slave: Slave, steps: int = 3) -> np.ndarray:
    slave.initialize({k: v for k, v in SLOT.items()})
    for _ in range(steps):
        assert slave.step(STEP) == OK
    return slave.get(list(fn.OUTPUTS))


# ---- the weights file ----


def test_the_committed_weights_and_their_builtin_copy_agree() -> None:
    data = fn.WEIGHTS_FILE.read_bytes()
    weights = fn.decode_weights(data)
    assert (weights.kernel, weights.width, weights.blocks) == tuple(fn.DEFAULT_SIZES.values())
    assert fn.encode_weights(weights) == data  # the format round-trips exactly
    assert fn.DEFAULT_WEIGHTS_HEADER.read_text() == fn.weights_header(data), \
        "fmus/forcenet/default_weights.h is stale: milling-twin train forcenet --header-only"


def _patched(data: bytes, offset: int, value: int, fix_checksum: bool) -> bytes:
    out = bytearray(data)
    out[offset:offset + 4] = struct.pack("<I", value)
    if fix_checksum:
        out[-8:] = struct.pack("<Q", fn._fnv1a64(bytes(out[:-8])))
    return bytes(out)


def _patched_double(data: bytes, offset: int, value: float) -> bytes:
    """A float64 replaced and the checksum made valid again: only the value checks can catch it."""
    out = bytearray(data)
    out[offset:offset + 8] = struct.pack("<d", value)
    out[-8:] = struct.pack("<Q", fn._fnv1a64(bytes(out[:-8])))
    return bytes(out)


LAYER1_ROWS = 56 + 8 + 8 * (16 * 7 + 16)  # offset of the row count of layer 1 (after the header and layer 0)
BAD_FILES = {  # name -> (bytes from the committed file, expected message)
    "missing": (None, "cannot open"),
    "empty": (lambda d: b"", "truncated: 0 bytes"),
    "truncated": (lambda d: d[:1000], "truncated: 1000 bytes, the header (K = 16, W = 32, B = 2) needs 40080"),
    "trailing": (lambda d: d + b"\0" * 8, "trailing data: 40088 bytes"),
    "inputs": (lambda d: _patched(d, 12, 8, False), "shape mismatch: the network has 8 inputs and 3 outputs, the "
                                                    "model needs 7 and 3"),
    "layer shape": (lambda d: _patched(d, LAYER1_ROWS, 31, True), "shape mismatch: layer 1 is 31 x 16, expected "
                                                                  "32 x 16"),
    "corrupted": (lambda d: d[:500] + bytes([d[500] ^ 1]) + d[501:], "checksum mismatch"),
    "magic": (lambda d: b"FORCENEX" + d[8:], "not a force-net weights file"),
    "nan weight": (lambda d: _patched_double(d, 56 + 8, math.nan), "layer 0 holds non-finite values"),
    "inf bias": (lambda d: _patched_double(d, 56 + 8 + 8 * 16 * 7, math.inf), "layer 0 holds non-finite values"),
    "zero scale": (lambda d: _patched_double(d, 32, 0.0), "scales h_ref, v_ref, load_ref must be positive and finite"),
}


@pytest.mark.parametrize("case", [c for c in BAD_FILES if c != "missing"])
def test_the_python_reader_rejects_bad_files(case: str) -> None:
    make, message = BAD_FILES[case]
    with pytest.raises(fn.WeightsError, match=message.replace("(", r"\(").replace(")", r"\)")):
        fn.decode_weights(make(fn.WEIGHTS_FILE.read_bytes()))


@pytest.mark.parametrize("version", [3, 2])
@pytest.mark.parametrize("case", list(BAD_FILES))
def test_a_bad_weights_file_fails_instantiation_with_the_reason(version: int, case: str, tmp_path: Path) -> None:
    folder = unpack(version, tmp_path / "fmu")
    weights = folder / "resources" / "weights.bin"
    make, message = BAD_FILES[case]
    if make is None:
        weights.unlink()
    else:
        weights.write_bytes(make(weights.read_bytes()))
    with Slave(fmu_path(version), unzipdir=str(folder)) as slave:
        with pytest.raises(Exception, match="Failed to instantiate"):
            slave.instantiate()
        instantiate = "fmi3InstantiateCoSimulation" if version == 3 else "fmi2Instantiate"
        error = slave.last_error()
        assert error.startswith(f"{instantiate}: ") and message in error and str(weights) in error, error


@pytest.mark.parametrize("version", [3, 2])
def test_reset_reloads_the_weights(version: int, tmp_path: Path) -> None:
    folder = unpack(version, tmp_path / "fmu")
    with Slave(fmu_path(version), unzipdir=str(folder)) as slave:
        slave.instantiate()
        first = run_slot(slave)
        slave.fmu.reset()
        assert_close(run_slot(slave), first, rtol=0)
        (folder / "resources" / "weights.bin").unlink()
        with pytest.raises(Exception):
            slave.fmu.reset()
        assert "Reset: the force-net weights file cannot be read: cannot open" in slave.last_error()


# ---- resource locations ----

ODD_NAME = "dir with space %41 #x"  # a literal "%41" must not be decoded in an FMI 3 path


def _instantiate_fmi2(slave: Slave, location: str):
    slave._callbacks = fmi2_callbacks(slave.messages)
    component = slave.fmu.fmi2Instantiate(b"located", fmi2CoSimulation, slave.md.guid.encode(), location.encode(),
                                          ctypes.byref(slave._callbacks), fmi2False, fmi2False)
    slave.fmu.component = component
    return component


def _instantiate_fmi3(slave: Slave, location: str):
    slave.fmu.logMessage = fmi3LogMessageCallback(fmi3_logger(slave.messages))
    slave.fmu.intermediateUpdate = fmi3IntermediateUpdateCallback()
    component = slave.fmu.fmi3InstantiateCoSimulation(
        b"located", slave.md.guid.encode(), location.encode(), fmi3False, fmi3False, fmi3False, fmi3False, None, 0,
        fmi3InstanceEnvironment(), slave.fmu.logMessage, slave.fmu.intermediateUpdate)
    slave.fmu.component = component
    return component


def test_fmi2_resource_uris(tmp_path: Path) -> None:
    folder = unpack(2, tmp_path / ODD_NAME / "fmu")
    resources = folder / "resources"
    quoted = quote(str(resources))
    assert "%2541" in quoted and "%20" in quoted and "%23" in quoted
    expected = expected_after_steps(SLOT, 3)
    good = [resources.as_uri(), f"file://{quoted}/", f"file:{quoted}", f"file://localhost{quoted}",
            "file://" + re.sub("%[0-9A-F]{2}", lambda m: m.group(0).lower(), quoted)]  # lower-case escapes
    for location in good:
        with Slave(fmu_path(2), unzipdir=str(folder)) as slave:
            assert _instantiate_fmi2(slave, location), f"{location}: {slave.messages}"
            assert_close(run_slot(slave), expected, what=location)
    bad = {"file://server/share/resources": "is not a local file URI",
           f"file://{quoted}%zz": "has a bad percent-escape",
           f"file://{quote(str(tmp_path))}/": "cannot open"}
    for location, message in bad.items():
        with Slave(fmu_path(2), unzipdir=str(folder)) as slave:
            assert not _instantiate_fmi2(slave, location)
            assert message in slave.last_error(), (location, slave.messages)


def test_fmi3_resource_paths(tmp_path: Path) -> None:
    folder = unpack(3, tmp_path / ODD_NAME / "fmu")
    resources = folder / "resources"
    expected = expected_after_steps(SLOT, 3)
    for location in (f"{resources}/", str(resources)):
        with Slave(fmu_path(3), unzipdir=str(folder)) as slave:
            assert _instantiate_fmi3(slave, location), f"{location}: {slave.messages}"
            assert_close(run_slot(slave), expected, what=location)
    with Slave(fmu_path(3), unzipdir=str(folder)) as slave:  # a path is not a URI: "%41" stays
        assert not _instantiate_fmi3(slave, str(resources).replace("%41", "A"))
        assert "cannot open" in slave.last_error()


@pytest.mark.parametrize("version", [3, 2])
def test_without_a_resource_location_the_builtin_network_is_used(version: int, tmp_path: Path) -> None:
    folder = unpack(version, tmp_path / "fmu")
    shutil.rmtree(folder / "resources")
    with Slave(fmu_path(version), unzipdir=str(folder)) as slave:
        instantiate = _instantiate_fmi3 if version == 3 else _instantiate_fmi2
        assert instantiate(slave, "")
        assert_close(run_slot(slave), expected_after_steps(SLOT, 3))


def test_a_retrained_network_needs_no_recompilation(tmp_path: Path) -> None:
    weights = fn.default_weights()
    w, b = weights.layers[-1]
    doubled = fn.Weights(weights.layers[:-1] + ((2 * w, 2 * b),), weights.h_ref, weights.v_ref, weights.load_ref)
    for version in (3, 2):
        copy = fn.install_weights(fmu_path(version), doubled, tmp_path / fmu_path(version).name)
        with zipfile.ZipFile(copy) as z, zipfile.ZipFile(fmu_path(version)) as original:
            assert z.read("resources/weights.bin") == fn.encode_weights(doubled)
            assert z.read(f"binaries/{'x86_64-linux' if version == 3 else 'linux64'}/ForceNet.so") == \
                original.read(f"binaries/{'x86_64-linux' if version == 3 else 'linux64'}/ForceNet.so")
        with Slave(fmu_path(version)) as slave, Slave(copy) as retrained:
            slave.instantiate()
            retrained.instantiate()
            base, twice = run_slot(slave), run_slot(retrained)
        forces = [fn.OUTPUTS.index(n) for n in ("Fx", "Fy", "Fz", "torque", "Mx", "My", "Mz")]
        assert np.abs(base[forces]).max() > 10
        assert_close(twice[forces], 2 * base[forces], rtol=1e-12)


# ---- the committed network ----


def test_the_committed_network_matches_the_mechanistic_model_on_held_out_conditions() -> None:
    """Conditions drawn with a seed the training never used (numpy inference, no torch): R^2 >= 0.99 per axis,
    pooled and with every sample relative to its condition's RMS force."""
    rng = np.random.default_rng(987654321)
    conditions = fn.sample_conditions(120, rng)
    values, angle, index = fn.repeat_angles(conditions, 12, rng)
    arrays = fn.element_arrays(values, angle)
    weights = fn.default_weights()
    mask = arrays["mask"]
    loads = fn.network(weights, arrays["features"][mask])
    forces = np.einsum("nij,nj->ni", fn.projection({k: arrays[k][mask] for k in ("sin", "cos", "dz")}), loads)
    predicted = np.zeros((len(angle), 3))
    np.add.at(predicted, np.nonzero(mask)[0], forces)
    truth = fn.mechanistic_forces(values, angle)
    rms = np.sqrt(np.bincount(index, np.sum(truth ** 2, axis=1)) / np.bincount(index) / 3)[index][:, None]

    def r2(p, t):
        return 1 - np.sum((p - t) ** 2, axis=0) / np.sum((t - t.mean(axis=0)) ** 2, axis=0)

    assert np.all(r2(predicted, truth) >= 0.99), r2(predicted, truth)
    assert np.all(r2(predicted / rms, truth / rms) >= 0.99), r2(predicted / rms, truth / rms)


def test_element_geometry_vectorized_equals_the_fmu_order() -> None:
    rng = np.random.default_rng(5)
    values, angle, _ = fn.repeat_angles(fn.sample_conditions(20, rng), 3, rng)
    arrays = fn.element_arrays(values, angle)
    for s in range(len(angle)):
        e = fn.elements({k: values[k][s] for k in values}, angle[s])
        mask = arrays["mask"][s]
        assert mask.sum() == len(e.features)
        if len(e.features):
            assert_close(arrays["features"][s][mask], e.features, rtol=1e-12)


def test_mechanistic_training_targets_are_the_sum_of_the_element_loads() -> None:
    """The element geometry the network sees is the mechanistic model's: its element loads, projected and
    summed over the same elements, give CuttingForce's forces."""
    rng = np.random.default_rng(11)
    values, angle, _ = fn.repeat_angles(fn.sample_conditions(30, rng), 4, rng)
    arrays = fn.element_arrays(values, angle)
    k = AL7075_CARBIDE
    h = arrays["h"]
    loads = np.stack([k["Ktc"] * h + k["Kte"], k["Krc"] * h + k["Kre"], k["Kac"] * h + k["Kae"]], -1)
    loads = np.where(arrays["mask"][..., None], loads, 0.0)
    forces = np.einsum("snij,snj->si", fn.projection(arrays), loads)
    assert_close(forces, fn.mechanistic_forces(values, angle), rtol=1e-9)


def test_moments() -> None:
    """Mz is the torque; about a point z' up the axis, M = M(0) - z' (z x F)."""
    at_tip = fn.tool_outputs(SLOT, 1.0)
    up = fn.tool_outputs({**SLOT, "moment_height": 0.02}, 1.0)
    assert at_tip["Mz"] == pytest.approx(at_tip["torque"], rel=1e-12)
    assert up["Mx"] == pytest.approx(at_tip["Mx"] + 0.02 * at_tip["Fy"], rel=1e-9)
    assert up["My"] == pytest.approx(at_tip["My"] - 0.02 * at_tip["Fx"], rel=1e-9)
    assert abs(at_tip["Mx"]) > 1e-3 and abs(at_tip["My"]) > 1e-3
    stopped = fn.tool_outputs({**SLOT, "spindle_speed": 0.0}, 1.0)
    assert all(v == 0.0 for v in stopped.values())


def test_geometry_image_shows_the_chip_in_the_window() -> None:
    image = fn.geometry_image({**SLOT, "entry_angle": math.pi / 2}, 0.3, columns=24)
    assert image["h"].shape == (fn.ELEMENTS_PER_FLUTE, 24)
    theta = (np.arange(24) + 0.5) * 2 * math.pi / 24
    ft = 0.015 * 2 * math.pi / (2 * SLOT["spindle_speed"])
    inside = (theta >= math.pi / 2) & (theta < math.pi)
    assert np.allclose(image["h"][3], np.where(inside, ft * np.sin(theta), 0.0))
    assert np.allclose(image["v"], SLOT["spindle_speed"] * 0.0125)


# ---- the C kernels ----

C_FLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-Wconversion", "-Wno-sign-conversion"]


def _kernel_driver(tmp_path: Path, kernel: int) -> Path:
    """tools/forcenet_run.c with the network's kernel forced (1: the baseline, 2: AVX2)."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler")
    folder = REPO / "fmus" / "forcenet"
    out = tmp_path / f"forcenet_run_{kernel}"
    subprocess.run([compiler, *C_FLAGS, f"-DFORCENET_KERNEL={kernel}", "-I", str(folder), "-I", str(generated_dir()),
                    str(folder / "tools" / "forcenet_run.c"), str(folder / "forcenet.c"), "-o", str(out), "-lm"],
                   check=True)
    return out


def _loads(driver: Path, features: np.ndarray) -> np.ndarray:
    text = f"{len(features)}\n" + "\n".join(" ".join(repr(float(x)) for x in f) for f in features) + "\n"
    result = subprocess.run([str(driver), "loads", str(fn.WEIGHTS_FILE)], input=text, capture_output=True, text=True,
                            check=True)
    return np.array([[float(x) for x in line.split()] for line in result.stdout.splitlines()]).reshape(-1, 3)


def test_the_avx2_and_baseline_kernels_give_bit_identical_loads(tmp_path: Path) -> None:
    """The FMU picks the AVX2 kernel where the CPU has it, else the x86-64 baseline: same operations, same order,
    the same bits (and the numpy reference's), for batches of every size (4-row blocks and their remainders)."""
    if "avx2" not in Path("/proc/cpuinfo").read_text():
        pytest.skip("this CPU has no AVX2")
    rng = np.random.default_rng(3)
    values, angle, _ = fn.repeat_angles(fn.sample_conditions(30, rng), 4, rng)
    arrays = fn.element_arrays(values, angle)
    features = arrays["features"][arrays["mask"]][:203]
    drivers = [_kernel_driver(tmp_path, k) for k in (1, 2)]
    baseline, avx2 = (_loads(d, features) for d in drivers)
    assert np.array_equal(baseline, avx2)
    assert np.array_equal(avx2, fn.network(fn.default_weights(), features))
    for n in (1, 2, 3, 5, 7, 9):  # every remainder of the row blocks
        assert np.array_equal(_loads(drivers[1], features[:n]), baseline[:n])


# ---- the engagement map ----

MAP_SIZE = fn.MAP_ROWS * fn.MAP_COLUMNS


def slot_map() -> np.ndarray:
    """What the Workpiece FMU gives for a full slot: every height in material over the front half (columns
    0..11 = 0..180 deg), nothing behind."""
    engagement = np.zeros((fn.MAP_ROWS, fn.MAP_COLUMNS))
    engagement[:, : fn.MAP_COLUMNS // 2] = 1.0
    return engagement.reshape(-1)


def set_map(slave: Slave, engagement: np.ndarray) -> None:
    if slave.fmi_version == 3:
        slave.set_real([slave.vr["engagement"]], list(engagement))
    else:
        slave.set_real(slave.elements["engagement"], list(engagement))


def run_with_maps(version: int, values: dict, maps: list[np.ndarray | None]) -> np.ndarray:
    """One instance: initialize at ``values``, then per map (None: leave the map as it is) set it and step."""
    with Slave(fmu_path(version)) as slave:
        slave.instantiate()
        slave.initialize(values)
        rows = []
        for engagement in maps:
            if engagement is not None:
                set_map(slave, engagement)
            assert slave.step(STEP) == OK, slave.messages[-2:]
            rows.append(slave.get(list(fn.OUTPUTS)))
        return np.array(rows)


@pytest.mark.parametrize("version", [3, 2])
def test_a_slot_map_gives_exactly_the_forces_of_the_slot_window(version: int) -> None:
    """Unconnected (the start value -1 everywhere), the window entry..exit decides; the Workpiece's map of a
    slot holds the same elements, so the forces are bit-identical; a map without material gives none."""
    without = run_with_maps(version, SLOT, [None] * 40)
    assert np.count_nonzero(without[:, 0]) > 30
    assert np.array_equal(run_with_maps(version, SLOT, [slot_map()] + [None] * 39), without)
    assert np.array_equal(run_with_maps(version, SLOT, [np.full(MAP_SIZE, -1.0)] * 40), without)
    empty = run_with_maps(version, SLOT, [np.zeros(MAP_SIZE)] + [None] * 39)
    native = [fn.OUTPUTS.index(n) for n in fn.NATIVE_OUTPUTS]
    assert not np.any(empty[:, native])
    assert np.array_equal(empty[:, fn.OUTPUTS.index("spindle_angle")], without[:, fn.OUTPUTS.index("spindle_angle")])


@pytest.mark.parametrize("version", [3, 2])
def test_the_fmu_reads_the_map_as_the_reference_does(version: int) -> None:
    """Random maps (given cells 0/1 or fractions, unknown cells -1) at random operating points: the FMU equals
    the numpy reference to 1e-12, and the maps change the forces."""
    rng = np.random.default_rng(17)
    values = fn.random_arguments(12, rng)
    points = [{k: float(c[i]) for k, c in values.items()} for i in range(12)]
    points[7]["spindle_speed"] = points[6]["spindle_speed"]  # no stopped spindle here (a warning)
    maps = [rng.choice([-1.0, 0.0, 1.0, 0.3, 0.7], MAP_SIZE, p=[0.2, 0.3, 0.3, 0.1, 0.1]) for _ in points]
    with Slave(fmu_path(version)) as slave:
        slave.instantiate()
        slave.initialize(points[0])
        actual = []
        for point, engagement in zip(points, maps):
            slave.set(point, include_fixed=False)
            set_map(slave, engagement)
            assert slave.step(1e-3) == OK, slave.messages[-2:]
            actual.append(slave.get(list(fn.OUTPUTS)))
    expected = fn.reference_trajectory([{**p, "engagement": m} for p, m in zip(points, maps)], 1e-3)
    assert_close(np.array(actual), expected)
    windows = fn.reference_trajectory(points, 1e-3)
    assert np.count_nonzero(np.abs(expected[:, 0] - windows[:, 0]) > 1e-6 * np.abs(windows[:, 0]).max()) >= 6


def test_how_the_map_is_sampled_onto_the_edge_elements() -> None:
    """Map row i holds the elements k = 2i, 2i + 1 of every flute (the rows halve the 16 heights), column j the
    feed-frame angles [15 j, 15 (j + 1)) deg."""
    values = {**SLOT, "helix_angle": 0.0, "n_flutes": 4}
    everything = fn.elements(values, 0.9)
    dz = SLOT["axial_depth"] / fn.ELEMENTS_PER_FLUTE
    for row in range(fn.MAP_ROWS):
        engagement = np.zeros((fn.MAP_ROWS, fn.MAP_COLUMNS))
        engagement[row] = 1.0
        some = fn.elements({**values, "engagement": engagement}, 0.9)
        heights = sorted(set(np.round(some.z / dz - 0.5).astype(int)))
        assert heights == [2 * row, 2 * row + 1]
        assert len(some.z) == len(everything.z) * 2 // fn.ELEMENTS_PER_FLUTE
    theta = np.mod(np.arctan2(everything.features[:, 3], everything.features[:, 4]), 2 * math.pi)
    for column in range(fn.MAP_COLUMNS):
        engagement = np.zeros((fn.MAP_ROWS, fn.MAP_COLUMNS))
        engagement[:, column] = 1.0
        some = fn.elements({**values, "engagement": engagement}, 0.9)
        inside = (theta >= math.radians(15 * column) - 1e-12) & (theta < math.radians(15 * (column + 1)) + 1e-12)
        assert len(some.z) == np.count_nonzero(inside)


# ---- scenarios ----

REPO = Path(__file__).resolve().parents[1]


def test_the_forcenet_scenario_is_the_mechanistic_one_with_one_line_swapped() -> None:
    mech = tomllib.loads((REPO / "scenarios" / "slot_milling.toml").read_text())
    net = tomllib.loads((REPO / "scenarios" / "slot_milling_forcenet.toml").read_text())
    assert mech["fmus"]["force"].pop("fmu") == "CuttingForce" and net["fmus"]["force"].pop("fmu") == "ForceNet"
    for doc in (mech, net):
        doc["scenario"].pop("name"), doc["scenario"].pop("description")
    assert mech == net


def test_forcenet_and_cuttingforce_give_the_same_slot_forces(tmp_path: Path) -> None:
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.results import load_results
    from milling_twin.orchestrator.scenario import load_scenario

    results = {}
    for name in ("slot_milling", "slot_milling_forcenet"):
        scenario = load_scenario(REPO / "scenarios" / f"{name}.toml", fmu_dir())
        results[name] = load_results(run(scenario, tmp_path, progress=False).run_dir)
    mech, net = results["slot_milling"], results["slot_milling_forcenet"]
    assert np.array_equal(mech["force.spindle_angle"], net["force.spindle_angle"])
    for axis in ("Fx", "Fy", "Fz", "torque", "power"):
        m, n = mech[f"force.{axis}"].to_numpy(), net[f"force.{axis}"].to_numpy()
        r2 = 1 - np.sum((n - m) ** 2) / np.sum((m - m.mean()) ** 2)
        assert r2 > 0.99, (axis, r2)
        assert n.mean() == pytest.approx(m.mean(), rel=0.03), axis


def test_the_forcenet_chatter_scenario_is_the_mechanistic_one_without_its_coefficients() -> None:
    mech = tomllib.loads((REPO / "scenarios" / "chatter.toml").read_text())
    net = tomllib.loads((REPO / "scenarios" / "chatter_forcenet.toml").read_text())
    assert mech["fmus"]["force"].pop("fmu") == "CuttingForce" and net["fmus"]["force"].pop("fmu") == "ForceNet"
    assert [mech["fmus"]["force"]["parameters"].pop(k) for k in ("Kte", "Kre", "Kae")] == [0.0, 0.0, 0.0]
    for doc in (mech, net):
        doc["scenario"].pop("name"), doc["scenario"].pop("description")
    assert mech == net


def _chatter_runs(tmp_path: Path, depth: float) -> dict:
    """chatter_forcenet.toml and chatter.toml with CuttingForce at the literature coefficients (those the network
    learnt, edge coefficients included), both at ``depth``."""
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.results import load_results
    from milling_twin.orchestrator.scenario import load_scenario, with_values

    mech = (REPO / "scenarios" / "chatter.toml").read_text()
    for name in ("Kte", "Kre", "Kae"):
        mech = mech.replace(f"{name} = 0.0", f"{name} = {AL7075_CARBIDE[name]!r}")
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "chatter_literature.toml").write_text(mech)
    frames = {}
    for name, path in (("net", REPO / "scenarios" / "chatter_forcenet.toml"),
                       ("mech", tmp_path / "chatter_literature.toml")):
        scenario = with_values(load_scenario(path, fmu_dir()), {"force.axial_depth": depth}, name=name)
        frames[name] = load_results(run(scenario, tmp_path / "runs", progress=False).run_dir)
    return frames


def _r2(actual: np.ndarray, expected: np.ndarray) -> float:
    return float(1 - np.sum((actual - expected) ** 2) / np.sum((expected - expected.mean()) ** 2))


def test_the_regenerative_chip_follows_the_mechanistic_model_in_the_chatter_loop(tmp_path: Path) -> None:
    """ForceNet's displacement inputs make the chip regenerative (the history of CuttingForce): coupled with
    ToolVibration below the stability limit (0.8 x 0.0398 mm at 6000 rpm) its forces follow CuttingForce's
    (r^2 > 0.999, measured 0.9996 and 0.9997) and so does the tool's vibration, which amplifies their difference
    this close to the limit (r^2 > 0.998, measured 0.9989 and 0.9991; 0.9998 while the delayed displacement was
    taken one step less than a period back, which damped the loop); above it (1.25 x) both chatter, the vibration
    growing alike."""
    from milling_twin.models.stability import Mode, stability_lobes

    mode = (Mode(922.0, 0.011, 1.34e6),)
    k = AL7075_CARBIDE
    limit = float(stability_lobes(mode, mode, k["Ktc"], k["Krc"], 2, 0.0, math.pi).limit(np.array([6000.0]))[0])
    assert limit == pytest.approx(3.985e-5, rel=1e-3)
    stable = _chatter_runs(tmp_path / "stable", 0.8 * limit)
    for column, least in (("force.Fx", 0.999), ("force.Fy", 0.999), ("vibration.tip_displacement_x", 0.998),
                          ("vibration.tip_displacement_y", 0.998)):
        assert _r2(stable["net"][column].to_numpy(), stable["mech"][column].to_numpy()) > least, column
    chatter = _chatter_runs(tmp_path / "chatter", 1.25 * limit)
    t = chatter["net"]["time"].to_numpy()
    for column in ("vibration.tip_displacement_x", "vibration.tip_displacement_y"):
        growth = {name: np.std(f[column].to_numpy()[t > 0.15]) / np.std(f[column].to_numpy()[(t > 0.05) & (t < 0.1)])
                  for name, f in chatter.items()}
        assert growth["mech"] > 2 and growth["net"] == pytest.approx(growth["mech"], rel=0.2), growth
        assert _r2(chatter["net"][column].to_numpy(), chatter["mech"][column].to_numpy()) > 0.95, column


@pytest.fixture(scope="module")
def literature_recordings(tmp_path_factory) -> Path:
    """Synthetic recordings made by the mechanistic model with the literature coefficients (what the
    committed network learnt), laid out like the real ones."""
    from test_slot_milling_validation import FEEDS, write_dynoware

    folder = tmp_path_factory.mktemp("slot_literature")
    t = 2.0 + np.arange(3000) * 1e-4
    omega = 6000 * 2 * math.pi / 60
    for feed in FEEDS:
        angle = np.mod(0.4 + omega * (t - t[0]), 2 * math.pi)
        out = CUTTING_FORCE.evaluate(**AL7075_CARBIDE, n_flutes=2, tool_diameter=0.025, helix_angle=math.radians(30),
                                     spindle_speed=omega, feed_velocity_x=feed / 60_000, axial_depth=0.003,
                                     angle=angle, delayed_displacement_x=0.0, delayed_displacement_y=0.0)
        write_dynoware(folder / f"6-n6000f{feed}ap3ae25.csv", t, np.column_stack([out["Fy"], out["Fx"], out["Fz"]]))
    return folder


def test_slot_milling_validation_runs_the_force_net(literature_recordings: Path, tmp_path: Path) -> None:
    from milling_twin.orchestrator.validation import slot_milling as sm

    fmu_path(3)
    doc = sm.validate(literature_recordings, REPO / "scenarios" / "slot_milling_forcenet.toml", fmu_dir(), tmp_path)
    assert doc["model"] == "ForceNet" and [c["feed_mm_per_min"] for c in doc["cases"]] == [300, 600, 900, 1200, 1500]
    for case in doc["cases"]:
        prior = case["prior"]
        assert max(abs(e) for e in prior["mean_relative_error"].values()) < 0.03, case
        assert min(prior["waveform_r2"].values()) > 0.98, case
        assert "identified" not in case and "finetuned" not in case
    folder = tmp_path / "slot_milling_forcenet"
    for name in ("slot_milling.json", "means.png", "waveforms_prior.png"):
        assert (folder / name).stat().st_size > 1000
    assert "ForceNet, network trained on the mechanistic model" in sm.summary(doc)


def test_finetuned_validation_needs_the_weights(literature_recordings: Path, tmp_path: Path) -> None:
    from milling_twin.cli import main

    fmu_path(3)
    assert main(["validate", "slot-milling", "--data", str(literature_recordings), "--scenario",
                 str(REPO / "scenarios" / "slot_milling_forcenet.toml"), "--finetuned", str(tmp_path / "none"),
                 "--out", str(tmp_path / "out"), "--fmu-dir", str(fmu_dir())]) == 2


REAL_DATA = Path(__import__("os").environ.get("MILLING_TWIN_SLOT_DATA")
                 or REPO.parent / "shared" / "data" / "slot_milling_forces")


@pytest.mark.skipif(not REAL_DATA.is_dir(), reason=f"the measured slot-milling recordings are not in {REAL_DATA}: put "
                    "them there (see orchestrator/validation/slot_milling.py) or set MILLING_TWIN_SLOT_DATA")
def test_real_recordings_with_the_force_net(tmp_path: Path) -> None:
    """The committed network on the five Kistler recordings: the mechanistic prior's figures (docs/validation.md)."""
    from milling_twin.orchestrator.validation import slot_milling as sm

    fmu_path(3)
    doc = sm.validate(datasets.data_dir(REAL_DATA), REPO / "scenarios" / "slot_milling_forcenet.toml", fmu_dir(), tmp_path)
    for case in doc["cases"]:
        prior = case["prior"]
        for axis in ("Fx", "Fy", "Fz"):
            assert np.sign(prior["simulated_mean_N"][axis]) == np.sign(prior["recorded_mean_N"][axis]), case
        if case["feed_mm_per_min"] >= 600:  # as the mechanistic model with the literature coefficients
            assert abs(prior["mean_relative_error"]["Fx"]) < 0.1 and abs(prior["mean_relative_error"]["Fy"]) < 0.1
        assert prior["waveform_r2"]["Fy"] > 0.5, case

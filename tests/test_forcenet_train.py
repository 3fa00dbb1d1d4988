"""The force net's torch side (milling_twin/training/force_net.py, the ``train`` extra): a short training run,
reproducibility, the export (BatchNorm folded) and the FMU's C inference against torch, fine-tuning on
recordings (synthetic everywhere; the measured slot-milling forces when present)."""
from __future__ import annotations

import math
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="torch is the optional 'train' extra: pip install -e '.[test,train]'")

from fmu_helpers import OK, Slave, fmu_dir, generated_dir, require_fmu  # noqa: E402
from milling_twin import datasets
from milling_twin.models import force_net as fn  # noqa: E402
from milling_twin.training import force_net as fnt  # noqa: E402
from milling_twin.models.cutting_force import CUTTING_FORCE  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FORCENET = REPO / "fmus" / "forcenet"
C_FLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-Wshadow", "-Wstrict-prototypes",
           "-Wmissing-prototypes", "-Wconversion", "-Wno-sign-conversion"]  # the FMU's (fmus/CMakeLists.txt)


@pytest.fixture(scope="session")
def driver(tmp_path_factory) -> Path:
    """fmus/forcenet/tools/forcenet_run.c with the FMU's forcenet.c, compiled with the FMU's flags."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    assert compiler, "no C compiler"
    out = tmp_path_factory.mktemp("forcenet_run") / "forcenet_run"
    subprocess.run([compiler, *C_FLAGS, "-I", str(FORCENET), "-I", str(generated_dir()),
                    str(FORCENET / "tools" / "forcenet_run.c"),
                    str(FORCENET / "forcenet.c"), "-o", str(out), "-lm"], check=True, capture_output=True, text=True)
    return out


def c_loads(driver: Path, weights_file: Path, features: np.ndarray) -> np.ndarray:
    text = f"{len(features)}\n" + "\n".join(" ".join(repr(float(x)) for x in row) for row in features) + "\n"
    result = subprocess.run([str(driver), "loads", str(weights_file)], input=text, capture_output=True, text=True,
                            check=True)
    return np.array([[float(x) for x in line.split()] for line in result.stdout.splitlines()]).reshape(-1, 3)


def relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference of an element's load vector relative to its magnitude."""
    return float(np.max(np.linalg.norm(a - b, axis=1) / np.linalg.norm(b, axis=1)))


def held_out_features(count: int = 40, seed: int = 77) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values, angle, _ = fn.repeat_angles(fn.sample_conditions(count, rng), 6, rng)
    arrays = fn.element_arrays(values, angle)
    return arrays["features"][arrays["mask"]]


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """The short training run (milling_twin.training.force_net.QUICK) and its export."""
    started = time.perf_counter()
    net, report = fnt.train(fnt.QUICK, log=None)
    seconds = time.perf_counter() - started
    weights = fnt.export(net)
    path = fn.write_weights(weights, tmp_path_factory.mktemp("quick") / "weights.bin")
    return net, report, weights, path, seconds


def test_a_short_training_run(quick) -> None:
    net, report, weights, path, seconds = quick
    assert seconds < 60, f"the short training run took {seconds:.0f} s"
    assert min(report["held_out_r2"].values()) > 0.97, report["held_out_r2"]
    assert report["test_samples"] == fnt.QUICK.test_conditions * fnt.QUICK.angles
    assert fn.read_weights(path).shapes() == fn.Weights.expected_shapes(16, 32, 2)


def test_training_is_reproducible() -> None:
    tiny = fnt.Config(train_conditions=40, test_conditions=10, angles=4, epochs=2)
    first, second = (fnt.export(fnt.train(tiny, log=None)[0]) for _ in range(2))
    assert fn.encode_weights(first) == fn.encode_weights(second)


def test_export_folds_batchnorm_exactly(quick) -> None:
    net, _, weights, _, _ = quick
    features = held_out_features()
    with torch.no_grad():
        reference = net.double()(torch.tensor(features)).numpy() * net.load_ref
    net.float()
    assert relative_difference(fn.network(weights, features), reference) < 1e-10
    assert relative_difference(fn.network(weights, features),
                               fnt.network_for(weights)(torch.tensor(features)).detach().numpy() * weights.load_ref) < 1e-12


def test_c_inference_equals_torch(quick, driver: Path) -> None:
    """The FMU's C code (forcenet.c) against the torch network as trained (BatchNorm not folded), float32 and
    float64: the element loads agree to 1e-5 relative (float32 rounding) and 1e-10 (float64)."""
    net, _, weights, path, _ = quick
    features = held_out_features()
    loads = c_loads(driver, path, features)
    with torch.no_grad():
        as_trained32 = net.float()(torch.tensor(features, dtype=torch.float32)).double().numpy() * net.load_ref
        as_trained64 = net.double()(torch.tensor(features)).numpy() * net.load_ref
    net.float()
    assert relative_difference(loads, as_trained32) < 1e-5
    assert relative_difference(loads, as_trained64) < 1e-10
    assert np.array_equal(loads, fn.network(weights, features))  # and the numpy reference bit for bit


def test_c_inference_of_the_committed_network_equals_torch(driver: Path) -> None:
    weights = fn.default_weights()
    features = held_out_features(seed=78)
    loads = c_loads(driver, fn.WEIGHTS_FILE, features)
    for dtype, tolerance in ((torch.float32, 1e-5), (torch.float64, 1e-12)):
        net = fnt.network_for(weights, dtype)
        with torch.no_grad():
            reference = net(torch.tensor(features, dtype=dtype)).double().numpy() * weights.load_ref
        assert relative_difference(loads, reference) < tolerance, dtype


def test_the_fmu_with_a_new_network_gives_the_torch_tool_forces(quick, tmp_path: Path) -> None:
    """The quickly trained network installed into the FMU (no recompilation): its forces are torch's."""
    net, _, weights, _, _ = quick
    values = {"n_flutes": 3, "tool_diameter": 0.012, "helix_angle": math.radians(35), "moment_height": 0.0,
              "spindle_speed": 800.0, "feed_velocity_x": 0.01, "feed_velocity_y": -0.004, "axial_depth": 0.006,
              "entry_angle": 0.3, "exit_angle": 2.5}
    for version in (3, 2):
        source = require_fmu(fmu_dir() / ("ForceNet.fmu" if version == 3 else "ForceNet_fmi2.fmu"))
        copy = fn.install_weights(source, weights, tmp_path / source.name)
        with Slave(copy) as slave:
            slave.instantiate()
            slave.initialize(values)
            rows = []
            for _ in range(20):
                assert slave.step(1e-4) == OK
                rows.append(slave.get(["spindle_angle", "Fx", "Fy", "Fz"]))
        rows = np.array(rows)
        batch = {k: np.full(len(rows), float(v)) for k, v in values.items()}
        arrays = fn.element_arrays(batch, rows[:, 0])
        with torch.no_grad():
            forces = fnt.tool_forces(net.float(), *fnt._tensors(arrays, net)).double().numpy()
        scale = np.max(np.abs(forces))
        assert scale > 1
        assert np.max(np.abs(rows[:, 1:] - forces)) < 1e-5 * scale


# ---- fine-tuning ----

OTHER_TOOL = {"Ktc": 950e6, "Krc": 250e6, "Kac": 150e6, "Kte": 16e3, "Kre": 19e3, "Kae": 18e3}


@pytest.fixture(scope="module")
def other_material(tmp_path_factory) -> Path:
    """Synthetic slot recordings of a material the network was not trained on (other coefficients)."""
    from test_slot_milling_validation import FEEDS, write_dynoware

    folder = tmp_path_factory.mktemp("slot_other")
    t = 1.0 + np.arange(2000) * 1e-4
    omega = 6000 * 2 * math.pi / 60
    for feed in FEEDS:
        angle = np.mod(2.0 + omega * (t - t[0]), 2 * math.pi)
        out = CUTTING_FORCE.evaluate(**OTHER_TOOL, n_flutes=2, tool_diameter=0.025, helix_angle=math.radians(30),
                                     spindle_speed=omega, feed_velocity_x=feed / 60_000, axial_depth=0.003,
                                     angle=angle, delayed_displacement_x=0.0, delayed_displacement_y=0.0)
        write_dynoware(folder / f"6-n6000f{feed}ap3ae25.csv", t, np.column_stack([out["Fy"], out["Fx"], out["Fz"]]))
    return folder


def test_finetuning_learns_another_material_for_a_left_out_feed(other_material: Path) -> None:
    from milling_twin.orchestrator.validation import slot_milling as sm

    recordings = datasets.read_recordings(other_material)
    tool = fnt.slot_tool()
    left_out = recordings[2]  # 900 mm/min
    tuned = fnt.finetune_on(fn.default_weights(), [r for r in recordings if r is not left_out], tool, rounds=1,
                            steps=150)
    recorded = left_out.forces.mean(axis=0)
    error = lambda w: np.abs(fnt.mean_slot_prediction(w, left_out, tool)[[1, 0, 2]] - recorded) / np.abs(recorded)  # noqa: E731
    before, after = error(fn.default_weights()), error(tuned)
    assert before.max() > 0.2, before  # another material: Fz is off by more than 20 %
    assert after.max() < 0.05, (before, after)


def test_finetune_command_writes_weights_the_validation_runs(other_material: Path, tmp_path: Path) -> None:
    from milling_twin.orchestrator.validation import slot_milling as sm

    require_fmu(fmu_dir() / "ForceNet.fmu")
    out = tmp_path / "ft"
    doc = fnt.finetune(other_material, out, log=None, rounds=1, steps=60)
    assert [c["left_out_feed_mm_per_min"] for c in doc["cases"]] == [300, 600, 900, 1200, 1500]
    for feed in (300, 600, 900, 1200, 1500):
        fn.read_weights(out / f"finetuned_without_f{feed}.bin")
    result = sm.validate(other_material, REPO / "scenarios" / "slot_milling_forcenet.toml", fmu_dir(), tmp_path / "v",
                         finetuned=out)
    for case, tuned in zip(result["cases"], doc["cases"]):
        # the FMU with the left-out network gives the mean the fine-tuning predicted (to the waveform sampling)
        for axis in ("Fx", "Fy", "Fz"):
            assert case["finetuned"]["mean_relative_error"][axis] == pytest.approx(
                tuned["finetuned_mean_relative_error"][axis], abs=2e-3)
    assert (tmp_path / "v" / "slot_milling_forcenet" / "waveforms_finetuned.png").is_file()


REAL_DATA = Path(os.environ.get("MILLING_TWIN_SLOT_DATA") or REPO.parent / "shared" / "data" / "slot_milling_forces")


@pytest.mark.skipif(not REAL_DATA.is_dir(), reason=f"the measured slot-milling recordings are not in {REAL_DATA}: put "
                    "them there (see orchestrator/validation/slot_milling.py) or set MILLING_TWIN_SLOT_DATA")
def test_finetuning_on_the_measured_feeds_predicts_a_left_out_one() -> None:
    """The network fine-tuned on the recordings at 300, 600, 1200 and 1500 mm/min predicts the mean forces
    at 900 mm/min (docs/forcenet.md: every left-out feed, milling-twin train forcenet-finetune)."""
    from milling_twin.orchestrator.validation import slot_milling as sm

    recordings = datasets.read_recordings(datasets.data_dir(REAL_DATA))
    tool = fnt.slot_tool()
    left_out = next(r for r in recordings if r.feed == 900)
    tuned = fnt.finetune_on(fn.default_weights(), [r for r in recordings if r is not left_out], tool)
    recorded = left_out.forces.mean(axis=0)
    error = np.abs(fnt.mean_slot_prediction(tuned, left_out, tool)[[1, 0, 2]] - recorded) / np.abs(recorded)
    before = np.abs(fnt.mean_slot_prediction(fn.default_weights(), left_out, tool)[[1, 0, 2]] - recorded) / np.abs(recorded)
    assert before[2] > 0.4 and error.max() < 0.12, (before, error)

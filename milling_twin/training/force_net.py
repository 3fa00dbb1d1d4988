"""Training, export and fine-tuning of the force net (models/force_net.py) with torch (the ``train`` extra).

    milling-twin train forcenet [--quick] [--out FILE] [--report FILE]
    milling-twin train forcenet-finetune [--data DIR] [--out DIR]
    milling-twin train forcenet --header-only      # default_weights.h from resources/weights.bin

``train`` regenerates the committed network ``fmus/forcenet/resources/weights.bin`` (and the FMU's built-in
copy ``fmus/forcenet/default_weights.h``) reproducibly: fixed seeds, deterministic algorithms, one thread
(bit-identical weights on the same machine and torch version; 106 s on the 2-core development machine).

**Training data** (:func:`make_dataset`): cutting conditions sampled from :data:`milling_twin.models.force_net.DOMAIN`
(flutes, tool diameter, helix, feed per tooth, feed direction, axial depth, radial engagement as slotting, up- or
down-milling, spindle speed) and, per condition, tool angles theta0; the targets are the forces on the tool
``Fx, Fy, Fz`` of the mechanistic model (``milling_twin.models.cutting_force.CUTTING_FORCE`` with its default Al7075
coefficients, no runout or vibration) plus Gaussian noise of ``NOISE`` times the condition's RMS force per
axis. The network is trained through the integration over the edge (what a dynamometer measures), never on
element loads: the same loss fine-tunes it on recorded forces. Held-out conditions are drawn separately
(never seen in training); R^2 per axis is reported against the noise-free mechanistic forces.

**Fine-tuning on recorded forces** (:func:`finetune`): the slot-milling recordings (read from ``--data``,
``$MILLING_TWIN_SLOT_DATA`` or ``../shared/data/slot_milling_forces``; never copied into the repository) are
folded into one mean waveform per revolution, their phase aligned with the network's prediction
(``milling_twin.orchestrator.validation.slot_milling.align``), and the network is fine-tuned on those waveforms and
their means with BatchNorm frozen, a small learning rate and an L2 pull towards the pretrained weights
(:func:`finetune_on`). Leave-one-out: for
each measured feed a network fine-tuned on the four others predicts it; the errors are written to
``<out>/finetune.json`` with the weights (``finetuned_without_f<feed>.bin``, ``finetuned_all.bin``), which
``milling-twin validate slot-milling --scenario scenarios/slot_milling_forcenet.toml
--finetuned <out>`` runs through the FMU.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from milling_twin import datasets
from milling_twin.models import force_net as fn
from milling_twin.models.cutting_force import AL7075_CARBIDE, TWO_PI

SEED = 20240605
NOISE = 0.02  # Gaussian noise on the training forces, times the condition's RMS force per axis
H = fn.ELEMENTS_PER_FLUTE


@dataclass(frozen=True)
class Config:
    kernel: int = fn.DEFAULT_SIZES["kernel"]
    width: int = fn.DEFAULT_SIZES["width"]
    blocks: int = fn.DEFAULT_SIZES["blocks"]
    train_conditions: int = 2000
    test_conditions: int = 400
    angles: int = 24              # tool angles per condition
    epochs: int = 60
    batch: int = 256              # samples (tool angles) per batch
    lr: float = 3e-3
    seed: int = SEED


QUICK = Config(train_conditions=600, test_conditions=100, angles=16, epochs=20)  # the tests' short run


def setup_torch(threads: int = 1) -> None:
    """Deterministic algorithms; one thread by default: this small network gains nothing from a second
    one, and OpenMP's waiting threads make it several times slower when the other core is busy."""
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True)


@dataclass
class Dataset:
    """Samples (one tool angle of one condition each) with their elements in contact packed: the
    elements of sample s are rows ``offsets[s] .. offsets[s + 1] - 1`` of ``features`` and ``project``."""

    features: torch.Tensor  # n x 7 (float32)
    project: torch.Tensor   # n x 3 x 3: element (t, r, a) load [N/m] -> force (x, y, z) on the tool [N] (dz in)
    offsets: np.ndarray     # S + 1
    target: torch.Tensor    # S x 3, N (with noise for training)
    clean: torch.Tensor     # S x 3, N (noise-free)
    scale: torch.Tensor     # S x 1, N: the condition's RMS force (loss weights)
    condition: np.ndarray   # S, condition index

    def __len__(self) -> int:
        return len(self.target)

    def batch(self, samples: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(features, projections, batch-local sample index) of the elements of ``samples``."""
        starts, counts = self.offsets[samples], self.offsets[samples + 1] - self.offsets[samples]
        local = np.repeat(np.arange(len(samples)), counts)
        index = np.repeat(starts - (np.cumsum(counts) - counts), counts) + np.arange(int(counts.sum()))
        index = torch.from_numpy(index)
        return self.features[index], self.project[index], torch.from_numpy(local)


def pack(arrays: dict, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """The elements in contact of element_arrays' output: (features, projections, offsets per sample)."""
    mask = arrays["mask"]
    offsets = np.concatenate([[0], np.cumsum(mask.sum(axis=1))])
    features = torch.tensor(arrays["features"][mask], dtype=dtype)
    project = torch.tensor(fn.projection({k: arrays[k][mask] for k in ("sin", "cos", "dz")}), dtype=dtype)
    return features, project, offsets


def make_dataset(conditions: int, angles: int, rng: np.random.Generator, noise: float = NOISE,
                 coefficients: dict[str, float] | None = None) -> Dataset:
    cond = fn.sample_conditions(conditions, rng)
    values, angle, index = fn.repeat_angles(cond, angles, rng)
    arrays = fn.element_arrays(values, angle)
    clean = fn.mechanistic_forces(values, angle, coefficients)
    rms = np.sqrt(np.bincount(index, np.sum(clean ** 2, axis=1), conditions) / np.bincount(index, None, conditions) / 3)
    rms = np.maximum(rms, 1e-9)[index]
    noisy = clean + noise * rms[:, None] * rng.standard_normal(clean.shape)
    features, project, offsets = pack(arrays)
    return Dataset(features, project, offsets, torch.tensor(noisy, dtype=torch.float32),
                   torch.tensor(clean, dtype=torch.float32), torch.tensor(rms[:, None], dtype=torch.float32), index)


# ---- the network ----

class Cube(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * x * x


class Residual(nn.Module):
    def __init__(self, width: int):
        super().__init__()
        self.l1, self.bn1 = nn.Linear(width, width), nn.BatchNorm1d(width)
        self.l2, self.bn2 = nn.Linear(width, width), nn.BatchNorm1d(width)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(x + self.bn2(self.l2(torch.relu(self.bn1(self.l1(x))))))


class ForceNetModule(nn.Module):
    """Per element: kernel-function block (Linear, BN, x^3), linear-transform block (Linear, BN, ReLU),
    residual blocks, output Linear: loads per unit length in units of ``load_ref``."""

    def __init__(self, kernel: int = 16, width: int = 32, blocks: int = 2):
        super().__init__()
        self.kernel = nn.Sequential(nn.Linear(fn.N_FEATURES, kernel), nn.BatchNorm1d(kernel), Cube())
        self.transform = nn.Sequential(nn.Linear(kernel, width), nn.BatchNorm1d(width), nn.ReLU())
        self.blocks = nn.ModuleList(Residual(width) for _ in range(blocks))
        self.out = nn.Linear(width, fn.N_LOADS)
        self.h_ref, self.v_ref, self.load_ref = fn.H_REF, fn.V_REF, fn.LOAD_REF

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a = self.transform(self.kernel(x))
        for block in self.blocks:
            a = block(a)
        return self.out(a)


def tool_forces(net: nn.Module, features: torch.Tensor, project: torch.Tensor, sample: torch.Tensor,
                samples: int) -> torch.Tensor:
    """Fx, Fy, Fz per sample (samples x 3): the loads of the elements in contact (packed, element i of sample
    ``sample[i]``), projected and summed."""
    loads = net(features) * net.load_ref                        # n x 3, N/m
    forces = torch.einsum("nij,nj->ni", project, loads)       # n x 3, N
    return torch.zeros(samples, 3, dtype=forces.dtype).index_add(0, sample, forces)


def predict(net: nn.Module, data: Dataset, batch: int = 4096) -> np.ndarray:
    net.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(data), batch):
            samples = np.arange(i, min(i + batch, len(data)))
            out.append(tool_forces(net, *data.batch(samples), len(samples)))
    return torch.cat(out).double().numpy()


def r2(predicted: np.ndarray, truth: np.ndarray) -> list[float]:
    return [float(1 - np.sum((truth[:, k] - predicted[:, k]) ** 2) / np.sum((truth[:, k] - truth[:, k].mean()) ** 2))
            for k in range(truth.shape[1])]


def train(config: Config = Config(), log=print) -> tuple[ForceNetModule, dict]:
    """Train on the mechanistic model; returns the network (eval mode) and a report with held-out R^2."""
    setup_torch()
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    started = time.perf_counter()
    train_set = make_dataset(config.train_conditions, config.angles, rng)
    test_set = make_dataset(config.test_conditions, config.angles, rng)
    data_time = time.perf_counter() - started
    net = ForceNetModule(config.kernel, config.width, config.blocks)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    steps = config.epochs * math.ceil(len(train_set) / config.batch)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimizer, max_lr=config.lr, total_steps=steps, pct_start=0.15)
    generator = torch.Generator().manual_seed(config.seed)
    history = []
    for epoch in range(config.epochs):
        net.train()
        order = torch.randperm(len(train_set), generator=generator).numpy()
        total = 0.0
        for i in range(0, len(order), config.batch):
            idx = order[i:i + config.batch]
            predicted = tool_forces(net, *train_set.batch(idx), len(idx))
            loss = torch.mean(((predicted - train_set.target[idx]) / train_set.scale[idx]) ** 2)
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            optimizer.step()
            schedule.step()
            total += float(loss.detach()) * len(idx)
        history.append(total / len(train_set))
        if log and (epoch % 5 == 4 or epoch == config.epochs - 1):
            log(f"epoch {epoch + 1}/{config.epochs}: training loss {history[-1]:.3e} "
                f"({time.perf_counter() - started:.0f} s)")
    net.eval()
    predicted = predict(net, test_set)
    clean = test_set.clean.double().numpy()
    report = {
        "config": config.__dict__, "domain": fn.DOMAIN, "noise": NOISE, "seed": config.seed,
        "coefficients": AL7075_CARBIDE, "elements_per_flute": H,
        "train_samples": len(train_set), "test_samples": len(test_set),
        "train_elements_in_contact": int(train_set.offsets[-1]),
        "held_out_r2": dict(zip(("Fx", "Fy", "Fz"), r2(predicted, clean))),
        # each sample relative to its condition's RMS force: small and large cuts count alike
        "held_out_r2_normalized": dict(zip(("Fx", "Fy", "Fz"), r2(predicted / test_set.scale.double().numpy(),
                                                                  clean / test_set.scale.double().numpy()))),
        "held_out_conditions": config.test_conditions,
        "held_out_rms_error_relative": float(np.sqrt(np.mean((predicted - clean) ** 2)) / np.sqrt(np.mean(clean ** 2))),
        "final_training_loss": history[-1], "data_seconds": data_time,
        "wall_seconds": time.perf_counter() - started, "torch": torch.__version__, "threads": torch.get_num_threads(),
    }
    return net, report


# ---- export: BatchNorm folded into the linear layers, float64 ----

def _fold(linear: nn.Linear, bn: nn.BatchNorm1d | None) -> tuple[np.ndarray, np.ndarray]:
    w = linear.weight.detach().double().numpy()
    b = linear.bias.detach().double().numpy()
    if bn is None:
        return w.copy(), b.copy()
    gamma, beta = bn.weight.detach().double().numpy(), bn.bias.detach().double().numpy()
    mean, var = bn.running_mean.detach().double().numpy(), bn.running_var.detach().double().numpy()
    k = gamma / np.sqrt(var + bn.eps)
    return w * k[:, None], (b - mean) * k + beta


def export(net: ForceNetModule) -> fn.Weights:
    layers = [_fold(net.kernel[0], net.kernel[1]), _fold(net.transform[0], net.transform[1])]
    for block in net.blocks:
        layers += [_fold(block.l1, block.bn1), _fold(block.l2, block.bn2)]
    layers.append(_fold(net.out, None))
    return fn.Weights(tuple(layers), net.h_ref, net.v_ref, net.load_ref)


def load_into(net: ForceNetModule, weights: fn.Weights) -> ForceNetModule:
    """A network (BatchNorm as identity: mean 0, variance 1 - eps, scale 1, shift 0) holding exported weights:
    the starting point of fine-tuning, equal to the exported network."""
    pairs = [(net.kernel[0], net.kernel[1]), (net.transform[0], net.transform[1])]
    for block in net.blocks:
        pairs += [(block.l1, block.bn1), (block.l2, block.bn2)]
    pairs.append((net.out, None))
    with torch.no_grad():
        for (linear, bn), (w, b) in zip(pairs, weights.layers):
            linear.weight.copy_(torch.tensor(w, dtype=linear.weight.dtype))
            linear.bias.copy_(torch.tensor(b, dtype=linear.bias.dtype))
            if bn is not None:
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0 - bn.eps)
                bn.weight.fill_(1.0)
                bn.bias.zero_()
    net.h_ref, net.v_ref, net.load_ref = weights.h_ref, weights.v_ref, weights.load_ref
    return net


def network_for(weights: fn.Weights, dtype=torch.float64) -> ForceNetModule:
    """A torch network (eval mode, ``dtype``) computing exactly the exported network."""
    net = ForceNetModule(weights.kernel, weights.width, weights.blocks).to(dtype)
    return load_into(net, weights).eval()


# ---- fine-tuning on the recorded slot-milling forces ----

def _slot_values(recording, tool: dict, angles: np.ndarray) -> dict[str, np.ndarray]:
    omega = recording.rpm * TWO_PI / 60
    count = len(angles)
    return {"n_flutes": np.full(count, float(tool["n_flutes"])),
            "tool_diameter": np.full(count, tool["tool_diameter"]),
            "helix_angle": np.full(count, tool["helix_angle"]), "spindle_speed": np.full(count, omega),
            "feed_velocity_x": np.full(count, recording.feed / 60_000), "feed_velocity_y": np.zeros(count),
            "axial_depth": np.full(count, recording.axial_depth / 1000), "entry_angle": np.zeros(count),
            "exit_angle": np.full(count, math.pi)}


def _recorded_targets(net: ForceNetModule, recording, tool: dict) -> tuple[dict, np.ndarray]:
    """The recording's mean waveform per revolution (model axes), at the tool angles its phase takes when
    aligned with the network's prediction (orchestrator.validation.slot_milling.align, the comparison of the
    validation); returns (element arrays at those angles, targets points x 3)."""
    from milling_twin.orchestrator.validation import slot_milling as sm

    rec_wave, _, _ = sm.recorded_waveform(recording)
    fine = np.arange(sm.FINE) * TWO_PI / sm.FINE
    arrays = fn.element_arrays(_slot_values(recording, tool, fine), fine)
    with torch.no_grad():
        sim = tool_forces(net, *_tensors(arrays, net)).numpy()
    sim_rec = np.column_stack([sim[:, ("Fx", "Fy", "Fz").index(sm.AXES[a])] for a in sm.AXES])  # recorded axes
    shift, _ = sm.align(rec_wave, sim_rec)
    n = len(rec_wave)  # recorded sample j lies at the simulated angle index shift + round(j FINE / n)
    angles = np.mod(shift + np.round(np.arange(n) * sm.FINE / n), sm.FINE) * TWO_PI / sm.FINE
    target = np.column_stack([rec_wave[:, list(sm.AXES).index(a)] for a in ("Fy", "Fx", "Fz")])  # model axes
    return fn.element_arrays(_slot_values(recording, tool, angles), angles), target


def _tensors(arrays: dict, net: nn.Module) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """tool_forces' arguments for all samples of element_arrays' output."""
    features, project, offsets = pack(arrays, next(net.parameters()).dtype)
    samples = len(offsets) - 1
    return features, project, torch.from_numpy(np.repeat(np.arange(samples), np.diff(offsets))), samples


def finetune_on(weights: fn.Weights, recordings: list, tool: dict, rounds: int = 2, steps: int = 300,
                lr: float = 1e-3, pull: float = 1e-2, mean_weight: float = 10.0, seed: int = SEED) -> fn.Weights:
    """Fine-tune exported weights on recordings (their mean waveforms per revolution): BatchNorm folded
    (frozen), float64, Adam; loss = mean squared error per axis relative to that axis' RMS recorded force,
    plus ``mean_weight`` times the squared error of the mean over the revolution (the dynamometer's
    resonances, which the network cannot represent, shape the waveform but not its mean), plus ``pull`` times the squared distance of the parameters from the pretrained ones (relative to their
    RMS). ``rounds`` times: align the recordings' phases with the current network, then ``steps`` steps
    (the second alignment sees the once-per-revolution pattern the first round learnt)."""
    setup_torch()
    torch.manual_seed(seed)
    net = network_for(weights, torch.float64)
    start = [p.detach().clone() for p in net.parameters()]
    size = [float(torch.sqrt(torch.mean(p ** 2))) + 1e-3 for p in start]
    optimizer = torch.optim.Adam(net.parameters(), lr=lr)
    for _ in range(rounds):
        sets = []
        for recording in recordings:
            arrays, target = _recorded_targets(net, recording, tool)
            sets.append((*_tensors(arrays, net), torch.tensor(target)))
        scale = torch.sqrt(torch.mean(torch.cat([t for *_, t in sets]) ** 2, dim=0))  # per axis
        for _ in range(steps):
            fit = 0.0
            for *args, t in sets:
                error = (tool_forces(net, *args) - t) / scale
                fit = fit + (torch.mean(error ** 2) + mean_weight * torch.mean(torch.mean(error, dim=0) ** 2)) / len(sets)
            loss = fit + pull * sum(torch.mean((p - p0) ** 2) / s ** 2 for p, p0, s in zip(net.parameters(), start, size))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    return export(net)


def slot_tool(scenario_path: Path | None = None) -> dict:
    """The tool of scenarios/slot_milling.toml (n_flutes, diameter, helix), read without the FMUs."""
    import tomllib

    from milling_twin.models.units import conversion_factor

    path = scenario_path or fn.REPO / "scenarios" / "slot_milling_forcenet.toml"
    parameters = tomllib.loads(path.read_text())["fmus"]["force"]["parameters"]
    si = lambda p, unit: p["value"] * conversion_factor(p["unit"], unit) if isinstance(p, dict) else p  # noqa: E731
    return {"n_flutes": int(parameters["n_flutes"]), "tool_diameter": si(parameters["tool_diameter"], "m"),
            "helix_angle": si(parameters["helix_angle"], "rad")}


def mean_slot_prediction(weights: fn.Weights, recording, tool: dict, points: int = 720) -> np.ndarray:
    """The network's mean forces over a revolution at the recording's conditions (model axes Fx, Fy, Fz)."""
    angles = np.arange(points) * TWO_PI / points
    arrays = fn.element_arrays(_slot_values(recording, tool, angles), angles)
    net = network_for(weights)
    with torch.no_grad():
        return tool_forces(net, *_tensors(arrays, net)).numpy().mean(axis=0)


def finetune(data: Path, out: Path, weights: fn.Weights | None = None, log=print, **options) -> dict:
    """Leave-one-feed-out fine-tuning on the slot-milling recordings; writes weights and finetune.json."""
    from milling_twin.orchestrator.validation import slot_milling as sm

    weights = weights or fn.default_weights()
    recordings = datasets.read_recordings(data)
    tool = slot_tool()
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    cases = []
    for i, left_out in enumerate(recordings):
        others = [r for j, r in enumerate(recordings) if j != i]
        tuned = finetune_on(weights, others, tool, **options)
        fn.write_weights(tuned, out / f"finetuned_without_f{left_out.feed:g}.bin")
        recorded = left_out.forces.mean(axis=0)  # recorded axes
        model_axes = lambda f: np.array([f[1], f[0], f[2]])  # noqa: E731  (model Fx,Fy,Fz -> recorded Fx,Fy,Fz)
        before = model_axes(mean_slot_prediction(weights, left_out, tool))
        after = model_axes(mean_slot_prediction(tuned, left_out, tool))
        case = {"left_out_feed_mm_per_min": left_out.feed, "recorded_mean_N": dict(zip(sm.AXES, recorded.tolist())),
                "pretrained_mean_relative_error": dict(zip(sm.AXES, ((before - recorded) / np.abs(recorded)).tolist())),
                "finetuned_mean_relative_error": dict(zip(sm.AXES, ((after - recorded) / np.abs(recorded)).tolist()))}
        cases.append(case)
        if log:
            log(f"without f{left_out.feed:g}: mean error at the left-out feed "
                + ", ".join(f"{a} {100 * case['pretrained_mean_relative_error'][a]:+.1f} -> "
                            f"{100 * case['finetuned_mean_relative_error'][a]:+.1f} %" for a in sm.AXES))
    fn.write_weights(finetune_on(weights, recordings, tool, **options), out / "finetuned_all.bin")
    doc = {"data": str(data), "tool": tool, "options": options, "cases": cases,
           "wall_seconds": time.perf_counter() - started,
           "axes": "recorded Fx, Fy, Fz (= model Fy, Fx, Fz), see orchestrator/validation/slot_milling.py"}
    (out / "finetune.json").write_text(json.dumps(doc, indent=2))
    return doc


# ---- command line ----

def write_default(weights: fn.Weights, path: Path = fn.WEIGHTS_FILE, header: Path = fn.DEFAULT_WEIGHTS_HEADER) -> None:
    fn.write_weights(weights, path)
    header.write_text(fn.weights_header(path.read_bytes()))


def train_command(args: argparse.Namespace) -> int:
    """``milling-twin train forcenet``: train, export and install the weights (or only rewrite the header)."""
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    if args.header_only:
        fn.DEFAULT_WEIGHTS_HEADER.write_text(fn.weights_header(fn.WEIGHTS_FILE.read_bytes()))
        print(f"wrote {fn.DEFAULT_WEIGHTS_HEADER}")
        return 0
    out = args.out or fn.WEIGHTS_FILE
    net, report = train(QUICK if args.quick else Config())
    weights = export(net)
    if out.resolve() == fn.WEIGHTS_FILE.resolve():
        write_default(weights)
    else:
        fn.write_weights(weights, out)
    args.report.parent.mkdir(parents=True, exist_ok=True)
    args.report.write_text(json.dumps(report, indent=2))
    print(json.dumps({k: report[k] for k in ("held_out_r2", "held_out_rms_error_relative", "wall_seconds")}))
    print(f"weights: {out}; report: {args.report}")
    return 0


def finetune_command(args: argparse.Namespace) -> int:
    """``milling-twin train forcenet-finetune``: leave-one-feed-out fine-tuning on the slot recordings."""
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    finetune(datasets.data_dir(args.data), args.out)
    print(f"weights and finetune.json in {args.out}")
    return 0

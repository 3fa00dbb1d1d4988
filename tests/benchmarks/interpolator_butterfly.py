"""Benchmark of the interpolator on the butterfly NURBS curve (scenarios/nurbs/): per parameter-update
method, the feedrate fluctuation, the chord error, the machining time against lower bounds and the C cost
per interpolation point. A script, not a timed test:

    .venv/bin/python tests/benchmarks/interpolator_butterfly.py [--repeat 15] [--plot scenarios/nurbs/butterfly_feed.png]

Setting (the literature's): F = 100 mm/s, tangential acceleration A = 1000 mm/s2, jerk J = 1e5 mm/s3 (also
the centripetal acceleration A and the curvature jerk v^3 kappa^2 <= J), chord error 1 um, period 1 ms; axis
limits set so high that they do not bind; arc_length_feedback off (open loop, as in the literature) unless a
row says otherwise (the FMU's default is on). The program is the G6.2 block alone, starting at rest on the first
control point (start_x/start_y = that point) and ending at rest on the last.

Runs the standalone driver build/tools/interp_run (the FMU's C engine, built by CMake from the same sources)
once with --csv for the metrics and --repeat times for the cost (parsing and scheduling excluded; median).

Metrics, over the interpolation steps inside the curve (the last step, clamped onto u = 1, excluded):
- fluctuation |V_actual - V_scheduled| / V_scheduled with V_actual = (arc length of the curve from u_i to
  u_i+1) / T (the path speed; 8-point Gauss-Legendre on the spline) and V_scheduled = (s_i+1 - s_i) / T (the
  schedule's step); the chord |C(u_i+1) - C(u_i)| is shorter than that arc by (kappa h)^2 / 24 of it, a geometric
  difference, not a speed error (column "chord vs step": the same with the chord, as the literature measures
  open-loop methods: a tool on schedule has that much shorter chords where the curve is sharp);
- chord error: the largest distance of the curve between u_i and u_i+1 from the chord (16 samples per step);
- time: the machining time against two lower bounds under the same limits: the velocity-limit-curve bound
  (integral of ds / VLC, 4.533 s; it ignores the acceleration limit) and the acceleration-limited
  time-optimal bound (bidirectional scan on the VLC with the tangential acceleration limit; jerk ignored),
  which every feasible schedule also needs, both from the exact limits on a 200,000-point grid.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.interpolate import BSpline

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from milling_twin.models.interpolator import nurbs_block_gcode  # noqa: E402
from milling_twin.training.rbf import load_weights  # noqa: E402

NURBS_DIR = REPO / "scenarios" / "nurbs"
DRIVER = REPO / "build" / "tools" / "interp_run"
F, A, J, CHORD, T = 0.1, 1.0, 100.0, 1e-6, 1e-3

LIMITS = {"acceleration": A, "jerk": J, "centripetal_acceleration": A, "chord_error": CHORD, "period": T,
          "max_feed": 1.0, "rapid_feed": 1.0, "arc_length_feedback": 0.0,
          **{f"axis_acceleration_{a}": 1e4 for a in "xyz"}, **{f"axis_jerk_{a}": 1e7 for a in "xyz"}}


def load_curve() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    data = np.genfromtxt(NURBS_DIR / "butterfly_control_points_weights.csv", delimiter=",", names=True)
    knots = np.loadtxt(NURBS_DIR / "butterfly_knots_6dp.csv")
    points = np.column_stack([data["x_mm"], data["y_mm"]])
    return points, data["weight"], knots


def program_text() -> str:
    points, weights, knots = load_curve()
    lines = ["(butterfly NURBS curve of the interpolation literature, scenarios/nurbs/PROVENANCE.md)",
             "(F 100 mm/s; start the tool on the first control point: start_x/start_y)", "G21 G90 G17"]
    lines += nurbs_block_gcode(points, weights, knots, 3, F * 60000.0)
    lines += ["M30"]
    return "\n".join(lines) + "\n"


def curve_evaluator():
    points, weights, knots = load_curve()
    homogeneous = np.column_stack([points * weights[:, None], weights])
    spline = BSpline(knots, homogeneous, 3)

    def evaluate(u: np.ndarray) -> np.ndarray:
        h = spline(u)
        return h[..., :2] / h[..., 2:3] * 1e-3  # m

    d_spline = spline.derivative(1)

    def derivative(u: np.ndarray) -> np.ndarray:
        h, dh = spline(u), d_spline(u)
        return (dh[..., :2] - dh[..., 2:3] * h[..., :2] / h[..., 2:3]) / h[..., 2:3] * 1e-3  # m per unit u

    evaluate.derivative = derivative
    return evaluate, spline, knots


def run_driver(params: dict[str, float], program: Path, csv: Path | None, repeat: int) -> tuple[str, float | None]:
    args = [str(DRIVER)]
    for name, value in params.items():
        args += ["--param", f"{name}={value!r}"]
    if csv is not None:
        args += ["--csv", str(csv)]
    if repeat:
        args += ["--repeat", str(repeat)]
    out = subprocess.run(args + [str(program)], check=True, capture_output=True, text=True).stdout
    cost = None
    for line in out.splitlines():
        if line.startswith("ns_per_point"):
            cost = float(line.split()[2])
    return out, cost


def lower_bounds(evaluate, spline) -> tuple[float, float]:
    """(integral ds / VLC, acceleration-limited time-optimal time) on a fine grid, exact limits."""
    u = np.linspace(0.0, 1.0, 200_001)
    d0 = spline(u)
    d1 = spline.derivative(1)(u)
    d2 = spline.derivative(2)(u)
    w, w1, w2 = d0[:, 2:3], d1[:, 2:3], d2[:, 2:3]
    c = d0[:, :2] / w
    c1 = (d1[:, :2] - w1 * c) / w
    c2 = (d2[:, :2] - 2 * w1 * c1 - w2 * c) / w
    c1, c2 = c1 * 1e-3, c2 * 1e-3
    speed = np.hypot(c1[:, 0], c1[:, 1])
    kappa = np.abs(c1[:, 0] * c2[:, 1] - c1[:, 1] * c2[:, 0]) / speed ** 3
    rho = 1.0 / np.maximum(kappa, 1e-300)
    chord = 2.0 / T * np.sqrt(np.maximum(CHORD * (2 * rho - CHORD), 0.0))
    vlc = np.minimum.reduce([np.full_like(rho, F), chord, np.sqrt(A * rho), np.cbrt(J * rho ** 2)])
    ds = 0.5 * (speed[1:] + speed[:-1]) * np.diff(u)
    vmin = np.minimum(vlc[1:], vlc[:-1])
    vlc_bound = float(np.sum(ds / vmin))
    v = vlc.copy()
    v[0] = v[-1] = 0.0
    for k in range(1, len(v)):
        v[k] = min(v[k], np.sqrt(v[k - 1] ** 2 + 2 * A * ds[k - 1]))
    for k in range(len(v) - 2, -1, -1):
        v[k] = min(v[k], np.sqrt(v[k + 1] ** 2 + 2 * A * ds[k]))
    accel_bound = float(np.sum(2 * ds / (v[1:] + v[:-1])))
    return vlc_bound, accel_bound


def metrics(csv: Path, evaluate, derivative) -> dict[str, float]:
    data = np.genfromtxt(csv, delimiter=",", names=True)
    x = np.column_stack([data["x"], data["y"]])
    u, s = data["u"], data["s"]
    steps = np.arange(len(u) - 1)
    inside = (u[steps + 1] < 1.0) & (np.diff(s) > 0)
    i = steps[inside]
    chord = np.linalg.norm(x[i + 1] - x[i], axis=1)
    scheduled = s[i + 1] - s[i]
    nodes, gauss_w = np.polynomial.legendre.leggauss(8)
    ua_i, ub_i = u[i], u[i + 1]
    grid_u = 0.5 * (ua_i + ub_i)[:, None] + 0.5 * (ub_i - ua_i)[:, None] * nodes[None, :]
    speed = np.linalg.norm(derivative(grid_u.ravel()), axis=1).reshape(grid_u.shape)
    actual = 0.5 * (ub_i - ua_i) * (speed @ gauss_w)
    fluctuation = np.abs(actual - scheduled) / scheduled
    chord_fluctuation = np.abs(chord - scheduled) / scheduled
    # chord error of every step
    lam = np.linspace(0.0, 1.0, 18)[1:-1]
    ua, ub = u[:-1], u[1:]
    grid = ua[:, None] + (ub - ua)[:, None] * lam[None, :]
    curve = evaluate(grid.ravel()).reshape(len(ua), len(lam), 2)
    p0, p1 = x[:-1], x[1:]
    seg = p1 - p0
    length2 = np.maximum(np.sum(seg * seg, axis=1), 1e-300)
    rel = curve - p0[:, None, :]
    t = np.clip(np.sum(rel * seg[:, None, :], axis=2) / length2[:, None], 0.0, 1.0)
    nearest = p0[:, None, :] + t[:, :, None] * seg[:, None, :]
    chord_error = float(np.max(np.linalg.norm(curve - nearest, axis=2)))
    # where the open-loop drift leaves the tool at the end: ahead (u reaches 1 before the schedule does, the tool
    # waits there) or behind (the schedule ends first, the tool jumps onto the last point)
    reached = int(np.argmax(u >= 1.0))
    if reached < len(u) - 1:
        drift = float(s[-1] - s[reached])  # > 0: ahead
    else:
        drift = -float(np.linalg.norm(x[-1] - x[-2]) - (s[-1] - s[-2]))  # < 0: the jump at the end
    actual_speed = np.concatenate([[0.0], np.linalg.norm(np.diff(x, axis=0), axis=1) / T])
    actual_speed[i + 1] = actual / T  # inside the curve: the arc travelled in the period
    plot_ok = np.concatenate([[False], (u[1:] < 1.0) & (np.diff(s) > 0)])
    return {"max_fluctuation": float(fluctuation.max()), "mean_fluctuation": float(fluctuation.mean()),
            "max_chord_fluctuation": float(chord_fluctuation.max()),
            "end_drift": drift, "plot_ok": plot_ok,
            "chord_error": chord_error, "time": float(data["t"][-1]), "feed": data["feed"], "s": s,
            "actual": actual_speed,
            "scheduled_step": np.concatenate([[0.0], np.diff(s) / T])}


def methods(weights: dict[str, float]) -> list[tuple[str, dict[str, float]]]:
    zero = {k: (0.0 if k.startswith(("rbf_weight", "rbf_bias")) else v) for k, v in weights.items()}
    return [
        ("1 first-order Taylor", {"method": 1}),
        ("2 second-order Taylor", {"method": 2}),
        ("3 RBF network (trained, milling_twin/training/rbf.py)", {"method": 3, **weights}),
        ("3 RBF, network output zeroed (ablation)", {"method": 3, **zero}),
        ("4 corrector on 2nd-order Taylor (default)", {"method": 4, "corrector_predictor": 2}),
        ("4 corrector on the RBF predictor", {"method": 4, "corrector_predictor": 3, **weights}),
        ("1 first-order Taylor, arc_length_feedback on", {"method": 1, "arc_length_feedback": 1.0}),
        ("2 second-order Taylor, arc_length_feedback on", {"method": 2, "arc_length_feedback": 1.0}),
        ("3 RBF network, arc_length_feedback on", {"method": 3, "arc_length_feedback": 1.0, **weights}),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15, help="runs for the cost per point (median)")
    parser.add_argument("--plot", type=Path, default=NURBS_DIR / "butterfly_feed.png")
    parser.add_argument("--weights", type=Path, default=NURBS_DIR / "butterfly_rbf_weights.toml")
    args = parser.parse_args(argv)
    if not DRIVER.is_file():
        print(f"build the driver first: cmake --build build --target interp_run ({DRIVER})", file=sys.stderr)
        return 2
    program = NURBS_DIR / "butterfly.nc"
    text = program_text()
    if not program.is_file() or program.read_text() != text:
        program.write_text(text)
        print(f"wrote {program.relative_to(REPO)}")
    points, _, _ = load_curve()
    start = {"start_x": float(points[0, 0]) / 1000.0, "start_y": float(points[0, 1]) / 1000.0}
    evaluate, spline, _ = curve_evaluator()
    vlc_bound, accel_bound = lower_bounds(evaluate, spline)
    weights = load_weights(args.weights)
    rows, curves = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, extra in methods(weights):
            params = {**LIMITS, **start, **extra}
            csv = Path(tmp) / "run.csv"
            run_driver(params, program, csv, 0)
            m = metrics(csv, evaluate, evaluate.derivative)
            _, cost = run_driver(params, program, None, args.repeat)
            rows.append((name, m, cost))
            curves[name] = m
    print(f"butterfly: F {F * 1e3:g} mm/s, A {A * 1e3:g} mm/s2, J {J * 1e3:g} mm/s3, chord error {CHORD * 1e6:g} um, "
          f"period {T * 1e3:g} ms")
    print(f"lower bounds: velocity-limit curve {vlc_bound:.3f} s, acceleration-limited {accel_bound:.3f} s\n")
    print("| method | max fluctuation | mean fluctuation | chord vs step (max) | max chord error "
          "| time (vs VLC bound / vs accel. bound) | end of curve | C cost per point |")
    print("|---|---|---|---|---|---|---|---|")
    for name, m, cost in rows:
        drift = m["end_drift"] * 1e3
        end = (f"{drift:.3f} mm ahead" if drift > 5e-4 else f"jump {-drift:.3f} mm" if drift < -5e-4 else "exact")
        print(f"| {name} | {m['max_fluctuation'] * 100:.3g} % | {m['mean_fluctuation'] * 100:.3g} % | "
              f"{m['max_chord_fluctuation'] * 100:.3g} % | "
              f"{m['chord_error'] * 1e6:.3f} um | {m['time']:.3f} s (+{(m['time'] / vlc_bound - 1) * 100:.1f} % / "
              f"+{(m['time'] / accel_bound - 1) * 100:.1f} %) | {end} | {cost:.0f} ns |")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
        taylor = curves["2 second-order Taylor"]
        corrector = curves["4 corrector on 2nd-order Taylor (default)"]
        s = corrector["s"] * 1e3
        axes[0].plot(s, corrector["scheduled_step"] * 1e3, lw=1.0, label="scheduled (step / T)")
        axes[0].plot(s, corrector["actual"] * 1e3, lw=0.6, ls="--", label="actual, corrector (arc / T)")
        axes[0].set_ylabel("feed (mm/s)")
        axes[0].legend(loc="lower right")
        axes[0].set_title("Butterfly: scheduled and actual feed along the curve")
        for name, m in (("2nd-order Taylor", taylor), ("RBF", curves["3 RBF network (trained, milling_twin/training/rbf.py)"]),
                        ("corrector", corrector)):
            ok = m["plot_ok"]
            rel = np.abs(m["actual"][ok] - m["scheduled_step"][ok]) / m["scheduled_step"][ok]
            axes[1].semilogy(m["s"][ok] * 1e3, np.maximum(rel, 1e-12) * 100, lw=0.6, label=name)
        axes[1].set_ylabel("|V - V_sched| / V_sched (%)")
        axes[1].set_xlabel("arc length (mm)")
        axes[1].legend(loc="lower right")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        print(f"\nplot: {args.plot.relative_to(REPO) if args.plot.is_relative_to(REPO) else args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

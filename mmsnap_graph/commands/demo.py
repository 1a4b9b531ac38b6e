"""``mmsnap demo``: a small, honest one-shot fusion demo (temporary main job).

Simulates a target walking a straight line through configuration B's common
area, two nodes, the measurement model of :mod:`factors.models` with the
paper's noise sigmas (seeded; no DSP, no clutter, no calibration error), and
fuses every frame twice with :func:`mmsnap_graph.oneshot.fuse_frame`: MAP with
the paper's prior and ML. It prints per-frame estimates with 1-sigma
uncertainties from the Laplace covariance and the RMSE against the truth,
next to the square root of the mean Bayesian bound. A later issue replaces
it with the full paper demo.
"""

from __future__ import annotations

import argparse

import numpy as np

from ..errors import ValidationError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="simulate a short two-node sequence (configuration B) and fuse it frame by frame",
        description="Simulate noisy range/spatial-frequency/Doppler measurements of a target "
        "walking a straight line in configuration B (paper sigmas) and print MAP and ML "
        "one-shot estimates with 1-sigma uncertainties and the RMSE against the truth.",
    )
    p.add_argument("--frames", type=int, default=12, help="frames to simulate (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default %(default)s)")
    p.add_argument(
        "--frame-period", type=float, default=0.15, dest="frame_period_s",
        help="frame period in seconds (default %(default)s, the paper's)",
    )
    p.set_defaults(func=run)


def simulate_sequence(n_frames: int, seed: int, frame_period_s: float):
    """Truth (F, 4), node poses (2, 3) and noisy measurements (F, 2, 3)."""
    from factors.models import measurement_model, wrap_angle

    from ..oneshot import MeasurementNoise
    from ..sim.networks import COMMON_AREAS, CONFIGURATIONS

    poses = np.array([CONFIGURATIONS["B"]["S1"], CONFIGURATIONS["B"]["S2"]])
    velocity = np.array([0.9, 0.4])  # m/s, a walking pace
    t = np.arange(n_frames) * frame_period_s
    # centred on the common area at mid-sequence
    start = COMMON_AREAS["B"].center_m - velocity * t[-1] / 2
    truth = np.column_stack([start + np.outer(t, velocity), np.tile(velocity, (n_frames, 1))])
    rng = np.random.default_rng(seed)
    h, _ = measurement_model(truth[:, None, :], poses[None])
    z = h + rng.normal(size=h.shape) * MeasurementNoise().sigmas
    z[..., 1] = wrap_angle(z[..., 1])  # the angle FFT measures omega in (-pi, pi]
    return truth, poses, z


def run(args: argparse.Namespace) -> int:
    from ..bounds import bayesian_bound
    from ..oneshot import GaussianPrior, fuse_frame

    if args.frames < 1:
        raise ValidationError(f"--frames must be >= 1, got {args.frames}")
    if not (np.isfinite(args.frame_period_s) and args.frame_period_s > 0):
        raise ValidationError(f"--frame-period must be > 0, got {args.frame_period_s}")
    truth, poses, z = simulate_sequence(args.frames, args.seed, args.frame_period_s)
    prior = GaussianPrior()
    print(
        f"configuration B: S1 at (0, 0, 0 deg), S2 at ({poses[1, 0]:g}, {poses[1, 1]:g}, "
        f"{np.degrees(poses[1, 2]):g} deg); {args.frames} frames of {args.frame_period_s:g} s, "
        f"seed {args.seed}"
    )
    print("simulated measurements (factors.models + Gaussian noise with the paper's sigmas);"
          " estimates +- 1 sigma (Laplace covariance)")
    header = (
        f"{'k':>3} {'truth x,y [m]':>15} {'truth vx,vy [m/s]':>18} | "
        f"{'MAP x,y +-1s [m]':>30} {'MAP vx,vy +-1s [m/s]':>30} | "
        f"{'ML x,y +-1s [m]':>30} {'ML vx,vy +-1s [m/s]':>30}"
    )
    print(header)

    def fmt(value, sigma):
        return f"{value[0]:6.2f}+-{sigma[0]:5.2f} {value[1]:6.2f}+-{sigma[1]:5.2f}"

    err = {"MAP": [], "ML": []}
    flagged = {"MAP": 0, "ML": 0}
    bounds = []
    for k in range(args.frames):
        row = f"{k:3d} {truth[k, 0]:7.2f} {truth[k, 1]:7.2f} {truth[k, 2]:9.2f} {truth[k, 3]:8.2f} |"
        for name, pr in (("MAP", prior), ("ML", None)):
            res = fuse_frame(poses, z[k], prior=pr)
            if not res.success:
                flagged[name] += 1
                row += f" {'flagged: ' + res.message[:50]:>61} |"
                continue
            err[name].append(res.state - truth[k])
            row += f" {fmt(res.state[:2], res.position_sigma_m):>30} {fmt(res.state[2:], res.velocity_sigma_mps):>30} |"
        bounds.append(bayesian_bound(truth[k], poses, prior=prior))
        print(row.rstrip(" |"))
    mean_bound = np.mean(bounds, axis=0)
    print()
    for name in ("MAP", "ML"):
        e = np.array(err[name])
        if e.size == 0:
            print(f"{name}: every frame flagged")
            continue
        rmse_p = np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))
        rmse_v = np.sqrt(np.mean(np.sum(e[:, 2:] ** 2, axis=1)))
        print(
            f"{name:3s} RMSE over {len(e)} frames: position {rmse_p:.3f} m, velocity {rmse_v:.3f} m/s"
            + (f" ({flagged[name]} frames flagged)" if flagged[name] else "")
        )
    print(
        f"sqrt of the mean Bayesian bound: position {np.sqrt(np.trace(mean_bound[:2, :2])):.3f} m, "
        f"velocity {np.sqrt(np.trace(mean_bound[2:, 2:])):.3f} m/s"
        f" (with {args.frames} frames the RMSE scatters around it by ~{100 / np.sqrt(2 * args.frames):.0f}%)"
    )
    return 0

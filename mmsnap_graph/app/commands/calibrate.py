"""``mmsnap calibrate``: self-calibration of every node of a recording.

Matches the nodes' tracks (or centroids) pairwise with a frame-lag search,
solves the pose graph anchored at the first node (S1), refines with the joint
calibration graph when every node has one centroid per frame, prints the
poses (degrees here only), writes the calibration JSON and stores the poses
and a ``/calibration`` group in the recording (atomically). Every node's
measurement noise is estimated from the data at the calibrated poses, printed
component by component (estimated, or not identified and what is used
instead) and stored as the ``/noise`` group (:mod:`mmsnap_graph.io.noise`),
which ``mmsnap fuse`` uses by default. Then the covariance self-check without
truth (docs/ROBUST.md): the recording fused as ``mmsnap fuse`` would fuse it
with what was just stored (into a temporary copy: nothing else is written),
its verdict printed, loud on stderr when the sigmas or poses make the
covariances wrong (``--no-self-check``: skipped; with ``--no-write`` there is
nothing stored to check).

The track-matching thresholds (seconds and metres) come from their defaults,
then the ``[matching]`` table of ``--config FILE`` (the TOML file of
``mmsnap process --config``; its other tables are ignored here), then the
explicit options; ``--show-config`` prints the effective table.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from mmsnap_graph._atomic import check_output_path
from mmsnap_graph.app.commands.file_rules import add_overwrite
from mmsnap_graph.app.runs import calibrate_and_store, calibration_json_path
from mmsnap_graph.calibration.pairwise.matching_options import MatchingOptions
from mmsnap_graph.errors import ConfigurationError, ValidationError

from .arguments import add_self_check_argument, say_self_check

#: Matching options: MatchingOptions field -> (metavar, help).
MATCHING_OPTIONS = {
    "max_lag_s": ("SECONDS", "largest clock lag between nodes to search, in seconds (whole "
                             "frames)"),
    "min_common_s": ("SECONDS", "a track pair must share this long (and at least 5 frames)"),
    "min_spread_m": ("METRES", "the shared target must move this far in each node's tracks"),
    "max_rmse_m": ("METRES", "largest track RMSE of a matched pair"),
    "inlier_gate_m": ("METRES", "a frame pair supports a pose within this distance (tracks "
                                "without covariances: centroids)"),
    "gate_probability": ("P", "the same with track covariances on both sides (EKF tracks): "
                              "chi-square(2) gate probability"),
}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="self-calibrate the node poses from a common moving target",
        description="Estimate every node's pose in S1's frame from the tracks (or centroids) of "
                    "a target seen by several nodes: pairwise closed form (paper eqs. 11-14) "
                    "with frame-lag search, pose graph, joint refinement on the raw centroid "
                    "measurements. Prints the poses with headings in degrees; writes JSON (radians) and updates the recording's node poses and "
                    "/calibration group.")
    p.add_argument("recording", nargs="?", default=None,
                   help="HDF5 recording (docs/FORMAT.md); not needed with --show-config")
    p.add_argument("--source", choices=["auto", "tracks", "centroids"], default="auto",
                   help="local positions to match: EKF tracks when present (auto), or "
                        "centroids (default %(default)s)")
    p.add_argument("--method", choices=["auto", "joint", "pose_graph"], default="auto",
                   help="refine with the joint graph when the centroids allow (auto), always "
                        "(joint), or stop at the pose graph (default %(default)s)")
    p.add_argument("--config", metavar="FILE", default=None,
                   help="TOML file: its [matching] table sets the options below (the file of "
                        "mmsnap process --config; its other tables are ignored here)")
    p.add_argument("--show-config", action="store_true",
                   help="print the effective [matching] table (defaults, --config, options) "
                        "and exit")
    for name, (metavar, text) in MATCHING_OPTIONS.items():
        flags = ["--" + name.replace("_", "-")]
        if name == "max_rmse_m":
            flags.append("--max-rmse")
        p.add_argument(*flags, dest=name, type=float, default=None, metavar=metavar,
                       help=f"{text}; overrides the file (default "
                            f"{getattr(MatchingOptions(), name):g})")
    p.add_argument("--sigmas", type=float, nargs=3,
                   metavar=("RANGE_M", "OMEGA_RAD", "DOPPLER_MPS"),
                   default=None, help="OMEGA_RAD is the sigma of omega = pi sin(theta), a phase in "
                                      "radians, not an angle; centroid noise for the joint graph (default: "
                                      "estimated from the data; the /noise group is "
                                      "estimated from the data either way)")
    p.add_argument("--robust", choices=["cauchy", "huber", "none"], default="cauchy",
                   help="robust kernel of the joint graph (default %(default)s)")
    p.add_argument("--sigma-a", type=float, default=3.0, metavar="SIGMA_A_MPS2",
                   help="white-acceleration sigma of the joint graph's constant-velocity "
                        "factors (default %(default)s m/s^2)")
    p.add_argument("--no-motion", action="store_true",
                   help="no constant-velocity factors in the joint graph (and no clock offsets)")
    p.add_argument("--no-time-offsets", action="store_true",
                   help="whole-frame lags only: do not estimate each node's clock offset "
                        "(a fraction of a frame) in the joint graph")
    # Either the range offset is estimated (--range-offset) or its rms is
    # considered in the covariance (--range-offset-rms), never both.
    depth = p.add_mutually_exclusive_group()
    depth.add_argument("--range-offset", default=None, metavar="MEAN_M,SIGMA_M",
                       help="estimate a range offset common to every node, the body's "
                            "reflection depth (each radar's centroid nearer to it than the "
                            "body's centre), with this prior, e.g. 0.10,0.05; `mmsnap fuse` "
                            "then adds it to every range (default: none)")
    depth.add_argument("--range-offset-rms", type=float, default=None, metavar="METRES",
                       help="not with --range-offset (which estimates it): the root mean "
                            "square of the body's reflection depth that the poses may have "
                            "taken in, added to their covariance along the direction it moves "
                            "them (default 0.112 m: 0.10 +- 0.05 m; not added where the "
                            "recording declares point targets, the simulator's clean model; "
                            "0: not added)")
    p.add_argument("--covariance", choices=["long_run", "model"], default="long_run",
                   help="pose covariance: long_run (default) widens the joint graph's "
                        "marginals where the frames' errors are correlated in time or the "
                        "model is not exact; model keeps the marginals")
    p.add_argument("--window-s", type=float, default=None, metavar="SECONDS",
                   help="calibrate window by window, windows of SECONDS read from the file in "
                        "turn and their poses combined: memory bounded by one window, not by "
                        "the recording (default: windows of 600 s for a recording longer than "
                        "20 minutes, else one solve; inf: one solve always)")
    p.add_argument("--json-out", default=None, metavar="PATH",
                   help="write the calibration JSON here (default: "
                        "<recording>.calibration.json; angles in radians); an existing file, "
                        "the default one included, is replaced only with --overwrite")
    p.add_argument("--json", action="store_true",
                   help="print the calibration JSON to stdout instead of the table (angles in "
                        "radians, as in the file); the JSON file is written either way")
    p.add_argument("-o", "--output", default=None,
                   help="write a copy of the recording here instead of updating it")
    p.add_argument("--no-write", action="store_true",
                   help="do not touch the recording (JSON only)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (the bar, over the steps, is drawn on stderr when it is "
                        "a terminal)")
    add_self_check_argument(p)
    add_overwrite(p)
    p.set_defaults(func=run)


#: Units of the three noise components, in MeasurementNoise order.
_NOISE_UNITS = (("range", "m"), ("omega", "rad"), ("doppler", "m/s"))


def noise_lines(noise) -> list[str]:
    """A :class:`~mmsnap_graph.data.noise.NoiseEstimate` as lines a radar
    engineer reads: one sigma a line with its unit, where it came from, the
    heavy-tail factor, and for a sigma the data cannot pin down, why and the
    value used instead."""
    lines = ["measurement noise per node, estimated from the data (1-sigma; `mmsnap fuse` "
             "uses it once stored as /noise):",
             "  omega = pi sin(theta) is the phase step between receive antennas (rad), not "
             "the angle theta",
             "  estimators: network = residuals between nodes at the calibrated poses; "
             "temporal = differences along each node's own centroid sequence"]
    tails_said = missing = False
    for name, e in noise.nodes.items():
        lines.append(f"  {name} (estimator: {e.method}):")
        for i, (comp, unit) in enumerate(_NOISE_UNITS):
            value = f"{comp:<8}{e.noise.sigmas[i]:.4g} {unit}"
            if e.identified[i]:
                text = f"    {value}: estimated from {e.n_residuals[i]} residuals"
                if round(e.tail_factors[i], 2) != 1.0:
                    text += f", x{e.tail_factors[i]:.2f} for heavy tails"
                    tails_said = True
            else:
                text = (f"    {value}: NOT identified, the data cannot pin it down; this "
                        f"fallback value is used instead\n      why: {e.reasons[i]}")
                missing = True
            lines.append(text)
    if tails_said:
        lines.append("  heavy tails: the residuals hold more large values (multipath, a limb "
                     "taken for the torso) than a Gaussian of the core spread; the sigma is "
                     "raised by this factor so that its variance matches them all")
    if missing:
        lines.append("  dof: degrees of freedom, the independent residuals left after the fit "
                     "(how much data the sigma rests on)")
    return lines


def _frames_text(nodes, fractions, z) -> str:
    return ", ".join(f"{n} {f:+.2f} frame (z {v:.1f})" for n, f, v in zip(nodes, fractions, z))


def _sigmas_text(sigmas, identified=None) -> str:
    parts = []
    for i, (comp, unit) in enumerate(_NOISE_UNITS):
        said = "" if identified is None else (" estimated" if identified[i]
                                              else " NOT identified (fallback)")
        parts.append(f"{comp} {sigmas[i]:.3g} {unit}{said}")
    return ", ".join(parts)


def _pose_graph_text(f) -> str:
    how = " (between factors of the pairwise poses)"
    if f.solve == "points":
        tau = (f", covariance x{f.autocorrelation_factor:.3g} for residuals correlated in time"
               if f.autocorrelation_factor > 1.05 else "")
        how = f" (joint least squares on the matched points{tau})"
    return f"pose graph: {f.n_nodes} node(s) calibrated from {f.n_edges} edge(s){how}"


def _joint_noise_text(f) -> str:
    if f.source == "temporal":
        return ("sigmas for the joint graph, from each node's own centroid sequence: "
                + _sigmas_text(f.sigmas, f.identified))
    said = "from its residuals" if f.source == "residuals" else "as given"
    return f"sigmas for the joint graph, {said}: " + _sigmas_text(f.sigmas)


def _clock_text(f) -> str:
    text = _frames_text(f.nodes, f.fractions, f.z)
    return {
        "no_start": "clock offsets: whole-frame lags (no successful joint solve to start from)",
        "solve_failed": f"clock offsets: whole-frame lags (the timed solve failed: "
                        f"{f.solve_status.message})",
        "beyond_half_frame": f"clock offsets: whole-frame lags kept (a fraction beyond half a "
                             f"frame contradicts the lag search: {text})",
        "not_determined": f"clock offsets: whole-frame lags kept (no fraction determined by the "
                          f"data, z < {f.evidence_z:g}: {text})",
        "estimated": f"clock offsets beyond the lags: {text}",
    }[f.outcome]


def _joint_fit_text(f) -> tuple[str, ...]:
    gn = f"{f.iterations} GTSAM Gauss-Newton/LM step(s)"
    if f.presolve_steps:
        steps = "+".join(str(n) for n in f.presolve_steps)
        gn = (f"numpy pre-solve {steps} step(s) ("
              + ("converged), then " + gn + " confirming its optimum" if f.presolve_converged
                 else "NOT converged: GTSAM continued), then " + gn))
    fit = (f"joint calibration of {f.n_nodes} nodes on {f.n_frames} frames, {f.n_outliers} "
           f"outlier detection(s), {gn}")
    return (fit,) + ((f"{f.turns} sharp turn(s) left out of the motion factors",)
                     if f.turns else ())


def _covariance_text(f) -> str | tuple[str, ...]:
    if f.method == "schur":
        text = f"covariance: a dense Schur complement ({f.failure})"
    elif f.method == "marginals":
        text = "covariance: the graph's marginals" + (f" ({f.failure})" if f.failure else "")
    elif f.max_widening <= 1.0:
        text = (f"covariance: the graph's marginals (the long-run covariance over "
                f"{f.bandwidth_frames} frames is within their sampling noise)")
    else:
        text = (f"covariance: long-run over {f.bandwidth_frames} frames (errors correlated in "
                f"time or model error), variances widened up to x{f.max_widening:.1f}")
    if f.reflection_depth_rms_m > 0:
        alone = (f"the data alone fix it to +- {f.depth_data_sigma_m:.3f} m; "
                 if f.depth_data_sigma_m > 0 else "")
        text += (f"; plus a reflection depth of {f.reflection_depth_rms_m:.3f} m rms that the "
                 f"poses cannot tell from the geometry ({alone}not estimated: --range-offset "
                 f"does)")
        s = np.reshape(f.without_depth_sigmas, (-1, 3))
        if len(f.without_depth_nodes) and s.shape[0] == len(f.without_depth_nodes):
            return (text, "1-sigma without the depth, what sessions of one walker and a "
                          "recording's halves scatter by (the depth is common to them): "
                    + ", ".join(f"{n} ({a:.3f} m, {b:.3f} m, {np.degrees(c):.2f} deg)"
                                for n, (a, b, c) in zip(f.without_depth_nodes, s)))
    return text


def _lag_evidence_text(f) -> str:
    head = f"{f.node_a}-{f.node_b}: lag {f.lag_frames} frames"
    if f.outcome == "determined":
        return f"{head} determined by the data (z = {f.z:.1f})"
    if f.outcome == "untested":
        return f"{head} NOT tested against lag 0 (too few frames at both lags): kept"
    if f.outcome == "window_edge":
        inner = f.lag_frames - int(np.sign(f.lag_frames))
        what = (f"z = {f.z:.1f}, but at the edge of the +-{f.window_frames}-frame window it "
                f"does not beat lag {inner} by z >= {f.evidence_z:g}: the fit may improve "
                f"further out")
    else:
        what = ("too few frames to tell" if not np.isfinite(f.z)
                else f"z = {f.z:.1f} < {f.evidence_z:g}")
    return f"{head} not determined by the data ({what} against lag 0 on the same tracks): " \
           f"lag 0 kept"


def _lag_cover_text(f) -> str:
    if not f.tested:
        return (f"{f.node_a}-{f.node_b}: lag not determined (other lags fit about as well "
                f"with other poses): the covariance covers their spread")
    return (f"{f.node_a}-{f.node_b}: lag not determined by the track matching; the joint "
            f"graph's clock offset ({f.clock_fraction:+.2f} +- {f.clock_sigma:.2f} frames) or "
            f"its centroids reject the shifts {list(f.rejected_shifts)} frames (z >= "
            f"{f.evidence_z:g}); the covariance covers the poses of "
            f"{list(f.kept_shifts) if f.kept_shifts else 'none'}")


def _disputed_text(f) -> str:
    return ("the track matching's lags not determined by the data (the joint graph's clock "
            "offsets contradict them: " + ", ".join(
                f"{n} lag {lag} frames, {fr:+.2f} +- {sd:.2f} frames beyond it"
                for n, lag, fr, sd in zip(f.nodes, f.lags, f.fractions, f.sigmas))
            + "): lag 0 kept")


def _not_observable_text(f) -> str:
    dirs = ", ".join("(" + ", ".join(f"{c:+.2f}" for c in d) + ")" for d in f.directions)
    return f"pose of {f.node} is not observable along {dirs} (dx_b, dy_b, dphi)"


def _noise_fact_text(f) -> str:
    unit = dict(_NOISE_UNITS)[f.component]
    return (f"noise: {f.node} {f.component} not identified at the calibrated poses, "
            f"{f.sigma:.4g} {unit} used" + (f" ({f.reason})" if f.reason else ""))


#: fact kind -> its words (one line, or a tuple of lines).
_FACT_TEXT = {
    "pose_graph_fit": _pose_graph_text,
    "targets_associated": lambda f: (f"several centroids per frame: {f.n_targets} target "
                                     f"tracks, {f.n_states} (frame, target) states"),
    "joint_noise": _joint_noise_text,
    "clock_offsets_tried": _clock_text,
    "joint_fit": _joint_fit_text,
    "robust_pass_failed": lambda f: (f"Gaussian factors: the robust pass failed "
                                     f"({f.status.message})"),
    "pose_covariance": _covariance_text,
    "range_offset_estimated": lambda f: (
        f"range offset (reflection depth) {f.offset_m:.3f} +- "
        f"{np.sqrt(f.variance_m2):.3f} m (prior {f.prior_mean_m:.2f} +- "
        f"{f.prior_sigma_m:.2f} m)"),
    "pose_not_observable": _not_observable_text,
    "solve_broke_down": lambda f: f"the {f.step.replace('_', ' ')} solve broke down: {f.reason}",
    "joint_skipped": lambda f: ("joint refinement skipped: no centroids of a common target "
                                "could be associated across nodes"
                                + (f" ({f.association_error})" if f.association_error else "")),
    "joint_rejected": lambda f: (f"kept the pose-graph poses: the joint refinement ended with "
                                 f"'{f.status.message}'"),
    "lag_evidence": _lag_evidence_text,
    "lag_not_determined": _lag_cover_text,
    "lags_disputed": _disputed_text,
    "noise_not_identified": _noise_fact_text,
    "windows_combined": lambda f: (
        (f"calibrated window by window: {f.n_combined} of {f.n_windows} windows of "
         f"{f.window_s:g} s combined (the poses are static: information form; the reflection "
         f"depth and lag covers not averaged down); the windows' spread chi2 "
         f"{f.spread_chi2:.1f} over {f.spread_dof} dof"
         + (f": covariance widened x{f.spread_factor:.2f}" if f.spread_factor > 1 else "")
         + "; the facts below are the first combined window's",)
        + tuple(f"  window left out: {w}" for w in f.skipped)),
}


def fact_lines(fact) -> list[str]:
    """One calibration fact (:mod:`mmsnap_graph.data.calibration_facts`) in
    words, one line per clause."""
    text = _FACT_TEXT[fact.kind](fact)
    return list(text) if isinstance(text, tuple) else [text]


def fact_text(fact) -> str:
    """One calibration fact in words, on one line."""
    return "; ".join(fact_lines(fact))


def format_table(cal) -> str:
    """The calibration as text, one fact a line: the poses with their
    1-sigma uncertainties (angles in degrees), the clock offsets, the
    pairwise fits, the noise (:func:`noise_lines`), the status and the
    facts (:func:`fact_text`)."""
    lines = [f"reference {cal.reference} (at 0, 0, 0); method {cal.method}; source {cal.source}",
             "poses in the reference's frame: x, y in metres, heading phi (the array axis) in "
             "degrees; s*: 1-sigma; lag: whole frames; offset: clock offset to the reference",
             f"{'node':<8}{'x_m':>9}{'y_m':>9}{'phi_deg':>10}{'sx_m':>9}{'sy_m':>9}"
             f"{'sphi_deg':>10}{'lag':>5}{'offset_ms':>11}{'s_ms':>7}"]
    for n in cal.node_names:
        if n not in cal.poses:
            lines.append(f"{n:<8}{'not calibrated (no path to ' + cal.reference + ')':>60}")
            continue
        x, y, phi = cal.poses[n]
        sd = np.sqrt(np.clip(np.diag(cal.covariances[n]), 0, None))
        tau = 1e3 * float(cal.time_offset_s.get(n, np.nan))
        s_tau = 1e3 * np.sqrt(max(float(cal.time_offset_variances.get(n, np.nan)), 0.0))
        lines.append(f"{n:<8}{x:9.3f}{y:9.3f}{np.degrees(phi):10.2f}{sd[0]:9.3f}{sd[1]:9.3f}"
                     f"{np.degrees(sd[2]):10.3f}{cal.lag_frames.get(n, 0):5d}{tau:11.1f}"
                     f"{s_tau:7.1f}")
    lines.extend(_mounting_lines(cal))
    if np.isfinite(cal.range_offset_m):
        lines.append(f"range offset (reflection depth): {cal.range_offset_m:.3f} +- "
                     f"{np.sqrt(cal.range_offset_variance):.3f} m (added to every range by "
                     f"`mmsnap fuse`)")
    if cal.edges:
        lines.append("pairwise closed form (track RMSE, paper eq. 14):")
        for e in cal.edges:
            lines.append(f"  {e.node_a}-{e.node_b}: RMSE {e.rmse_m:.3f} m over {e.n_frames} "
                         f"frames, lag {e.lag_frames} frames")
    for k, v in cal.failures.items():
        lines.append(f"  {k}: {v}")
    if cal.noise is not None:
        lines.extend(noise_lines(cal.noise))
    lines.append(("ok: " if cal.success else "INCOMPLETE: ") + cal.status.message)
    # With the noise estimate printed above, its unidentified components are said there.
    said = ("noise_not_identified",) if cal.noise is not None else ()
    lines.extend("  " + line for f in cal.facts if f.kind not in said for line in fact_lines(f))
    return "\n".join(lines)


def _mounting_lines(cal) -> list[str]:
    """Each calibrated node's 1-sigma against a physical mounting (a tape):
    the covariance with every radar's uncompensated angle bias considered
    (:mod:`mmsnap_graph.calibration.angle_bias`)."""
    from mmsnap_graph.calibration.angle_bias import ANGLE_BIAS_RMS_RAD, mounting_covariance

    rows = []
    for n in cal.node_names:
        if n == cal.reference or n not in cal.poses or not np.any(cal.covariances[n]):
            continue
        sd = np.sqrt(np.clip(np.diag(mounting_covariance(cal.poses[n], cal.covariances[n])),
                             0, None))
        rows.append(f"  {n}: ({sd[0]:.3f} m, {sd[1]:.3f} m, {np.degrees(sd[2]):.2f} deg)")
    if not rows:
        return []
    return [f"1-sigma against a physical mounting (a tape), with each radar's uncompensated "
            f"angle bias ({np.degrees(ANGLE_BIAS_RMS_RAD):.0f} deg rms) that the calibration "
            f"takes as its heading, as fusion needs it:"] + rows


def effective_matching(args: argparse.Namespace) -> MatchingOptions:
    """Defaults, then the ``[matching]`` table of ``--config``, then the
    explicit options (a bad one is named as its option)."""
    # Here: the config module imports the signal chain (SciPy, scikit-learn),
    # which building the parser (`mmsnap --help`) must not.
    from mmsnap_graph.app.config_file import read_matching_config

    cfg = MatchingOptions() if args.config is None else read_matching_config(args.config)
    for name in MATCHING_OPTIONS:
        value = getattr(args, name)
        if value is None:
            continue
        try:
            cfg = dataclasses.replace(cfg, **{name: value})
        except (ConfigurationError, ValidationError) as exc:
            raise ValidationError(f"--{name.replace('_', '-')}: {exc}") from None
    return cfg


def run(args: argparse.Namespace) -> int:
    from mmsnap_graph.app.config_file import matching_config_to_toml

    matching = effective_matching(args)
    if args.show_config:
        sys.stdout.write(matching_config_to_toml(matching))
        return 0
    if args.recording is None:
        raise ValidationError("mmsnap calibrate: a recording is required (unless --show-config)")
    # Here: `mmsnap --help` does not import GTSAM or h5py.
    from mmsnap_graph.calibration import JOINT_OPTIONS_BY_TARGETS, joint_options_for
    from mmsnap_graph.data.noise import MeasurementNoise

    noise = None
    if args.sigmas is not None:
        r, w, v = args.sigmas
        noise = MeasurementNoise(range_m=r, omega_rad=w, doppler_mps=v)
    prior = _range_offset_prior(args.range_offset)

    def joint_options(base):
        """``base`` (the recording's default) with this command's flags."""
        try:
            joint = dataclasses.replace(
                base, robust=None if args.robust == "none" else args.robust,
                motion=not args.no_motion, sigma_a_mps2=args.sigma_a,
                time_offsets=not args.no_time_offsets)
        except ValidationError as exc:
            raise ValidationError(f"--sigma-a: {exc}") from None
        rms = joint.range_offset_rms_m if args.range_offset_rms is None else args.range_offset_rms
        try:
            return dataclasses.replace(joint, covariance=args.covariance,
                                       range_offset_prior_m=prior,
                                       range_offset_rms_m=rms if rms else None)
        except ValidationError as exc:
            raise ValidationError(f"--range-offset-rms: {exc}") from None

    for base in JOINT_OPTIONS_BY_TARGETS.values():  # the flags checked before anything is read
        joint_options(base)
    json_path = check_output_path(args.json_out if args.json_out else
                                  calibration_json_path(args.recording))
    if args.output is not None and not args.no_write:
        check_output_path(args.output)

    def options(rec) -> dict:
        return dict(source=args.source, method=args.method, noise=noise, matching=matching,
                    joint=joint_options(joint_options_for(rec)))

    # With --json, stdout holds the calibration JSON alone; the words go to stderr.
    say = (lambda text: print(text, file=sys.stderr)) if args.json else print
    cal, written = calibrate_and_store(args.recording, options, output=args.output,
                                       json_path=json_path, write=not args.no_write,
                                       on_result=lambda c: say(format_table(c)),
                                       progress=not args.no_progress and sys.stderr.isatty(),
                                       overwrite=args.overwrite, window_s=args.window_s)
    if args.json:
        sys.stdout.write(Path(written[0]).read_text(encoding="utf-8"))
    say(f"wrote {written[0]}")
    if not args.no_write:
        say(f"wrote {written[1]}: node poses, /calibration and /noise")
        if not args.no_self_check and cal.success:
            say_self_check("calibrate", stored_self_check(written[1]),
                           sys.stderr if args.json else sys.stdout)
    return 0 if cal.success else 1


def stored_self_check(path):
    """The covariance self-check of ``path`` fused with its stored
    calibration and noise (``mmsnap fuse``'s defaults), into a temporary
    copy; None when nothing could be fused."""
    import tempfile

    from mmsnap_graph.app.runs import fuse_stored
    from mmsnap_graph.errors import MmsnapError

    with tempfile.TemporaryDirectory(prefix="mmsnap-selfcheck-") as tmp:
        try:
            fused, _ = fuse_stored(path, output=Path(tmp) / "fused.h5", progress=False)
        except MmsnapError as exc:
            print(f"mmsnap calibrate: covariance self-check not run: {exc}", file=sys.stderr)
            return None
    return fused.consistency


def _range_offset_prior(text: str | None):
    """``--range-offset MEAN_M,SIGMA_M`` as a pair (None when not given)."""
    if text is None:
        return None
    try:
        mean, sigma = (float(v) for v in text.split(","))
    except ValueError:
        raise ValidationError(f"--range-offset must be MEAN_M,SIGMA_M (e.g. 0.10,0.05), got "
                              f"{text!r}") from None
    if not (np.isfinite(mean) and abs(mean) <= 1.0 and np.isfinite(sigma) and sigma > 0):
        raise ValidationError(f"--range-offset {text!r}: the mean must be metres within +-1 m "
                              f"and the sigma > 0 m (e.g. 0.10,0.05; centimetres given as "
                              f"metres?)")
    return mean, sigma

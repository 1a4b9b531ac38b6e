"""argparse types shared by the sub-commands: ``NAME=VALUES`` options (a
node name and its numbers, e.g. a pose ``S2=0,7,180``)."""

from __future__ import annotations

import argparse
import sys
import warnings
from typing import Callable

import numpy as np

from mmsnap_graph.errors import MmsnapWarning, ValidationError

__all__ = ["named_values", "named_pose", "solver_choice", "check_sigmas", "SIGMA_LIMITS",
           "HEADING_HELP", "looks_like_radians", "FUSE_DEFAULTS", "add_fusion_arguments",
           "fusion_settings", "fusion_config", "config_text", "add_calibration_arguments",
           "calibration_for", "bounds_value"]


#: The heading convention, stated by every option that takes a node pose.
HEADING_HELP = ("PHI is the heading in degrees: the direction of the antenna array axis (TI's "
                "x axis, along the board); the radar looks along its boresight, PHI + 90 deg "
                "(docs/CONVENTIONS.md)")


def looks_like_radians(value: float, text: str) -> bool:
    """Whether a value typed where degrees are asked looks like radians: not
    zero, not whole, within +-2 pi, and written with three decimals or more
    (``1.5708``) or within 0.01 of a multiple of pi/12 (``3.14``, ``0.785``)."""
    if value == 0 or float(value).is_integer() or abs(value) > 2 * np.pi + 0.01:
        return False
    mantissa = text.strip().lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    round_angle = np.min(np.abs(abs(value) - np.pi / 12 * np.arange(1, 25))) < 0.01
    return decimals >= 3 or bool(round_angle)


def named_values(kind: str, n_values: int | None,
                 degrees: tuple[int, ...] = ()) -> Callable[[str], tuple[str, object]]:
    """argparse type for ``NAME=V1,V2,...`` with ``n_values`` numbers ->
    ``(name, [floats])``; ``n_values`` None: one string value -> ``(name,
    str)``. ``kind`` names the values in the error (``X_M,Y_M,PHI_DEG``).
    ``degrees`` : the indices of values in degrees; one that looks like
    radians (:func:`looks_like_radians`) warns (:class:`MmsnapWarning`)."""
    def parse(text: str):
        name, sep, rest = text.partition("=")
        if not sep or not name or not rest:
            raise argparse.ArgumentTypeError(f"{text!r} must look like NAME={kind}")
        if n_values is None:
            return name, rest
        try:
            values = [float(v) for v in rest.split(",")]
        except ValueError:
            values = []
        if len(values) != n_values:
            raise argparse.ArgumentTypeError(f"{text!r} must look like NAME={kind}")
        names = kind.split(" ")[0].split(",")
        for k in degrees:
            if looks_like_radians(values[k], rest.split(",")[k]):
                warnings.warn(f"{text!r}: {names[k]}={values[k]:g} looks like radians "
                              f"({values[k]:g} rad = {np.degrees(values[k]):.4g} deg); this "
                              "option takes degrees", MmsnapWarning, stacklevel=2)
        return name, values
    return parse


def named_pose(text: str) -> tuple[str, list[float]]:
    """argparse type for a node pose ``NAME=X_M,Y_M,PHI_DEG`` -> ``(name,
    [x_m, y_m, phi_rad])`` (degrees on the command line, radians inside)."""
    name, (x, y, phi_deg) = named_values("X_M,Y_M,PHI_DEG (e.g. S2=0,7,180)", 3,
                                         degrees=(2,))(text)
    return name, [x, y, float(np.deg2rad(phi_deg))]


def solver_choice(allowed: tuple[str, ...]) -> Callable[[str], str]:
    """argparse type for ``--solver``: one of ``allowed`` (names of
    :data:`mmsnap_graph.fusion.solvers.settings.SOLVERS`); a former name
    (``batch``, ``numpy``) is refused naming the one that replaced it."""
    def parse(text: str) -> str:
        from mmsnap_graph.errors import MmsnapWarning, ValidationError
        from mmsnap_graph.fusion.solvers.settings import check_solver

        try:
            return check_solver(text, allowed, what="--solver")
        except ValidationError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = "solver"
    return parse


#: Largest plausible measurement sigma of each component of ``--sigmas``, and
#: the unit mistake a larger value most likely is. The spatial frequency
#: omega = pi sin(theta) lies within +-pi, so its sigma cannot exceed pi.
SIGMA_LIMITS = (
    ("range_m", 10.0, "metres: centimetres or millimetres typed?"),
    ("omega_rad", float(np.pi), "radians of the spatial frequency omega = pi sin(theta), "
                                "within +-pi: degrees typed?"),
    ("doppler_mps", 50.0, "m/s: km/h or cm/s typed?"),
)


def check_sigmas(values) -> None:
    """``--sigmas RANGE_M OMEGA_RAD DOPPLER_MPS``: three finite sigmas > 0,
    each within :data:`SIGMA_LIMITS`; else :class:`ValidationError` naming
    the flag, the component and the likely unit mistake."""
    for value, (name, limit, unit) in zip(values, SIGMA_LIMITS):
        if not (np.isfinite(value) and value > 0):
            raise ValidationError(f"--sigmas: {name} must be finite and > 0, got {value!r}")
        if value > limit:
            raise ValidationError(f"--sigmas: {name}={value:g} is more than {limit:.4g}, the "
                                  f"largest plausible sigma, in {unit}")


# ----------------------------------------------------------------------------
# The fusion flags of `mmsnap fuse`, `mmsnap batch` and `mmsnap replay`
# ----------------------------------------------------------------------------

#: Each fusion setting's default: what a flag not given and a ``[fuse]`` key
#: not in the ``--config`` file leave (:func:`fusion_config`). The same
#: settings as :data:`mmsnap_graph.fusion.config.DEFAULT_CONFIG`.
FUSE_DEFAULTS: dict[str, object] = {
    "mode": "map", "covariance": "laplace", "solver": "vectorized", "source": "centroids",
    "gate": 0.999, "grid_points": 21, "robust": "gate", "motion_check": True,
    "coverage_check": True, "placement_check": True, "body_merge": True, "body_check": True, "learned_walls": True,
    "in_front": False, "bounds": None, "bounds_cfg": None,
}


def _bounds(text: str) -> tuple[float, float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f"--bounds {text!r} must look like XMIN,XMAX,YMIN,YMAX "
                                         "in metres (e.g. -2,1.6,0,3.6)")
    return values


#: The ``--bounds XMIN,XMAX,YMIN,YMAX`` parser, for every verb that takes a room box.
bounds_value = _bounds


def _off(group, flag: str, dest: str, text: str) -> None:
    """A ``--no-...`` switch whose absence leaves the file's or the default value."""
    group.add_argument(flag, dest=dest, action="store_const", const=False, default=None,
                       help=text)


def add_fusion_arguments(p: argparse.ArgumentParser, *, solvers: tuple[str, ...],
                         default_solver: str = "vectorized") -> None:
    """The fusion flags (one :class:`~mmsnap_graph.fusion.config.FusionConfig`)
    of ``mmsnap fuse``, ``mmsnap batch`` and ``mmsnap replay``, and ``--config``."""
    from mmsnap_graph.data.body import CENTROID_MERGE_RADIUS_M

    p.set_defaults(default_solver=default_solver)
    g = p.add_argument_group("fusion (every flag also a key of the --config file's [fuse] "
                             "table)")
    g.add_argument("--config", dest="fuse_config", metavar="FILE.toml", default=None,
                   help="a TOML file whose [fuse] table sets these options (a flag given "
                        "wins; docs/how-to/fuse.md)")
    g.add_argument("--mode", choices=["map", "ml"], default=None,
                   help="MAP with the paper's prior, or maximum likelihood (default map)")
    g.add_argument("--covariance", choices=["laplace", "grid"], default=None,
                   help="Laplace (inverse information) or the paper's grid posterior "
                        "covariance (slow) (default laplace)")
    g.add_argument("--solver", type=solver_choice(solvers), default=None,
                   metavar="{" + ",".join(solvers) + "}",
                   help=f"the solver of each target (default {default_solver}; "
                        "docs/STREAMING.md)")
    g.add_argument("--source", choices=["centroids", "point_cloud"], default=None,
                   help="detections to fuse (default centroids)")
    g.add_argument("--gate", type=float, default=None,
                   help="association gate probability for several targets (default 0.999)")
    g.add_argument("--grid-points", type=int, default=None,
                   help="grid points per axis for --covariance grid (default 21)")
    g.add_argument("--robust", choices=["gate", "huber", "cauchy", "none"], default=None,
                   help="robust one-shot fusion: leave out a node whose residual fails the "
                        "chi-square gate (gate), or down-weight it (huber, cauchy); none = "
                        "plain least squares, and neither motion check nor body merge (default gate)")
    _off(g, "--no-motion-check", "motion_check",
         "do not check each fused target against the motion of the neighbouring frames "
         "(default: a target no neighbouring frame confirms is refitted without the nodes "
         "that disagree, or flagged; docs/ROBUST.md)")
    _off(g, "--no-coverage-check", "coverage_check",
         "with the motion check: keep a target that a radar whose field of view covers it "
         "does not see in the frames around (default: flagged, status 10: a multipath image)")
    _off(g, "--no-placement-check", "placement_check",
         "keep a target seen by one radar alone that no walk ties to a target seen by two "
         "(default: flagged, status 10: one radar cannot tell a person from a multipath image "
         "where no other radar looks)")
    _off(g, "--no-body-merge", "body_merge",
         "fuse each of a node's centroids of a frame closer than the merge radius "
         f"({CENTROID_MERGE_RADIUS_M:g} m) on its own (default: merged into one, as one body "
         "split into clusters)")
    _off(g, "--no-body-check", "body_check",
         "keep fused targets of a frame closer than a body's width (default: the one seen by "
         "fewer nodes is flagged, status 12)")
    _off(g, "--no-learned-walls", "learned_walls",
         "keep fused targets beyond the walls learned from the radars' multipath images "
         "(default: flagged, status 11, when no room box is given; docs/ROBUST.md)")
    g.add_argument("--in-front", action="store_const", const=True, default=None,
                   help="the radars hang on the room's walls, facing in: a fused target behind "
                        "any radar is outside the room and flagged (status 11)")
    box = g.add_mutually_exclusive_group()
    box.add_argument("--bounds", type=_bounds, default=None, metavar="XMIN,XMAX,YMIN,YMAX",
                     help="the room box in the reference frame (m): fused targets outside it "
                          "are flagged (status 11; e.g. reflections via a wall)")
    box.add_argument("--bounds-cfg", default=None, metavar="FILE.cfg",
                     help="the reference radar's people-tracking .cfg: its boundaryBox is the "
                          "room box, and a target standing still outside its "
                          "staticBoundaryBox is flagged (docs/ROBUST.md)")


def fusion_settings(args: argparse.Namespace) -> dict[str, object]:
    """Each fusion setting: the flag when given, else the ``--config`` file's
    ``[fuse]`` key, else :data:`FUSE_DEFAULTS` (the solver: the verb's)."""
    table = {}
    if args.fuse_config:
        # Here: the config module brings the signal chain's (scikit-learn) with it.
        from mmsnap_graph.app.config_file import read_fuse_table

        table = read_fuse_table(args.fuse_config)
    out = dict(FUSE_DEFAULTS, solver=args.default_solver)
    for key in out:
        value = getattr(args, key)
        if value is not None:
            out[key] = value
        elif key in table:
            out[key] = table[key]
    if args.bounds is not None or args.bounds_cfg is not None:
        # A box given on the command line replaces the file's, of either kind.
        out["bounds" if args.bounds_cfg is not None else "bounds_cfg"] = None
    if out["bounds"] is not None and out["bounds_cfg"] is not None:
        raise ValidationError("the --config file gives bounds and bounds_cfg: give one room box")
    if out["grid_points"] < 5 or out["grid_points"] % 2 == 0:
        raise ValidationError(f"--grid-points must be odd and >= 5, got {out['grid_points']}")
    return out


def _room_check(s: dict):
    """The :class:`~mmsnap_graph.fusion.config.RoomCheck` of the settings, or None."""
    from mmsnap_graph.fusion.config import RoomCheck
    from mmsnap_graph.fusion.recording.room import RoomBounds
    from mmsnap_graph.io.ti.cfg import read_boundary_boxes

    box = lambda v: RoomBounds(x_min=v[0], x_max=v[1], y_min=v[2], y_max=v[3])
    bounds = static = None
    if s["bounds"] is not None:
        try:
            bounds = box(s["bounds"])
        except ValidationError as exc:
            raise ValidationError(f"--bounds: {exc}") from None
    elif s["bounds_cfg"] is not None:
        boxes = read_boundary_boxes(s["bounds_cfg"])
        if "boundaryBox" not in boxes and "staticBoundaryBox" not in boxes:
            raise ValidationError(f"--bounds-cfg {s['bounds_cfg']}: no boundaryBox or "
                                  "staticBoundaryBox command")
        bounds = box(boxes["boundaryBox"]) if "boundaryBox" in boxes else None
        static = box(boxes["staticBoundaryBox"]) if "staticBoundaryBox" in boxes else None
    if bounds is None and static is None and not s["in_front"]:
        return None
    return RoomCheck(bounds=bounds, static_bounds=static, in_front=bool(s["in_front"]))


def fusion_config(args: argparse.Namespace):
    """The :class:`~mmsnap_graph.fusion.config.FusionConfig` of the parsed
    fusion flags and ``--config`` file (:func:`fusion_settings`): the one
    place a verb's arguments become a fusion configuration."""
    from mmsnap_graph.data.body import CENTROID_MERGE_RADIUS_M
    from mmsnap_graph.data.noise import GaussianPrior
    from mmsnap_graph.fusion.config import (AssociationOptions, CoverageCheck, DuplicateCheck,
                                            FusionConfig, LearnedWalls, MotionCheck, SplitCheck,
                                            UnplacedCheck)
    from mmsnap_graph.fusion.options import FusionOptions

    s = fusion_settings(args)
    motion = s["robust"] != "none" and s["motion_check"]
    room = _room_check(s)
    checks = [SplitCheck()]
    if motion:
        checks.append(MotionCheck())
        if s["coverage_check"]:
            checks.append(CoverageCheck())
    if s["robust"] != "none" and s["placement_check"]:
        checks.append(UnplacedCheck())
    if room is not None:
        checks.append(room)
    if s["learned_walls"] and (room is None or room.bounds is None):
        checks.append(LearnedWalls())
    if s["body_check"]:
        checks.append(DuplicateCheck())
    try:
        return FusionConfig(
            solve=FusionOptions(solver=s["solver"], covariance=s["covariance"],
                                grid_points_per_axis=s["grid_points"]),
            prior=GaussianPrior() if s["mode"] == "map" else None,
            robust=None if s["robust"] == "none" else s["robust"],
            association=AssociationOptions(
                gate_probability=s["gate"], source=s["source"],
                merge_body_m=CENTROID_MERGE_RADIUS_M if (s["body_merge"] and s["robust"] != "none")
                else None),
            checks=tuple(checks))
    except ValidationError as exc:
        raise ValidationError(f"fusion options: {exc}") from None


def config_text(config) -> str:
    """What a :class:`~mmsnap_graph.fusion.config.FusionConfig` runs, in words (one line)."""
    from mmsnap_graph.fusion.config import (CoverageCheck, DuplicateCheck, LearnedWalls,
                                            MotionCheck, RoomCheck, UnplacedCheck)

    robust = "none" if config.robust is None else config.robust.kernel
    parts = [f"{config.mode}, {config.solve.covariance}, {config.solve.solver}, robust {robust}"]
    if config.check(MotionCheck):
        parts.append("motion check" + (" with coverage" if config.check(CoverageCheck) else ""))
    if config.check(UnplacedCheck):
        parts.append("one-radar targets tied to two")
    if config.association.merge_body_m is not None:
        parts.append(f"centroids within {config.association.merge_body_m:g} m merged")
    dup = config.check(DuplicateCheck)
    parts.append(f"one target per {dup.body_m:g} m" if dup else "no body check")
    room = config.check(RoomCheck)
    if room is not None and room.in_front:
        parts.append("targets in front of every radar")
    if config.check(LearnedWalls):
        parts.append("walls learned from multipath images")
    if room is not None and room.bounds is not None:
        parts.append(f"room bounds {room.bounds.text()}")
    if room is not None and room.static_bounds is not None:
        parts.append(f"static bounds {room.static_bounds.text()}")
    return "; ".join(parts)


def add_calibration_arguments(p: argparse.ArgumentParser) -> None:
    """What to fuse with (``mmsnap fuse``, ``mmsnap replay``): the stored
    calibration as :func:`mmsnap_graph.app.runs.stored_calibration` reads it."""
    g = p.add_argument_group("calibration")
    g.add_argument("--calibration", default=None,
                   help="calibration JSON ({'nodes': {'S1': {'pose': [x_m, y_m, phi_rad]}, "
                        "...}}); default: the poses stored in the recording")
    g.add_argument("--sigmas", nargs=3, type=float, default=None,
                   metavar=("RANGE_M", "OMEGA_RAD", "DOPPLER_MPS"),
                   help="measurement noise sigmas of every node (OMEGA_RAD: of omega = pi "
                        "sin(theta), a phase in radians, not an angle; default: each node's "
                        "sigmas in the recording's /noise group, estimated from the data by "
                        "`mmsnap calibrate` or `mmsnap noise`; without it the paper's "
                        "resolutions 0.035 m, pi/4 rad, 0.1807 m/s)")
    g.add_argument("--no-pose-covariance", action="store_true",
                   help="treat the calibrated poses as exact (default: the calibration's pose "
                        "covariances are included in the fused covariance, docs/CONVENTIONS.md "
                        "'Calibration-aware fusion'; Laplace covariance only)")
    g.add_argument("--no-time-offsets", action="store_true",
                   help="do not bring the nodes' detections to the reference clock with the "
                        "calibration's clock offsets (default: they are)")


def calibration_for(args: argparse.Namespace, path, node_names, config):
    """The stored calibration as the calibration flags ask for it (poses,
    their covariances, clock offsets, noise;
    :func:`mmsnap_graph.app.runs.stored_calibration`), for ``config``'s covariance."""
    from mmsnap_graph.app.runs import paper_noise, stored_calibration

    if args.no_pose_covariance:
        covs = False
    elif config.solve.covariance != "laplace":
        covs = "poses exact (pose covariances need --covariance laplace)"
    else:
        covs = True
    cal = stored_calibration(path, node_names, calibration_json=args.calibration,
                             sigmas=args.sigmas, pose_covariances=covs,
                             time_offsets=not args.no_time_offsets)
    return cal.with_default_noise(*paper_noise())


def add_self_check_argument(p: argparse.ArgumentParser) -> None:
    """``--no-self-check``: the covariance self-check without truth
    (:mod:`mmsnap_graph.fusion.recording.consistency`) of ``fuse``,
    ``calibrate`` and ``replay``, not run or not printed."""
    p.add_argument("--no-self-check", action="store_true",
                   help="do not run or print the covariance self-check without truth (is the "
                        "fused covariances' size right for the data? docs/ROBUST.md)")


def say_self_check(command: str, report, out) -> None:
    """The self-check's line on ``out`` and, when it failed, the loud
    sentence (:attr:`~mmsnap_graph.fusion.recording.consistency.ConsistencyReport.warning`)
    on stderr after the command's name."""
    if report is None:
        return
    print(report.text(), file=out)
    if report.warning:
        print(f"mmsnap {command}: {report.warning}", file=sys.stderr)

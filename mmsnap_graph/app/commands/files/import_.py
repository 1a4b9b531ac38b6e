"""``mmsnap import``: TI radar data -> an HDF5 recording (docs/TI.md).

Four sources: ``dca1000`` (raw ADC captures with the ``.cfg`` they were made
with), ``ti-uart`` (binary logs of a demo's data UART), ``table`` (CSV /
``.npy`` / ``.npz`` point logs) and ``rosbag`` (ROS 1 / ROS 2 bags of TI
drivers' point clouds, docs/how-to/rosbag.md). The point sources share one
projection and mounting path (:func:`_points_recording`). Degrees appear only
here.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from mmsnap_graph.errors import ValidationError

from ..arguments import HEADING_HELP, named_values



#: ``--time-unit`` choices, each 1000 times finer than the one before.
TIME_UNITS = ("s", "ms", "us", "ns")


def height_band(text: str) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--height-band {text!r} must look like LOW_M,HIGH_M "
                                         "(e.g. 0.2,2.0)") from None
    return low, high


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pose", action="append", type=named_values("X_M,Y_M,PHI_DEG", 3, (2,)),
                   default=[], metavar="NAME=X,Y,PHI_DEG",
                   help="a known (surveyed) node pose: x, y in metres; repeat. "
                        f"{HEADING_HELP}, stored in radians. `mmsnap calibrate` reports a "
                        "calibrated pose far from it")
    p.add_argument("-o", "--output", required=True, help="output HDF5 recording")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")


def _points_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mount", action="append", type=named_values("HEIGHT_M,TILT_DEG", 2, (1,)),
                   default=[], metavar="NAME=HEIGHT_M,TILT_DEG",
                   help="mounting height above the floor in metres and down tilt in degrees "
                        "(> 0 looks down) of a node (repeat; default: the .cfg's "
                        "sensorPosition, else 0, 0)")
    p.add_argument("--room-pose", action="append", type=named_values("X_M,Y_M,PHI_DEG", 3, (2,)),
                   default=[], metavar="NAME=X,Y,PHI_DEG",
                   help="the points of this node are in a room frame made with this nominal "
                        "mounting pose, x, y in metres (with --mount's height and tilt); they "
                        f"are taken back to the sensor frame, where they must lie in front of "
                        f"the radar. {HEADING_HELP}. Give it for every node of a room-frame "
                        "log; `mmsnap calibrate` reports a calibrated pose far from it")
    p.add_argument("--height-band", type=height_band, default=None,
                   metavar="LOW_M,HIGH_M",
                   help="keep points between these heights above the floor (drops floor and "
                        "ceiling points)")
    p.add_argument("--frame-period", type=float, default=None, metavar="SECONDS",
                   help="frame period in seconds, e.g. 0.05 for 20 fps (default: from --cfg, "
                        "or the .cfg lines of a TI visualizer replay file); checked against "
                        "the log's time stamps")
    p.add_argument("--cfg", default=None, help="the .cfg the radars ran (for the frame period "
                                               "and sensorPosition)")
    p.add_argument("--ignore-unknown-commands", action="store_true",
                   help="skip .cfg commands this reader does not know (listed on stderr)")
    p.add_argument("--destack", action="store_true",
                   help="the log stores each frame as a stack of the last frames' points: "
                        "drop the run of points each stack shares with the previous one")
    p.add_argument("--accumulate", type=int, default=1, metavar="K",
                   help="merge the points of the last K frames into each frame (sparse "
                        "clouds; default 1 = off)")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "import", help="import TI radar data (DCA1000 raw ADC, UART point clouds, tables, "
                       "ROS bags)",
        description="Write an HDF5 recording (docs/FORMAT.md) from TI radar data; "
                    "docs/TI.md says which source needs which option.")
    sub = p.add_subparsers(dest="source", metavar="SOURCE")
    sub.required = True
    d = sub.add_parser("dca1000", help="raw ADC captures (adc_data.bin) with their .cfg")
    d.add_argument("--cfg", required=True, help="the mmWave SDK .cfg of the capture")
    d.add_argument("--board", default=None, help="board preset giving the antenna layout "
                                                 "(AWR1843BOOST, IWR6843ISK, IWR6843AOP, "
                                                 "AWR2243BOOST); required")
    d.add_argument("--node", action="append", type=named_values("CAPTURE.bin", None), required=True,
                   metavar="NAME=CAPTURE.bin",
                   help="a node's capture (repeat the same NAME for split parts, in order)")
    d.add_argument("--sub-frame", type=int, default=None,
                   help="sub-frame to import from an advanced frame (required then)")
    d.add_argument("--iq-swap", action="store_true", help="the device sent Q before I")
    d.add_argument("--allow-partial-frame", action="store_true",
                   help="drop an incomplete last frame of a capture cut short (warns)")
    d.add_argument("--ignore-unknown-commands", action="store_true",
                   help="skip .cfg commands this reader does not know (listed on stderr)")
    _common(d)
    d.set_defaults(func=run_dca1000)
    u = sub.add_parser("ti-uart", help="binary logs of a TI demo's data UART (TLV frames)")
    u.add_argument("--node", action="append", type=named_values("LOG.bin", None), required=True,
                   metavar="NAME=LOG.bin", help="a node's UART log (repeat per node)")
    u.add_argument("--demo", choices=["auto", "oob", "tracking", "counting"], default="auto",
                   help="the demo the board ran: detected from the bytes (auto, the default), "
                        "out-of-box (TLVs 1, 7), 3D People Tracking (TLV 1020) or the legacy "
                        "3D People Counting (48-byte header, TLV 6)")
    _points_options(u)
    _common(u)
    u.set_defaults(func=run_uart)
    t = sub.add_parser("table", help="CSV / .npy / .npz point logs, TI visualizer replay JSON")
    t.add_argument("--node", action="append", type=named_values("TABLE", None), default=[],
                   metavar="NAME=TABLE", help="a node's table (repeat per node)")
    t.add_argument("--table", default=None,
                   help="one table holding every node (a node column)")
    t.add_argument("--coordinates", choices=["auto", "cartesian", "spherical"], default="auto")
    t.add_argument("--degrees", action="store_true",
                   help="the table's angle columns are in degrees (default: radians; an angle "
                        "beyond +-pi without --degrees is an error)")
    t.add_argument("--snr-unit", choices=["db", "0.1db", "linear"], default=None,
                   help="unit of the SNR column when its header does not say: dB (default), "
                        "TI's side-info steps of 0.1 dB "
                        "(the mmWave SDK demos' TLV 7), or a linear power ratio (the people-"
                        "tracking demos); SNRs beyond any radar's in dB are an error")
    t.add_argument("--time-unit", choices=TIME_UNITS, default="s",
                   help="unit of the time-stamp column (default %(default)s); stamps that "
                        "disagree with the frame period by a factor of 1000 are an error "
                        "naming the unit they look like")
    t.add_argument("--columns", action="append", type=_columns_value, default=[],
                   metavar="HEADER=COLUMN|PRESET",
                   help="read the table's column HEADER as COLUMN (x, y, z, doppler, frame, "
                        "time_s, range, azimuth, elevation, snr, noise, node), e.g. "
                        "--columns 'Velocity=doppler'; repeat. Or the header set of a TI tool: "
                        "visualizer (the Industrial / Applications Visualizer: frameNum, "
                        "timestamp in ms, X, Y, Z, Doppler, SNR, Noise, Track index), "
                        "sdk-script (mmw_demo_example_script.py's CSV, SNR in 0.1 dB; "
                        "recognised without this option). A unit in a header is read "
                        "(X (m), Azimuth (deg), Timestamp (ms)); cells may be separated by "
                        "commas, semicolons or tabs; the visualizer's replay JSON is read as "
                        "a table")
    _points_options(t)
    _common(t)
    t.set_defaults(func=run_table)
    b = sub.add_parser("rosbag", help="ROS 1 / ROS 2 bags of TI point clouds (PointCloud2)",
                       description="Import the sensor_msgs/PointCloud2 topics of a ROS 1 .bag "
                                   "or a ROS 2 bag folder (sqlite3 or MCAP) written by TI's ROS "
                                   "drivers (docs/TI.md, 'ROS bags'); needs "
                                   'pip install "mmsnap_graph[rosbag]".')
    b.add_argument("bag", help="a ROS 1 .bag file or a ROS 2 bag folder (with metadata.yaml)")
    b.add_argument("--topic", action="append", type=named_values("NODE", None), required=True,
                   metavar="TOPIC=NODE",
                   help="a PointCloud2 topic and the node it is (repeat per radar, in node "
                        "order), e.g. --topic /ti_mmwave/radar_scan_pcl_0=S1")
    b.add_argument("--stamps", choices=["auto", "header", "receive"], default="auto",
                   help="the clouds' time: their header.stamp, the bag's receive time, or auto "
                        "(the default): the header stamps unless a cloud's is 0, as TI's driver "
                        "leaves it, then the receive times for every topic")
    _points_options(b)
    _common(b)
    b.set_defaults(func=run_rosbag)


def _columns_value(text: str):
    """``--columns``: ``HEADER=COLUMN`` -> (header, column), or a preset name."""
    from mmsnap_graph.io.ti.headers import PRESETS, preset_names
    if "=" not in text:
        if text not in PRESETS:
            raise argparse.ArgumentTypeError(f"{text!r} must look like HEADER=COLUMN or be a "
                                             f"preset of TI's tools: {preset_names()}")
        return text
    return named_values("COLUMN", None)(text)


def _columns_option(args):
    """``read_point_tables(columns=)`` from the ``--columns`` given: a mapping,
    a preset name, or None."""
    presets = [c for c in args.columns if isinstance(c, str)]
    pairs = [c for c in args.columns if not isinstance(c, str)]
    if presets and (pairs or len(presets) > 1):
        raise ValidationError(f"--columns {presets[0]}: a preset names every column; give it "
                              "alone (or HEADER=COLUMN renames without it)")
    return presets[0] if presets else (dict(pairs) or None)


def _poses(args) -> dict:
    return {name: [x, y, np.deg2rad(phi)] for name, (x, y, phi) in args.pose}


def _grouped(pairs) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for name, value in pairs:
        out.setdefault(name, []).append(value)
    return out


def _nominal(args) -> dict:
    """The metadata of the nominal poses given (``--pose`` over
    ``--room-pose``), which ``mmsnap calibrate`` compares its poses with."""
    from mmsnap_graph.evaluation.nominal import nominal_metadata
    given = {name: (pose, "room_pose") for name, pose in getattr(args, "room_pose", [])}
    given.update({name: (pose, "pose") for name, pose in args.pose})
    out = {}
    for name, ((x, y, phi_deg), source) in given.items():
        out.update(nominal_metadata(name, [x, y, np.deg2rad(phi_deg)], source))
    return out


def _write(args, recording) -> int:
    import dataclasses

    from mmsnap_graph.io import write_recording
    nominal = _nominal(args)
    if nominal:
        recording = dataclasses.replace(recording, metadata={**recording.metadata, **nominal})
    path = write_recording(args.output, recording, overwrite=args.overwrite)
    for name, node in recording.nodes.items():
        level = node.point_cloud if node.point_cloud is not None else None
        what = (f"{len(level)} points in {len(np.unique(level.frame))} frames" if level is not None
                else f"{node.cube.shape[0]} cubes {node.cube.shape[1:]}")
        print(f"{name}: {what}")
    print(f"wrote {path}")
    return 0


def _read_cfg(args, **options):
    """The ``.cfg`` of ``--cfg``; unknown commands skipped are listed on stderr."""
    from mmsnap_graph.io.ti.cfg import read_ti_cfg
    ti = read_ti_cfg(args.cfg, ignore_unknown=args.ignore_unknown_commands, **options)
    if ti.unknown:
        print(f"{args.cfg}: ignored unknown commands {', '.join(ti.unknown)}", file=sys.stderr)
    return ti


def run_dca1000(args: argparse.Namespace) -> int:
    from mmsnap_graph.io.ti.dca1000 import recording_from_dca1000
    ti = _read_cfg(args, board=args.board)
    if ti.advanced and args.sub_frame is None:
        raise ValidationError(f"{args.cfg} is an advanced frame of {ti.n_sub_frames} "
                              "sub-frames: choose one with --sub-frame")
    config = ti.configs if ti.advanced else ti.configs[0]
    sub_frame = args.sub_frame if ti.advanced else None
    if not ti.advanced and args.sub_frame not in (None, 0):
        raise ValidationError(f"--sub-frame {args.sub_frame}: {args.cfg} has no sub-frames")
    rec = recording_from_dca1000(_grouped(args.node), config, poses=_poses(args) or None,
                                 iq_swap=args.iq_swap,
                                 allow_partial_frame=args.allow_partial_frame,
                                 sub_frame=sub_frame,
                                 metadata={"board": ti.board, "cfg": str(args.cfg),
                                           **({} if sub_frame is None
                                              else {"sub_frame": int(sub_frame)})})
    return _write(args, rec)


#: TI's frame periodicity is 5 ns x 2^28 = 1.34 s at most; a longer frame
#: period on the command line is a unit mistake (milliseconds typed as seconds).
MAX_FRAME_PERIOD_S = 1.35
#: A frame period below 0.1 ms (10 kHz frames) is none a TI radar makes.
MIN_FRAME_PERIOD_S = 1e-4


def _check_point_options(args) -> None:
    """Usage errors (exit 2) of the point-cloud imports' numeric options."""
    from mmsnap_graph.io.ti.point_cloud import MAX_MOUNT_HEIGHT_M
    if args.accumulate < 1:
        raise ValidationError(f"--accumulate: n_frames={args.accumulate} must be an integer >= 1")
    period = args.frame_period
    if period is not None and not (np.isfinite(period) and period > 0):
        raise ValidationError(f"--frame-period must be finite and > 0, got {period}")
    if period is not None and period > MAX_FRAME_PERIOD_S:
        raise ValidationError(f"--frame-period {period:g}: the frame period is in seconds and a "
                              f"TI radar's is at most {MAX_FRAME_PERIOD_S} s; milliseconds? "
                              f"({period:g} ms is --frame-period {period / 1000:g})")
    if period is not None and period < MIN_FRAME_PERIOD_S:
        raise ValidationError(f"--frame-period {period:g}: the frame period is in seconds (e.g. "
                              f"0.05 for 20 fps); {period:g} s is below any TI radar's "
                              f"({MIN_FRAME_PERIOD_S:g} s)")
    for name, (height, tilt) in args.mount:
        if not (np.isfinite(height) and np.isfinite(tilt)):
            raise ValidationError(f"--mount {name}={height:g},{tilt:g}: height and tilt must be "
                                  "finite")
        if abs(height) > MAX_MOUNT_HEIGHT_M:
            raise ValidationError(f"--mount {name}={height:g},{tilt:g}: a sensor {height:g} m "
                                  f"above the floor; the height is in metres (centimetres? "
                                  f"{height:g} cm is --mount {name}={height / 100:g},{tilt:g})")
        if abs(tilt) >= 90:
            raise ValidationError(f"--mount {name}={height:g},{tilt:g}: the down tilt is in "
                                  "degrees and must lie in (-90, 90)")


def _timing(args, replays=()):
    """(frame period, TiConfig or None) from --frame-period / --cfg, else
    the frame period of the .cfg lines of the first of the ``replays`` (TI
    visualizer replay files) that holds them (each node's own mounting is
    not taken from them: --mount)."""
    _check_point_options(args)
    ti = None
    from mmsnap_graph.io.ti.cfg import TIMING_ONLY_LAYOUT
    if args.cfg is not None:
        ti = _read_cfg(args, layout=TIMING_ONLY_LAYOUT)
    period = args.frame_period if args.frame_period is not None else (
        ti.configs[0].frame_period_s if ti is not None else None)
    if period is None:
        from mmsnap_graph.io.ti.cfg import parse_ti_cfg
        from mmsnap_graph.io.ti.replay import replay_cfg_text
        for path in replays:
            text = replay_cfg_text(path)
            if text is not None:
                period = parse_ti_cfg(text, layout=TIMING_ONLY_LAYOUT, ignore_unknown=True,
                                      source=f"{path} (its cfg lines)").configs[0].frame_period_s
                print(f"frame period {period:g} s: the .cfg lines of {path}")
                break
    if period is None:
        raise ValidationError("the frame period is unknown: give --frame-period or --cfg")
    return period, ti


def _mountings(args, names, ti) -> dict:
    from mmsnap_graph.io.ti.point_cloud import Mounting
    mounts = dict(args.mount)
    rooms = dict(args.room_pose)
    unknown = sorted((set(mounts) | set(rooms)) - set(names))
    if unknown:
        raise ValidationError(f"--mount/--room-pose name nodes {unknown} that are not imported "
                              f"(nodes: {list(names)})")
    default = (0.0, 0.0)
    if ti is not None and ti.sensor_height_m is not None:
        default = (ti.sensor_height_m, float(np.rad2deg(ti.elevation_tilt_rad)))
    out = {}
    for name in names:
        height, tilt_deg = mounts.get(name, default)
        room = rooms.get(name)
        out[name] = Mounting(height_m=height, tilt_rad=np.deg2rad(tilt_deg),
                             room_pose=None if room is None else (room[0], room[1],
                                                                  np.deg2rad(room[2])))
    return out


def _unit_hint(args, cloud, period) -> str:
    """``--time-unit X`` that makes the table's stamps agree with the frame
    period (:func:`~mmsnap_graph.io.ti.point_cloud.stamp_unit_factor`), or ''."""
    from mmsnap_graph.io.ti.point_cloud import stamp_unit_factor
    unit = getattr(args, "time_unit", None)
    factor = stamp_unit_factor(cloud, period)
    if unit not in TIME_UNITS or factor is None:
        return ""
    k = TIME_UNITS.index(unit) + int(round(np.log10(factor) / 3))
    if not 0 <= k < len(TIME_UNITS) or k == TIME_UNITS.index(unit):
        return ""
    return (f"; the time stamps look like {TIME_UNITS[k]}, read as {unit}: give --time-unit "
            f"{TIME_UNITS[k]}")


def _check_period(args, clouds, period) -> None:
    """The frame period agrees with each cloud's time stamps (usage error)."""
    from mmsnap_graph.io.ti.point_cloud import check_frame_period
    option = "--frame-period" if args.frame_period is not None else f"the frame period of " \
                                                                     f"--cfg {args.cfg}"
    for name, cloud in clouds.items():
        problem = check_frame_period(cloud, period, node=name, option=option)
        if problem:
            hint = _unit_hint(args, cloud, period)
            raise ValidationError(problem + (hint or "; give the log's frame period in seconds "
                                             "with --frame-period (and the stamps' unit with "
                                             "--time-unit)"))


def _points_recording(args, clouds, ti, period, metadata):
    from mmsnap_graph.io.ti.point_cloud import (accumulate_frames, destack_frames,
                                             recording_from_point_clouds)
    _check_period(args, clouds, period)
    if args.destack:
        clouds = {name: destack_frames(c, frame_period_s=period)
                  for name, c in clouds.items()}
    if args.accumulate != 1:
        try:
            clouds = {name: accumulate_frames(c, args.accumulate, frame_period_s=period)
                      for name, c in clouds.items()}
        except ValidationError as exc:
            raise ValidationError(f"--accumulate {args.accumulate}: {exc}") from None
        metadata = dict(metadata, accumulated_frames=args.accumulate)
    band = args.height_band
    return recording_from_point_clouds(clouds, frame_period_s=period,
                                       mounting=_mountings(args, list(clouds), ti),
                                       height_band_m=band, poses=_poses(args) or None,
                                       metadata=metadata)


def run_uart(args: argparse.Namespace) -> int:
    from mmsnap_graph.io.ti.uart import read_ti_uart
    period, ti = _timing(args)
    clouds, demos = {}, set()
    for name, paths in _grouped(args.node).items():
        if len(paths) != 1:
            raise ValidationError(f"--node {name} is given {len(paths)} times; one log per node")
        n_sub = None if ti is None else (ti.n_sub_frames if ti.advanced else 1)
        log = read_ti_uart(paths[0], demo=args.demo, n_sub_frames=n_sub)
        for bad in log.bad[:10]:
            print(f"{name}: skipped {bad}", file=sys.stderr)
        if len(log.bad) > 10:
            print(f"{name}: ... {len(log.bad) - 10} more bad packets", file=sys.stderr)
        if log.missing_frames:
            print(f"{name}: {log.missing_frames} frame number(s) missing between the first and "
                  "the last (frames the board did not send or the log lost)", file=sys.stderr)
        clouds[name] = log.points
        demos.add(log.demo)
    rec = _points_recording(args, clouds, ti, period, {"source": "ti-uart-" + "+".join(sorted(demos))})
    return _write(args, rec)


def run_table(args: argparse.Namespace) -> int:
    from mmsnap_graph.io.ti.point_table import read_point_tables
    if bool(args.node) == bool(args.table):
        raise ValidationError("give either --node NAME=TABLE (repeat) or --table FILE")
    period, ti = _timing(args, [args.table] if args.table else [p for _, p in args.node])
    opts = dict(coordinates=args.coordinates, degrees=args.degrees, time_unit=args.time_unit,
                snr_unit=args.snr_unit, frame_period_s=period, columns=_columns_option(args))
    if args.table:
        clouds = read_point_tables(args.table, **opts)
    else:
        names = [name for name, _ in args.node]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValidationError(f"--node {twice[0]} is given {names.count(twice[0])} times; "
                                  "one table per node")
        clouds = {}
        for name, path in args.node:
            several = read_point_tables(path, **opts)
            if len(several) != 1:
                raise ValidationError(f"--node {name}={path}: the table holds {len(several)} "
                                      f"nodes {sorted(several)} (a node column); import it "
                                      f"with --table {path}")
            clouds[name] = next(iter(several.values()))
    rec = _points_recording(args, clouds, ti, period, {"source": "table"})
    return _write(args, rec)


def _bag_period(args, bag) -> None:
    """A usage error when the frame period is not given, with the bag's own."""
    if args.frame_period is None and args.cfg is None:
        steps = [f"{t.topic} every {t.median_interval_s:.4g} s" for t in bag.topics
                 if t.median_interval_s is not None]
        seen = f" (the bag's clouds arrive {', '.join(steps)}, median)" if steps else ""
        raise ValidationError(f"the frame period is unknown: give --frame-period or --cfg{seen}")


def run_rosbag(args: argparse.Namespace) -> int:
    import warnings

    from mmsnap_graph.errors import MmsnapWarning
    from mmsnap_graph.io.ti.rosbag import read_rosbag
    _check_point_options(args)
    topics = [t for t, _ in args.topic]
    twice = sorted({t for t in topics if topics.count(t) > 1})
    if twice:
        raise ValidationError(f"--topic {twice[0]} is given {topics.count(twice[0])} times; one "
                              "node per topic")
    bag = read_rosbag(args.bag, dict(args.topic), stamps=args.stamps)
    _bag_period(args, bag)
    period, ti = _timing(args)
    print(f"{args.bag}: ROS {bag.ros_version} ({bag.storage}); time stamps: "
          f"{bag.stamps_reason}", file=sys.stderr)
    no_velocity = []
    for t in bag.topics:
        ids = ", ".join(repr(i) for i in t.frame_ids)
        print(f"{t.node}: {t.topic}: {t.messages} clouds, {t.points} points, frame_id {ids}",
              file=sys.stderr)
        if not t.velocity:
            no_velocity.append(t.node)
            warnings.warn(f"{t.topic} ({t.node}) has no velocity field (the older radar-lab "
                          "driver's layout): its Doppler is unknown and imported as 0 m/s, "
                          "which calibration and fusion take as measured", MmsnapWarning,
                          stacklevel=2)
    metadata = {"source": f"rosbag{bag.ros_version}-{bag.storage}", "rosbag_stamps": bag.stamps}
    if no_velocity:
        metadata["rosbag_nodes_without_doppler"] = ",".join(no_velocity)
    rec = _points_recording(args, bag.clouds, ti, period, metadata)
    return _write(args, rec)

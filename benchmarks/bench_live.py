"""``mmsnap live`` on emulated boards: latency from a frame's last byte to its
fused line, frames dropped, the queue's depth, and the CPU per frame against
the offline pipeline on the same frames.

Boards: ``--boards`` TI out-of-box boards (the four-radar square of
bench_stream.py; 2 or 3: its first ones) on real pseudo-terminals
(tests/_boards.py, the emulator the tests use), each playing a simulated walk
of ``--people`` walkers (point clouds lifted to 3D, 20 fps) for ``--seconds``
(the walk's 60 s looped, frame numbers running on). ``mmsnap live`` runs in a
subprocess pinned to one core (``--core``) with ``--record``; this process
plays the boards and reads the JSON lines as they come.

Printed:

- latency, per slot with people: the time this process read the slot's
  first JSON line minus the time the last board wrote that frame's last byte
  (both on the host's monotonic clock; the board frame of a slot from the
  recording's ``{board}_board_frame_offset``): median, p99, max, against the
  targets 5 ms and 20 ms; and live's own figure (from its last byte read);
- frames dropped: packets sent minus frames fused per board, the readers'
  bad / out-of-sequence / missing counts, frames too late for their slot,
  and the most board frames the session's queue held (its bound 2400);
- live against ``mmsnap replay`` of the recording ``--record`` wrote: the
  people rows that agree (state within 1e-9);
- CPU per fused slot of the live process (its user + system time between
  the first and the last line, /proc) against the offline pipeline on the
  same frames in this process (CPU time of: each board frame's points
  projected and clustered as live does, then
  :func:`~mmsnap_graph.fusion.recording.sequence.fuse_recording` and
  :func:`~mmsnap_graph.tracking.central.track_fused` on the recorded
  centroids, vectorized solver), as a ratio.

The machine's other load inflates wall-clock latencies; the CPU figures are
the fairer ones. Usage::

    python benchmarks/bench_live.py [--boards 4] [--seconds 60] [--people 2] [--core 0]
    python benchmarks/bench_live.py --seconds 600      # the soak: 10 minutes
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))        # the board emulator and the UART encoder

from _boards import EmulatedBoard, Scene, pending_bytes, wait_for  # noqa: E402
from ti_encode import encode_oob_frame  # noqa: E402
from ti_samples import lift  # noqa: E402

from mmsnap_graph.io import read_recording  # noqa: E402
from mmsnap_graph.sim import SimulationOptions, simulate_recording  # noqa: E402

#: The four-radar square of bench_stream.py.
NETWORK = {"S1": [0.0, 0.0, 0.0], "S2": [0.0, 7.0, np.pi],
           "S3": [-3.5, 3.5, -np.pi / 2], "S4": [3.5, 3.5, np.pi / 2]}
PERIOD_S = 0.05
WALK_FRAMES = 1200                  # 60 s, looped
MOUNT = (1.0, 10.0)                 # height m, tilt deg
CFG = ROOT / "data" / "ti" / "iwr1843_oob.cfg"


def _packets(names, n_frames, people, seed):
    net = {n: NETWORK[n] for n in names}
    rec = simulate_recording(net, "random", SimulationOptions(physics=None, n_targets=people,
                                                             frame_period_s=PERIOD_S),
                             levels=["point_cloud"], n_frames=min(n_frames, WALK_FRAMES),
                             seed=seed)
    out = {}
    for name in names:
        det = rec.nodes[name].point_cloud
        xyz, dop = lift(det, MOUNT[0], np.deg2rad(MOUNT[1]), seed)
        per = [(xyz[det.frame == f], dop[det.frame == f], det.snr_db[det.frame == f])
               for f in range(min(n_frames, WALK_FRAMES))]
        out[name] = [encode_oob_frame(i + 1, per[i % len(per)][0], per[i % len(per)][1],
                                      per[i % len(per)][2], np.full(len(per[i % len(per)][1]),
                                                                     45.0))
                     for i in range(n_frames)]
    return out, rec


def _cpu_s(pid):
    """User + system CPU seconds of a process (/proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _children_cpu_s(pid):
    """{child pid: its CPU seconds so far} (the refinement's process)."""
    out = {}
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        for kid in kids:
            out[int(kid)] = _cpu_s(int(kid))
    except (OSError, ValueError, IndexError):
        pass
    return out


def run_live(names, packets, tmp, core, live_args=(), together=False):
    poses = {n: NETWORK[n] for n in names}
    cal = tmp / "cal.json"
    cal.write_text(json.dumps({"nodes": {n: {"pose": p} for n, p in poses.items()}}))
    rec_path = tmp / "live.h5"
    # One walk all boards look at; each board ends its frames at its own
    # moment of the period (boards on their own clocks), or all at once.
    scene = Scene()
    boards = {n: EmulatedBoard(packets[n], frame_period_s=PERIOD_S, garbled_first=False,
                               scene=scene,
                               phase_s=0.0 if together else k * PERIOD_S / len(names))
              for k, n in enumerate(names)}
    args = [sys.executable, "-m", "mmsnap_graph", "live", "--calibration", str(cal),
            "--record", str(rec_path), *live_args]
    for n, b in boards.items():
        args += ["--board", f"{n}={b.cli_port},{b.data_port},{CFG}",
                 "--mount", f"{n}={MOUNT[0]},{MOUNT[1]}"]
    pin = (lambda: os.sched_setaffinity(0, {core})) if core is not None else None
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=pin)
    lines, cpu = [], {"load": [], "children": {}}

    def read():
        for line in proc.stdout:
            now = time.monotonic()
            if not lines:
                cpu["first"] = (now, _cpu_s(proc.pid))
            lines.append((now, line))
            cpu["last"] = (now, _cpu_s(proc.pid))
            if len(lines) % 200 == 1:
                cpu["children"].update(_children_cpu_s(proc.pid))
            if not cpu["load"] or now - cpu["load"][-1][0] >= 10.0:
                cpu["load"].append((now, os.getloadavg()[0], _cpu_s(proc.pid)))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        for b in boards.values():
            wait_for(lambda: b.done.is_set() or proc.poll() is not None, "the boards to play",
                     timeout_s=2 * len(b.packets) * PERIOD_S + 120)
        for b in boards.values():
            wait_for(lambda: pending_bytes(b) == 0 or proc.poll() is not None, "live to read")
        time.sleep(1.0)                      # the last slots fused (1.5 frames' wait)
        cpu["children"].update(_children_cpu_s(proc.pid))
        proc.send_signal(signal.SIGINT)
        stderr = proc.stderr.read()
        proc.wait(timeout=120)
        reader.join(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        for b in boards.values():
            b.close()
    if proc.returncode != 0:
        raise SystemExit(f"mmsnap live failed:\n{stderr}")
    return boards, lines, cpu, stderr, rec_path, cal


def packet_of_slot(metadata, name, slot):
    """Index of the packet board ``name`` sent for ``slot`` (its frame
    numbers from 1), by the recording's ``{name}_board_frame_offsets``: a
    slot's offset from the board's frame counter changes where live's clock
    re-anchors (a slot's packet taken at the first frame's offset is then one
    too late, written after its line was read: a negative latency)."""
    table = np.asarray(metadata[f"{name}_board_frame_offsets"], dtype=np.int64).reshape(-1, 2)
    row = int(np.searchsorted(table[:, 0], slot, "right")) - 1
    return None if row < 0 else int(slot - table[row, 1] - 1)


def latency(boards, lines, rec):
    """(slots,) ms from the last byte written to the first line read, and the
    time each line was read."""
    md = rec.metadata
    first_line = {}
    for t, line in lines:
        first_line.setdefault(json.loads(line)["frame"], t)
    lat, when = [], []
    for slot, t in first_line.items():
        last = []
        for n, b in boards.items():
            if f"{n}_board_frame_offsets" not in md:
                continue                                  # the board sent nothing
            i = packet_of_slot(md, n, slot)
            k = None if i is None else i - b.first_packet     # its write (the scene's past lost)
            if k is not None and 0 <= k < len(b.write_times):
                last.append(b.write_times[k])
        if last:
            lat.append(t - max(last))
            when.append(t)
    return np.asarray(lat) * 1e3, np.asarray(when)


def over_time(lat, when, cpu, every_s):
    """Lines: per ``every_s`` of the run, the latency percentiles, the live
    process's CPU per slot and the load average (the soak's figures)."""
    out, t0 = [], when.min() if when.size else 0.0
    load = np.array(cpu["load"]) if cpu["load"] else np.zeros((0, 3))
    for k in range(int(np.ceil((when.max() - t0) / every_s)) if when.size else 0):
        m = (when >= t0 + k * every_s) & (when < t0 + (k + 1) * every_s)
        inside = (load[:, 0] >= t0 + k * every_s) & (load[:, 0] < t0 + (k + 1) * every_s)
        part = load[inside]
        cpu_txt = ""
        if len(part) > 1:
            slots = max(1, round((part[-1, 0] - part[0, 0]) / PERIOD_S))
            cpu_txt = f", live CPU {(part[-1, 2] - part[0, 2]) / slots * 1e3:.2f} ms/slot"
        load_txt = f", load average {part[:, 1].mean():.1f}" if len(part) else ""
        if m.any():
            out.append(f"  {k * every_s:6.0f}-{(k + 1) * every_s:.0f} s: {m.sum()} slots, latency "
                       f"median {np.median(lat[m]):.2f} ms, p99 {np.percentile(lat[m], 99):.2f} "
                       f"ms, max {lat[m].max():.2f} ms{cpu_txt}{load_txt}")
    return out


def offline_cpu(rec_path, names):
    """CPU seconds of the offline pipeline on the recorded frames: each
    board's point cloud projected as live projects it (the recording holds it
    so) and clustered in one call (sparse clouds: ``min_samples=1``, as live
    decides), then fuse_recording + track_fused on the centroids live fused."""
    import dataclasses

    from mmsnap_graph.app.pipeline import SPARSE_POINTS_PER_FRAME
    from mmsnap_graph.app.runs import paper_noise
    from mmsnap_graph.data.radar_config import TABLE_I
    from mmsnap_graph.fusion.config import DEFAULT_CONFIG
    from mmsnap_graph.fusion.options import FusionOptions, NetworkCalibration
    from mmsnap_graph.fusion.recording.sequence import fuse_recording
    from mmsnap_graph.radar.chain import ChainConfig
    from mmsnap_graph.radar.cluster import torso_centroids
    from mmsnap_graph.tracking.central import CentralConfig, track_fused

    rec = read_recording(rec_path, load_cubes=False)
    cluster = ChainConfig().cluster
    start = time.process_time()
    for n in names:
        pc = rec.nodes[n].point_cloud
        counts = np.bincount(pc.frame - pc.frame.min())
        if np.median(counts[counts > 0]) < SPARSE_POINTS_PER_FRAME:
            cluster = dataclasses.replace(cluster, min_samples=1)
        torso_centroids(pc, cluster, doppler_resolution_mps=TABLE_I.doppler_resolution_mps)
    cluster_s = time.process_time() - start
    config = dataclasses.replace(DEFAULT_CONFIG, solve=FusionOptions(solver="vectorized"))
    start = time.process_time()
    poses = {n: np.asarray(NETWORK[n]) for n in names}
    fused = fuse_recording(rec, config, calibration=NetworkCalibration(node_poses=poses),
                           noise=paper_noise()[0])
    track_fused(fused, CentralConfig(frame_period_s=PERIOD_S))
    return cluster_s, time.process_time() - start


def replay_differs(lines, rec_path, cal, tmp):
    """(people rows live printed, those ``mmsnap replay`` of the recording
    gives otherwise or not at all (state beyond 1e-9 or a missing id), rows
    replay has that live lacks) on the frames live printed."""
    out = tmp / "replay.jsonl"
    subprocess.run([sys.executable, "-m", "mmsnap_graph", "replay", str(rec_path),
                    "--calibration", str(cal), "-o", str(out)], cwd=ROOT, check=True,
                   capture_output=True)
    live = {}
    for _, line in lines:
        r = json.loads(line)
        live[(r["frame"], r["id"])] = [r["x_m"], r["y_m"], r["vx_mps"], r["vy_mps"]]
    last = max((k[0] for k in live), default=-1)
    again = {}
    for line in out.read_text().splitlines():
        r = json.loads(line)
        for tid, x in zip(r["track_id"], r["track_state"]):
            if r["frame"] <= last:
                again[(r["frame"], tid)] = x
    differ = sum(1 for k, x in live.items()
                 if k not in again or not np.allclose(x, again[k], rtol=0, atol=1e-9))
    return len(live), differ, len(set(again) - set(live))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=4, choices=(2, 3, 4))
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--people", type=int, default=2)
    ap.add_argument("--core", type=int, default=0, help="the core live runs on (-1: any)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-placement-check", action="store_true",
                    help="run mmsnap live with --no-placement-check")
    ap.add_argument("--every", type=float, default=60.0,
                    help="print the latency, CPU and load average per this many seconds")
    ap.add_argument("--refine", action="store_true",
                    help="run mmsnap live with --refine (the refinement in its own process)")
    ap.add_argument("--together", action="store_true",
                    help="every board ends its frames at the same moment (default: the boards' "
                         "frames spread over the period, as boards on their own clocks)")
    args = ap.parse_args()
    names = list(NETWORK)[: args.boards]
    n_frames = int(round(args.seconds / PERIOD_S))
    packets, _ = _packets(names, n_frames, args.people, args.seed)
    print(f"{args.boards} boards at {1 / PERIOD_S:g} fps for {args.seconds:g} s "
          f"({n_frames} frames each), {args.people} walker(s), mmsnap live on core "
          f"{args.core if args.core >= 0 else 'any'}, placement check "
          f"{'off' if args.no_placement_check else 'on'}, refinement "
          f"{'on' if args.refine else 'off'}, boards' frames "
          f"{'at once' if args.together else 'spread over the period'}; load average "
          f"{os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        boards, lines, cpu, stderr, rec_path, cal = run_live(
            names, packets, tmp, None if args.core < 0 else args.core,
            ("--no-placement-check",) * args.no_placement_check + ("--refine",) * args.refine,
            together=args.together)
        rec = read_recording(rec_path, load_cubes=False)
        lat, when = latency(boards, lines, rec)
        held = max(b.write_times[-1] - b.write_times[0] - (len(b.write_times) - 1) * PERIOD_S
                   for b in boards.values())
        reanchors = {n: len(np.reshape(rec.metadata.get(f"{n}_board_frame_offsets", []),
                                       (-1, 2))) - 1 for n in names}
        print(f"latency last byte written -> first fused line read, {lat.size} slots with "
              f"people: median {np.median(lat):.2f} ms (target 5), p99 "
              f"{np.percentile(lat, 99):.2f} ms (target 20), max {lat.max():.2f} ms, min "
              f"{lat.min():.2f} ms; the boards' slots re-anchored {sum(reanchors.values())} "
              "time(s)")
        print("\n".join(over_time(lat, when, cpu, args.every)))
        for line in stderr.splitlines():
            if line.startswith(tuple(f"{n}:" for n in names)) or "latency" in line:
                print(f"  live: {line}")
        got = {}
        for line in stderr.splitlines():
            head, _, rest = line.partition(": ")
            if head in names and rest.split()[1:2] == ["frames"]:
                got[head] = int(rest.split()[0])
        sent = {n: len(b.write_times) for n, b in boards.items()}
        # A board held back by a full pseudo-terminal (live not reading fast
        # enough) writes late; a real board's UART would lose those bytes.
        print(f"boards held back by live's reading at most {held:.2f} s over the run (0: "
              "live kept up; a real board would have lost the bytes)")
        print(f"board frames sent {sum(sent.values())}, read by live {sum(got.values())}: "
              f"{sum(sent.values()) - sum(got.values())} dropped")
        slots = len({json.loads(line)["frame"] for _, line in lines})
        (t0, c0), (t1, c1) = cpu["first"], cpu["last"]
        per_slot = (c1 - c0) / max(1, round((t1 - t0) / PERIOD_S))
        cluster_s, fuse_s = offline_cpu(rec_path, names)
        n_slots = n_frames
        offline = (cluster_s + fuse_s) / n_slots
        print(f"CPU per slot: live {per_slot * 1e3:.2f} ms (the whole process: readers, parser, "
              f"clustering, stream, JSON, recorder; {slots} slots with people); offline on the "
              f"same frames {offline * 1e3:.2f} ms (clustering {cluster_s / n_slots * 1e3:.2f}, "
              f"fuse_recording + track_fused {fuse_s / n_slots * 1e3:.2f}); ratio live/offline "
              f"{per_slot / offline:.2f}")
        if cpu["children"]:
            child = sum(cpu["children"].values())
            what = "the learned walls' and the refinement's" if args.refine else \
                "the learned walls'"
            print(f"  {what} process(es): {child:.1f} s CPU ({child / max(1, slots) * 1e3:.2f} "
                  "ms per slot with people; pinned with live to its core, at nice +10)")
        if args.refine:         # the poses changed during the session: replay has the first
            return
        n_live, differ, missing = replay_differs(lines, rec_path, cal, tmp)
        print(f"mmsnap replay of the recording: {n_live - differ} of {n_live} people rows live "
              f"printed the same (state within 1e-9), {differ} differ, {missing} missing in live")


if __name__ == "__main__":
    main()

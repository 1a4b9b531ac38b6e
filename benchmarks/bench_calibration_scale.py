"""Time and peak memory of calibrating a recording against frames and nodes.

    python benchmarks/bench_calibration_scale.py [--frames 600,1500,3000,6000]
        [--nodes 2,3,5,10] [--baseline-path DIR] [--baseline-max-frames N]
        [--repeat 2] [--timeout S]

Each size is a simulated recording (``sim.simulate_recording``: centroids of
one walker on the ``"random"`` trajectory, 150 ms frames, seed 1) of N nodes
on a 5 m circle facing its centre, written once to a temporary HDF5 file.
For each size a fresh subprocess (one BLAS thread) reads it and runs
``calibrate_recording`` with the defaults of ``mmsnap calibrate`` (track
matching and lag search over every node pair, pose graph, joint graph with
motion factors); it prints the wall time of the calibration and the peak
resident memory of the subprocess (``resource.getrusage``, which includes
the interpreter and the recording: about 150 MB before calibrating). On
Linux the peak is reset after reading the recording (``/proc/self/clear_refs``),
so it is the resident peak during the calibration; the resident size before
it is printed too.

``--hours 1,2,4`` measures the windowed calibration instead (``mmsnap
calibrate`` above 20 minutes, :mod:`mmsnap_graph.calibration.joint.windowed`):
for each duration of ``--nodes`` nodes (one count), the windowed solve of
``--window-s`` windows read from the file (its peak includes reading them:
nothing is read before), and, up to ``--batch-max-hours``, the batch solve of
the same recording; it prints the time per hour and the peak of each, the
ratio of the windowed time per hour to the batch's, and the ratio of the
peaks of the longest and the shortest duration (target: within 10%).

``--baseline-path DIR`` runs the same measurement with the package found in
``DIR`` (e.g. a checkout of an older commit) up to ``--baseline-max-frames``
frames, and prints the ratio. The growth exponent is the least-squares slope
of log(time) (and log(memory)) against log(frames) per node count.

The machine may be shared: figures vary with load; run twice (``--repeat``)
and read the smaller time.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from mmsnap_graph.sim import SimulationOptions

ROOT = Path(__file__).resolve().parents[1]
FRAME_PERIOD_S = 0.15


def network(n_nodes: int) -> dict[str, np.ndarray]:
    """N nodes on a 5 m circle, each facing the centre (boresight = local +y)."""
    ang = 2.0 * np.pi * np.arange(n_nodes) / n_nodes
    # headings wrapped into (-pi, pi]: the data layer refuses headings beyond 2 pi
    return {f"S{i + 1}": np.array([5.0 * np.cos(a), 5.0 * np.sin(a),
                                   float(np.angle(np.exp(1j * (a + np.pi / 2))))])
            for i, a in enumerate(ang)}


def make_recording(path: Path, n_nodes: int, n_frames: int) -> None:
    from mmsnap_graph.io.hdf5 import write_recording
    from mmsnap_graph.sim.simulator import simulate_recording

    rec = simulate_recording(network(n_nodes), "random",
                             SimulationOptions(physics=None, frame_period_s=FRAME_PERIOD_S),
                             levels=("centroids",), n_frames=n_frames, seed=1)
    write_recording(path, rec, overwrite=True)


def _status_mb(field: str) -> float | None:
    """A memory figure of /proc/self/status in MB (None off Linux)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return float(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def measure_one(path: str) -> None:
    """Child process: read, calibrate, print a JSON line."""
    import resource

    from mmsnap_graph.calibration import calibrate_recording
    from mmsnap_graph.io.hdf5 import read_recording

    rec = read_recording(path)
    rss0 = _status_mb("VmRSS")
    try:  # Linux: reset the peak (VmHWM) so that it is the calibration's own
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    t0 = time.perf_counter()
    cal = calibrate_recording(rec)
    t = time.perf_counter() - t0
    peak = _status_mb("VmHWM")
    if peak is None:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(dict(time_s=t, peak_mb=peak, before_mb=rss0, success=bool(cal.success),
                          method=cal.method, max_position_error_m=_max_position_error(cal))))


def _max_position_error(cal) -> float:
    true = network(len(cal.node_names))
    ref = true[cal.reference]
    c, s = np.cos(ref[2]), np.sin(ref[2])
    return max(float(np.hypot(*(np.asarray(cal.poses[n])[:2]
                                - np.array([[c, s], [-s, c]]) @ (true[n][:2] - ref[:2]))))
               for n in cal.poses)


def measure_windowed(path: str, window_s: float) -> None:
    """Child process: the windowed calibration of the file (windows read
    from it), a JSON line."""
    import mmsnap_graph.calibration.joint.windowed as w
    from mmsnap_graph.io.chunks import open_detection_windows

    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    rss0 = _status_mb("VmRSS")
    t0 = time.perf_counter()
    index = open_detection_windows(path)
    frames = w.window_frames_for(index.last_frame - index.first_frame + 1,
                                 index.frame_period_s, window_s)
    cal = w.calibrate_windowed(index, frames)
    t = time.perf_counter() - t0
    peak = _status_mb("VmHWM")
    fact = cal.facts[0]
    print(json.dumps(dict(time_s=t, peak_mb=peak, before_mb=rss0, success=bool(cal.success),
                          method=f"windowed {fact.n_combined}/{fact.n_windows}",
                          max_position_error_m=_max_position_error(cal))))


def run_child(path: Path, package_root: Path, timeout_s: float,
              window_s: float | None = None) -> dict | None:
    env = dict(os.environ, PYTHONPATH=str(package_root), OPENBLAS_NUM_THREADS="1",
               OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    # the child imports this file from the current tree, the package from package_root
    call = (f"b.measure_one({str(path)!r})" if window_s is None
            else f"b.measure_windowed({str(path)!r}, {float(window_s)!r})")
    code = (f"import sys; sys.path.insert(0, {str(ROOT / 'benchmarks')!r}); "
            f"import bench_calibration_scale as b; {call}")
    try:
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                             text=True, timeout=timeout_s, check=True)
    except subprocess.TimeoutExpired:
        return None
    except subprocess.CalledProcessError as exc:
        print(exc.stderr[-2000:], file=sys.stderr)
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def growth(xs, ys) -> float:
    ok = [(x, y) for x, y in zip(xs, ys) if y is not None]
    if len(ok) < 2:
        return float("nan")
    lx, ly = np.log([x for x, _ in ok]), np.log([y for _, y in ok])
    return float(np.polyfit(lx, ly, 1)[0])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", default="600,1500,3000,6000")
    p.add_argument("--nodes", default="2,3,5,10")
    p.add_argument("--baseline-path", type=Path, default=None,
                   help="a directory holding an older mmsnap_graph (and factors) package")
    p.add_argument("--baseline-max-frames", type=int, default=1500)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--timeout", type=float, default=900.0, help="per run, seconds")
    p.add_argument("--hours", default=None,
                   help="e.g. 1,2,4: the windowed calibration of these durations (one --nodes)")
    p.add_argument("--window-s", type=float, default=600.0)
    p.add_argument("--batch-max-hours", type=float, default=1.0)
    args = p.parse_args()
    if args.hours is not None:
        return hours_main(args)
    frames = [int(f) for f in args.frames.split(",")]
    nodes = [int(n) for n in args.nodes.split(",")]
    print(f"calibrate_recording, one BLAS thread per run, best of {args.repeat}; "
          f"load average at start {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        for n in nodes:
            times, mems = [], []
            for f in frames:
                path = Path(tmp) / f"rec_{n}_{f}.h5"
                make_recording(path, n, f)
                runs = [run_child(path, ROOT, args.timeout) for _ in range(args.repeat)]
                runs = [r for r in runs if r is not None]
                if not runs:
                    print(f"  {n:2d} nodes x {f:6d} frames: timed out after {args.timeout:.0f} s")
                    times.append(None)
                    mems.append(None)
                    continue
                best = min(runs, key=lambda r: r["time_s"])
                times.append(best["time_s"])
                mems.append(best["peak_mb"])
                line = (f"  {n:2d} nodes x {f:6d} frames: {best['time_s']:8.2f} s "
                        f"(runs {', '.join('%.2f' % r['time_s'] for r in runs)}), peak RSS "
                        f"{best['peak_mb']:7.0f} MB (resident before calibrating {best['before_mb']:.0f}), "
                        f"{best['method']}, success={best['success']}, max position error "
                        f"{best['max_position_error_m'] * 100:.1f} cm")
                if args.baseline_path is not None and f <= args.baseline_max_frames:
                    base = run_child(path, args.baseline_path, args.timeout)
                    if base is not None:
                        line += (f" | baseline {base['time_s']:.2f} s, {base['peak_mb']:.0f} MB "
                                 f"(speed-up {base['time_s'] / best['time_s']:.1f}x)")
                print(line, flush=True)
                path.unlink()
            print(f"  {n:2d} nodes: growth exponent time {growth(frames, times):.2f}, "
                  f"peak memory {growth(frames, mems):.2f} (frames {frames})", flush=True)


def _line(label: str, r: dict, hours: float) -> str:
    return (f"    {label}: {r['time_s']:8.1f} s ({r['time_s'] / hours:6.1f} s per hour), peak RSS "
            f"{r['peak_mb']:6.0f} MB, {r['method']}, success={r['success']}, max position "
            f"error {r['max_position_error_m'] * 100:.1f} cm")


def hours_main(args) -> None:
    """The windowed calibration of 1, 2, 4 h (``--hours``) against the batch."""
    hours = [float(h) for h in args.hours.split(",")]
    n = int(args.nodes.split(",")[0])
    print(f"windowed calibration ({args.window_s:g} s windows) vs batch, {n} nodes, one BLAS "
          f"thread per run; load average at start {os.getloadavg()[0]:.1f}", flush=True)
    peaks, per_hour_w, per_hour_b = {}, {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for h in hours:
            f = int(round(h * 3600.0 / FRAME_PERIOD_S))
            path = Path(tmp) / f"rec_{n}_{f}.h5"
            make_recording(path, n, f)
            print(f"  {h:g} h ({f} frames):", flush=True)
            w = run_child(path, ROOT, args.timeout, window_s=args.window_s)
            if w is None:
                print("    windowed: failed or timed out", flush=True)
            else:
                peaks[h], per_hour_w[h] = w["peak_mb"], w["time_s"] / h
                print(_line("windowed", w, h), flush=True)
            if h <= args.batch_max_hours:
                bt = run_child(path, ROOT, args.timeout)
                if bt is None:
                    print("    batch: failed or timed out", flush=True)
                else:
                    per_hour_b[h] = bt["time_s"] / h
                    print(_line("batch   ", bt, h), flush=True)
                    if w is not None:
                        print(f"    windowed / batch: time per hour x{per_hour_w[h] / per_hour_b[h]:.2f}"
                              f", peak x{w['peak_mb'] / bt['peak_mb']:.2f}", flush=True)
            path.unlink()
    if len(peaks) >= 2:
        lo, hi = min(peaks), max(peaks)
        print(f"  windowed peak {hi:g} h / {lo:g} h: x{peaks[hi] / peaks[lo]:.3f} (target within "
              f"10%); time per hour {', '.join(f'{h:g} h {v:.1f} s' for h, v in per_hour_w.items())}")


if __name__ == "__main__":
    main()

"""Measure what real TI point clouds look like, to calibrate the simulator.

Reads the two public IWR1843 recordings (out-of-box demo point clouds,
people walking; MIT licence) stored as pickles of 10-frame stacks of
room-frame points, with a restricted unpickler (numpy arrays, lists and dicts
only), and prints, per radar (S1 = "Ori" at (0, 0) facing +y, S2 = "Side" at
(1.70, 1.65) m facing -x):

- new points per 50 ms frame after de-stacking (mean, standard deviation);
- the share of zero-Doppler (static) points, and of moving points outside
  the room box (ghosts: multipath, side lobes);
- people: moving points of S1 and S2 in the room and the 0.2-2.0 m height
  band, clustered over 11-frame windows and linked into tracks; per radar,
  frame and person the centroid of that radar's points within 0.6 m of the
  track; its error relative to a local quadratic fit of the same radar's
  centroids (+-1 s), as range / cross-range standard deviations and the
  lag-1 autocorrelation (per 50 ms frame, and the time constant it implies),
  with standard errors (the scatter's from the frames' effective number
  ``n (1 - rho) / (1 + rho)``, the autocorrelation's ``1 / sqrt(n)``);
- the extent of a person's points (standard deviation about the centroid);
- split clusters: 10-frame windows in which one person's points of one
  radar form two or more DBSCAN clusters (eps 0.3 m, 3 points);
- the slow part: the two radars' smoothed centroids of one person drift
  apart and back (standard deviation about their mean offset, and the lag
  at which its autocorrelation falls below 1/e), over frames both see;
- multipath images of a walker (``images``): each radar's moving points in
  the height band beyond a wall of the room box, attributed to the tracked
  person (walking at 0.2 m/s or more, with points of that radar in that
  frame) whose mirror image M through that wall, or one-bounce image B (at
  ``(|P - S| + |M - S|) / 2`` from the radar S along M's bearing), lies
  within 1 m: the share of such person-frames with an image point, the
  image points per frame when there is one (and the person's own), the
  image's SNR minus the person's (dB, same frame), how far beyond the wall
  (10/50/90th percentiles), which geometry fits (distances to M and B, the
  range residual to each), and how the image frames come: runs of
  consecutive frames, and episodes (image frames less than 0.5 s apart);
  points only within 4 m of their radar, as the recorder cut them;
- the reflection depth: the two radars' smoothed centroids of the same
  person differ by ``-d1 u1 + d2 u2`` (``u_i`` the unit line of sight from
  radar i to the person) when each radar sees the body's near side ``d_i``
  metres in front of its centre; least squares over all frames both see,
  with a block bootstrap (2 s blocks) for the uncertainty, once with the
  tape-measured mounting taken as exact and once with a free translation
  of S2 (the mounting's own error).

``--simulated N`` measures N seeded simulations (real physics) of the first
recording's geometry the same way, with one and with two walkers.

Run: ``python tools/measure_real_recordings.py DIR [--json OUT]`` with DIR the
folder of the pickles (``multiple_tracking_Jun-05-16-07-02.pkl``,
``fall_detection_Jun-10-15-48-31.pkl``).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter
from sklearn.cluster import DBSCAN

FRAME_S = 0.05
RADARS = {"S1": ("IWR1843_Ori", np.array([0.0, 0.0])), "S2": ("IWR1843_Side", np.array([1.70, 1.65]))}
RECORDINGS = {
    "multiple_tracking": ("multiple_tracking_Jun-05-16-07-02.pkl", (-2.0, 1.6), (0.0, 3.6), 2),
    "fall_detection": ("fall_detection_Jun-10-15-48-31.pkl", (-1.7, 1.6), (0.0, 3.6), 1),
}
BAND_M = (0.2, 2.0)


class _ArraysOnly(pickle.Unpickler):
    """Numpy arrays, lists and dicts; anything else is refused."""

    _ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
                ("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "scalar"),
                ("numpy._core.multiarray", "scalar")}

    def find_class(self, module, name):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refused {module}.{name}")


def load_stacks(path: Path) -> list:
    with open(path, "rb") as f:
        return _ArraysOnly(f).load()


def destack(stacks: list) -> list:
    """New points of each saved frame: the stack minus the prefix it repeats
    from the previous stack (a stack is the radar's last 10 frames, oldest
    first)."""
    out = [np.asarray(stacks[0], dtype=np.float64)]
    for prev, cur in zip(stacks[:-1], stacks[1:]):
        keep = 0
        for drop in range(len(prev) + 1):
            n = len(prev) - drop
            if n <= len(cur) and np.array_equal(prev[drop:].view(np.uint16), cur[:n].view(np.uint16)):
                keep = n
                break
        out.append(np.asarray(cur[keep:], dtype=np.float64))
    return out


def _table(frames: list) -> tuple[np.ndarray, np.ndarray]:
    fr = np.concatenate([np.full(len(p), k) for k, p in enumerate(frames)])
    return fr, np.concatenate(frames) if fr.size else np.zeros((0, 5))


def _people_tracks(points: np.ndarray, frame: np.ndarray, n_frames: int, n_people: int) -> np.ndarray:
    """(n_people, F, 2) smoothed positions (nan where unseen) from windowed
    DBSCAN centres linked greedily into the ``n_people`` longest tracks."""
    tracks: list[dict] = []
    for k in range(n_frames):
        sel = np.abs(frame - k) <= 5
        xy = points[sel, :2]
        if len(xy) < 5:
            continue
        lab = DBSCAN(eps=0.5, min_samples=5).fit_predict(xy)
        centres = [xy[lab == c].mean(0) for c in set(lab) - {-1}]
        free = list(range(len(centres)))
        for tr in sorted(tracks, key=lambda t: -len(t["k"])):
            if k - tr["k"][-1] > 20 or not free:
                continue
            d = [np.linalg.norm(centres[j] - tr["xy"][-1]) for j in free]
            j = int(np.argmin(d))
            if d[j] < 0.7:
                tr["k"].append(k)
                tr["xy"].append(centres[free.pop(j)])
        tracks += [{"k": [k], "xy": [centres[j]]} for j in free]
    tracks = sorted(tracks, key=lambda t: -len(t["k"]))[:n_people]
    out = np.full((n_people, n_frames, 2), np.nan)
    for i, tr in enumerate(tracks):
        kk = np.array(tr["k"])
        xy = np.array(tr["xy"])
        full = np.arange(kk[0], kk[-1] + 1)
        for a in range(2):
            out[i, full, a] = np.interp(full, kk, xy[:, a])
    return out


def _smooth(c: np.ndarray, half: int = 20) -> np.ndarray:
    """Local quadratic fit (+-half frames) over runs of frames with a value."""
    out = np.full_like(c, np.nan)
    ok = np.isfinite(c[:, 0])
    idx = np.flatnonzero(ok)
    if idx.size < 2 * half + 1:
        return out
    # Fit on the frames with a value, as a function of time (gaps interpolated).
    full = np.arange(idx[0], idx[-1] + 1)
    for a in range(2):
        filled = np.interp(full, idx, c[idx, a])
        out[full, a] = savgol_filter(filled, 2 * half + 1, 2)
    out[~ok] = np.nan
    return out


def _radial_cross(err: np.ndarray, centre: np.ndarray, radar_xy: np.ndarray) -> np.ndarray:
    los = centre - radar_xy
    u = los / np.linalg.norm(los, axis=1, keepdims=True)
    v = np.stack([-u[:, 1], u[:, 0]], axis=1)
    return np.stack([np.sum(err * u, 1), np.sum(err * v, 1)], axis=1)


def _lag1(e: np.ndarray) -> float:
    """Lag-1 autocorrelation over consecutive frames with values."""
    ok = np.isfinite(e[:-1]) & np.isfinite(e[1:])
    a, b = e[:-1][ok], e[1:][ok]
    m = np.nanmean(e)
    return float(np.sum((a - m) * (b - m)) / np.nansum((e - m) ** 2) * np.isfinite(e).sum() / max(ok.sum(), 1))


def _depth_fit(d: np.ndarray, u1: np.ndarray, u2: np.ndarray, free_translation: bool) -> np.ndarray:
    cols = [-u1, u2] + ([np.tile([1.0, 0.0], (len(d), 1)), np.tile([0.0, 1.0], (len(d), 1))]
                        if free_translation else [])
    a = np.stack([c.reshape(-1) for c in cols], axis=1)
    return np.linalg.lstsq(a, d.reshape(-1), rcond=None)[0]


def _bootstrap(rows: np.ndarray, fn, rng, block: int = 40, n: int = 300) -> np.ndarray:
    starts = np.arange(0, len(rows), block)
    draws = []
    for _ in range(n):
        pick = rng.choice(starts, size=len(starts))
        idx = np.concatenate([np.arange(s, min(s + block, len(rows))) for s in pick])
        draws.append(fn(idx))
    return np.std(draws, axis=0)


def measure_recording(path: Path, xlim, ylim, n_people: int, rng) -> dict:
    stacks = load_stacks(path)
    return measure_frames({name: destack([s[key] for s in stacks])
                           for name, (key, _) in RADARS.items()}, xlim, ylim, n_people, rng)


def simulated_frames(seed: int, n_frames: int = 635, n_people: int = 2) -> dict:
    """The simulator's point clouds (default options: real physics) of the
    first recording's geometry and room at 20 fps, people walking at random
    in the part of the room both radars see, as room-frame points per frame
    (height 1 m, inside the band)."""
    from factors.models import local_to_global
    from mmsnap_graph.sim import Area, RealPhysics, SimulationOptions, simulate_recording
    from mmsnap_graph.sim.trajectories import make_trajectory

    net = {"S1": (0.0, 0.0, 0.0), "S2": (1.70, 1.65, np.pi / 2)}
    area = Area(x_min_m=-1.6, x_max_m=1.0, y_min_m=0.8, y_max_m=3.3)
    states = np.stack([make_trajectory("random", area, n_frames=n_frames, frame_period_s=FRAME_S,
                                       rng=np.random.default_rng([seed, t]))
                       for t in range(n_people)])
    opt = SimulationOptions(frame_period_s=FRAME_S, min_range_m=0.25,
                            physics=RealPhysics(room=(-2.0, 1.6, 0.0, 3.6)))
    rec = simulate_recording(net, states, opt, levels=("point_cloud",), seed=seed)
    out = {}
    for name, node in rec.nodes.items():
        pc = node.point_cloud
        th = np.arcsin(pc.omega_rad / np.pi)
        xy = local_to_global(np.stack([pc.range_m * np.sin(th), pc.range_m * np.cos(th)], 1),
                             rec.truth.node_poses[name])
        pts = np.column_stack([xy, np.ones(len(pc)), pc.doppler_mps, 10 * pc.snr_db])
        out[name] = [pts[pc.frame == k] for k in range(n_frames)]
    return out


def _runs(on: np.ndarray, gap: int = 1) -> np.ndarray:
    """Lengths (first to last frame) of the runs of ``on`` frames, frames
    fewer than ``gap`` apart joined."""
    idx = np.flatnonzero(on)
    if idx.size == 0:
        return np.zeros(0, int)
    cut = np.flatnonzero(np.diff(idx) > gap)
    first, last = idx[np.r_[0, cut + 1]], idx[np.r_[cut, idx.size - 1]]
    return last - first + 1


def _image_points(fr, p, radar_xy, room, tracks, vel):
    """(frame, person, G (2), wall, depth, snr, distance to M, to B, range
    residual to M, to B) of the moving points beyond a wall attributed to a
    walking person (module doc)."""
    depth = np.stack([room[0] - p[:, 0], p[:, 0] - room[1], room[2] - p[:, 1], p[:, 1] - room[3]], 1)
    out = []
    for k in np.flatnonzero(depth.max(1) > 0):
        f, g, w = fr[k], p[k, :2], int(np.argmax(depth[k]))
        best = None
        for i in range(tracks.shape[0]):
            pp = tracks[i, f]
            if not np.isfinite(pp[0]) or np.hypot(*vel[i, f]) < 0.2:
                continue
            m = pp.copy()
            m[w // 2] = 2 * room[w] - pp[w // 2]
            r_p, r_m, r_g = (np.linalg.norm(q - radar_xy) for q in (pp, m, g))
            b = radar_xy + (r_p + r_m) / 2 * (m - radar_xy) / r_m
            row = [f, i, *g, w, depth[k].max(), p[k, 4] / 10, np.linalg.norm(g - m),
                   np.linalg.norm(g - b), r_g - r_m, r_g - (r_p + r_m) / 2]
            if best is None or min(row[7:9]) < min(best[7:9]):
                best = row
        if best is not None and min(best[7:9]) < 1.0:
            out.append(best)
    return np.array(out).reshape(-1, 11)


def measure_images(fr, p, radar_xy, room, tracks, n_f: int) -> dict:
    """Multipath images of the walkers seen by one radar (module doc); ``fr``,
    ``p`` its moving points in the height band within 4 m."""
    vel = np.full_like(tracks, np.nan)
    for i in range(tracks.shape[0]):
        ok = np.flatnonzero(np.isfinite(tracks[i, :, 0]))
        if ok.size > 11:
            for a in range(2):
                vel[i, ok, a] = savgol_filter(tracks[i, ok, a], 11, 2, deriv=1) / FRAME_S
    img = _image_points(fr, p, radar_xy, room, tracks, vel)
    own_n, own_snr, walking = np.zeros((tracks.shape[0], n_f)), {}, np.zeros((tracks.shape[0], n_f), bool)
    for i in range(tracks.shape[0]):
        for f in range(n_f):
            if not np.isfinite(tracks[i, f, 0]) or not np.hypot(*vel[i, f]) >= 0.2:
                continue
            sel = (fr == f) & (np.linalg.norm(p[:, :2] - tracks[i, f], axis=1) < 0.6)
            if sel.any():
                walking[i, f] = True
                own_n[i, f] = sel.sum()
                own_snr[(i, f)] = float(np.median(p[sel, 4]) / 10)
    keep = np.array([walking[int(r[1]), int(r[0])] for r in img], bool).reshape(-1)
    img = img[keep]
    on = np.zeros((tracks.shape[0], n_f), bool)
    on[img[:, 1].astype(int), img[:, 0].astype(int)] = True
    pairs = {(int(i), int(f)) for f, i in img[:, :2]}
    counts = [np.sum((img[:, 0] == f) & (img[:, 1] == i)) for i, f in pairs]
    d_snr = [r[6] - own_snr[(int(r[1]), int(r[0]))] for r in img]
    runs = np.concatenate([_runs(on[i]) for i in range(on.shape[0])])
    episodes = np.concatenate([_runs(on[i], gap=10) for i in range(on.shape[0])])
    med = lambda a: float(np.median(a)) if len(a) else None  # noqa: E731
    return {
        "walking_frames_seen": int(walking.sum()),
        "image_point_count": int(len(img)),
        "frame_share_with_image": float(on.sum() / max(walking.sum(), 1)),
        "image_points_per_image_frame": float(np.mean(counts)) if counts else None,
        "person_points_per_walking_frame": float(own_n[walking].mean()) if walking.any() else None,
        "snr_image_minus_person_db_median": med(d_snr),
        "depth_beyond_wall_m_p10_p50_p90": (np.percentile(img[:, 5], [10, 50, 90]).tolist()
                                            if len(img) else None),
        "walls_xmin_xmax_ymin_ymax": np.bincount(img[:, 4].astype(int), minlength=4).tolist(),
        "distance_to_mirror_one_bounce_m_median": [med(img[:, 7]), med(img[:, 8])],
        "range_residual_to_mirror_one_bounce_m_median": [med(img[:, 9]), med(img[:, 10])],
        "mirror_closer_share": float(np.mean(img[:, 7] < img[:, 8])) if len(img) else None,
        "run_frames_mean_max": [float(runs.mean()), int(runs.max())] if runs.size else None,
        "episodes": int(episodes.size),
        "episode_frames_mean": float(episodes.mean()) if episodes.size else None,
        "image_frames_per_episode": float(on.sum() / max(episodes.size, 1)),
    }


def measure_frames(frames_by_radar: dict, xlim, ylim, n_people: int, rng) -> dict:
    """The figures of the module doc from new points per frame and radar."""
    n_f = len(frames_by_radar["S1"])
    res: dict = {"frames": n_f, "radars": {}}
    clouds, moving = {}, {}
    for name in RADARS:
        fr, p = _table(frames_by_radar[name])
        counts = np.bincount(fr, minlength=n_f)[1:]
        static = p[:, 3] == 0
        in_room = ((p[:, 0] >= xlim[0]) & (p[:, 0] < xlim[1]) & (p[:, 1] >= ylim[0])
                   & (p[:, 1] < ylim[1]))
        band = (p[:, 2] >= BAND_M[0]) & (p[:, 2] <= BAND_M[1])
        mv = ~static
        res["radars"][name] = {
            "points_per_frame": [float(counts.mean()), float(counts.std())],
            "moving_points_per_frame": float(np.bincount(fr[mv], minlength=n_f)[1:].mean()),
            "empty_frame_share": float(np.mean(counts == 0)),
            "no_moving_point_frame_share": float(np.mean(np.bincount(fr[mv], minlength=n_f)[1:] == 0)),
            "zero_doppler_share": float(static.mean()),
            "zero_doppler_share_in_room_band": float(static[in_room & band].mean()),
            "moving_outside_room_share": float(np.mean(~in_room[mv])),
            "snr_db_median_moving_static": [float(np.median(p[mv, 4]) / 10),
                                            float(np.median(p[static, 4]) / 10)],
        }
        clouds[name] = (fr, p)
        moving[name] = mv & in_room & band
    both_fr = np.concatenate([clouds[n][0][moving[n]] for n in RADARS])
    both_p = np.concatenate([clouds[n][1][moving[n]] for n in RADARS])
    tracks = _people_tracks(both_p, both_fr, n_f, n_people)
    room = np.array([xlim[0], xlim[1], ylim[0], ylim[1]])
    for name, (_, radar_xy) in RADARS.items():
        fr, p = clouds[name]
        sel = ((p[:, 3] != 0) & (p[:, 2] >= BAND_M[0]) & (p[:, 2] <= BAND_M[1])
               & (np.linalg.norm(p[:, :2] - radar_xy, axis=1) <= 4.0))
        res["radars"][name]["images"] = measure_images(fr[sel], p[sel], radar_xy, room, tracks, n_f)
    smooth = {}
    for name, (_, radar_xy) in RADARS.items():
        fr, p = clouds[name][0][moving[name]], clouds[name][1][moving[name]]
        errs, spread, splits, windows, counts = [], [], 0, 0, []
        rhos = []
        smooth[name] = []
        for i in range(n_people):
            c = np.full((n_f, 2), np.nan)
            for k in range(n_f):
                if not np.isfinite(tracks[i, k, 0]):
                    continue
                sel = (fr == k) & (np.linalg.norm(p[:, :2] - tracks[i, k], axis=1) < 0.6)
                if sel.any():
                    c[k] = p[sel, :2].mean(0)
                    counts.append(int(sel.sum()))
                    if sel.sum() >= 3:
                        spread.append(_radial_cross(p[sel, :2] - c[k], np.repeat(c[k][None], sel.sum(), 0),
                                                    radar_xy).std(0))
            s = _smooth(c)
            smooth[name].append(s)
            ok = np.isfinite(s[:, 0]) & np.isfinite(c[:, 0])
            if ok.sum() > 20:
                e = np.full((n_f, 2), np.nan)
                e[ok] = _radial_cross(c[ok] - s[ok], s[ok], radar_xy)
                errs.append(e[ok])
                rhos.append([_lag1(e[:, 0]), _lag1(e[:, 1])])
            for k in range(0, n_f - 10, 10):
                sel = ((fr >= k) & (fr < k + 10)
                       & (np.linalg.norm(p[:, :2] - np.nan_to_num(tracks[i, min(k + 5, n_f - 1)], nan=1e9),
                                         axis=1) < 1.0))
                if sel.sum() >= 3:
                    lab = DBSCAN(eps=0.3, min_samples=3).fit_predict(p[sel, :2])
                    n_cl = len(set(lab) - {-1})
                    if n_cl >= 1:
                        windows += 1
                        splits += n_cl >= 2
        e = np.concatenate(errs) if errs else np.zeros((0, 2))
        rho = np.nanmean(np.array(rhos), axis=0) if rhos else np.array([np.nan, np.nan])
        r = res["radars"][name]
        r["person_points_per_frame"] = [float(np.mean(counts)), float(np.std(counts))] if counts else None
        r["person_frames_seen_share"] = float(len(counts) / max(np.isfinite(tracks[..., 0]).sum(), 1))
        r["centroid_error_std_range_cross_m"] = e.std(0).tolist()
        r["centroid_error_lag1_range_cross"] = rho.tolist()
        # Standard errors with the effective number of independent frames.
        n_eff = len(e) * (1 - np.clip(rho, 0, 0.95)) / (1 + np.clip(rho, 0, 0.95))
        r["centroid_error_std_se_m"] = (e.std(0) / np.sqrt(2 * np.maximum(n_eff, 1))).tolist()
        r["centroid_error_lag1_se"] = (1 / np.sqrt(np.maximum(len(e), 1)) + 0 * rho).tolist()
        r["centroid_error_frames"] = int(len(e))
        r["centroid_error_tau_s_range_cross"] = (-FRAME_S / np.log(np.clip(rho, 1e-3, 0.999))).tolist()
        r["point_spread_std_range_cross_m"] = (np.mean(spread, axis=0).tolist() if spread else None)
        r["split_window_share"] = float(splits / max(windows, 1))
        r["split_windows"] = int(windows)
    # Reflection depth from the two radars' smoothed centroids of each person.
    rows = []
    for i in range(n_people):
        s1, s2 = smooth["S1"][i], smooth["S2"][i]
        ok = np.isfinite(s1[:, 0]) & np.isfinite(s2[:, 0])
        mid = 0.5 * (s1[ok] + s2[ok])
        u1 = mid - RADARS["S1"][1]
        u2 = mid - RADARS["S2"][1]
        u1 /= np.linalg.norm(u1, axis=1, keepdims=True)
        u2 /= np.linalg.norm(u2, axis=1, keepdims=True)
        rows.append(np.concatenate([s1[ok] - s2[ok], u1, u2], axis=1))
    rows = np.concatenate(rows) if rows else np.zeros((0, 6))
    out = {"frames_both_radars": int(len(rows))}
    if len(rows) < 50:
        res["reflection_depth_d1_d2_m"] = out
        return res
    for free in (False, True):
        fit = lambda idx: _depth_fit(rows[idx, :2], rows[idx, 2:4], rows[idx, 4:6], free)  # noqa: E731
        est = fit(np.arange(len(rows)))
        sd = _bootstrap(rows, fit, rng)
        key = "with_free_S2_translation" if free else "mounting_exact"
        out[key] = {"estimate": est.tolist(), "bootstrap_std": sd.tolist()}
    res["reflection_depth_d1_d2_m"] = out
    res["mean_centroid_offset_S1_minus_S2_m"] = rows[:, :2].mean(0).tolist()
    # The slow part of the error: the two radars' smoothed tracks of one
    # person drift apart and back over seconds (aspect, body, mounting).
    slow = rows[:, :2] - rows[:, :2].mean(0)
    res["slow_offset_std_m"] = slow.std(0).tolist()
    lags = np.arange(1, 200)
    ac = [np.mean(np.sum(slow[:-k] * slow[k:], 1)) / np.mean(np.sum(slow ** 2, 1)) for k in lags]
    below = np.flatnonzero(np.array(ac) < np.exp(-1))
    res["slow_offset_correlation_time_s"] = float(lags[below[0]] * FRAME_S) if below.size else None
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--simulated", type=int, default=0, metavar="N",
                    help="also measure N seeded simulations of the first recording's geometry")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    result = {}
    for name, (fn, xlim, ylim, n_people) in RECORDINGS.items():
        result[name] = measure_recording(args.folder / fn, xlim, ylim, n_people, rng)
    xlim, ylim = RECORDINGS["multiple_tracking"][1:3]
    for seed in range(args.simulated):
        for people in (1, 2):
            result[f"simulated_{people}_people_seed_{seed}"] = measure_frames(
                simulated_frames(seed, n_people=people), xlim, ylim, people, rng)
    text = json.dumps(result, indent=1)
    if args.json:
        args.json.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The per-node scene filters of real point clouds (mmsnap_graph.radar.scene)
on small synthetic clouds whose static scene, bodies, ghosts and blips are
known."""

from __future__ import annotations

import numpy as np
import pytest

from mmsnap_graph.data.recording import Detections
from mmsnap_graph.errors import ConfigurationError
from mmsnap_graph.radar.scene import (
    SceneConfig,
    SceneReport,
    existence_mask,
    filter_centroids,
    filter_points,
    ghost_mask,
    merge_close_centroids,
    static_scene_mask,
)

FP = 0.05                                   # 20 fps


def detections(frame, xy, doppler, snr=None) -> Detections:
    """Detections at local positions ``xy`` (K, 2) (x across, y boresight)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    r = np.hypot(xy[:, 0], xy[:, 1])
    return Detections(frame=np.asarray(frame), range_m=r, omega_rad=np.pi * xy[:, 0] / r,
                      doppler_mps=np.asarray(doppler, dtype=float),
                      snr_db=None if snr is None else np.asarray(snr, dtype=float))


def room_scene(seed=0, n_frames=400):
    """A wall point (static, every frame, quantised jitter), a walker (moving
    points) and a person who stands still for 1 s (zero Doppler) elsewhere.
    Returns the detections and each point's kind."""
    rng = np.random.default_rng(seed)
    frame, xy, dop, kind = [], [], [], []
    for f in range(n_frames):
        if rng.random() < 0.7:                                   # wall at (1, 3)
            frame.append(f), xy.append([1.0, 3.0] + rng.normal(0, 0.03, 2))
            dop.append(0.0), kind.append("wall")
        walker = np.array([-1.5 + 3.0 * f / n_frames, 2.0])
        frame.append(f), xy.append(walker + rng.normal(0, 0.05, 2))
        dop.append(0.8), kind.append("walker")
        if 100 <= f < 120:                                       # stands still 1 s
            frame.append(f), xy.append([-1.0, 1.2] + rng.normal(0, 0.03, 2))
            dop.append(0.0), kind.append("still")
    return detections(frame, xy, dop), np.asarray(kind)


def test_static_scene_drops_the_background_and_keeps_people():
    det, kind = room_scene()
    keep = static_scene_mask(det, FP)
    assert not keep[kind == "wall"].any()               # the wall: all its points
    assert keep[kind == "walker"].all()                 # moving points never
    assert keep[kind == "still"].all()                  # 1 s of 20 still: not background
    # ... but a walker crossing the wall keeps its moving points there.
    crossing = detections([5], [[1.0, 3.0]], [0.9])
    both = Detections(frame=np.r_[det.frame, crossing.frame],
                      range_m=np.r_[det.range_m, crossing.range_m],
                      omega_rad=np.r_[det.omega_rad, crossing.omega_rad],
                      doppler_mps=np.r_[det.doppler_mps, crossing.doppler_mps])
    assert static_scene_mask(both, FP)[-1]


def test_a_person_standing_most_of_the_recording_becomes_background():
    # The documented limit: standing in one place for a fifth of the windows.
    frames = np.arange(200)
    det = detections(frames, np.tile([0.5, 2.0], (200, 1)), np.zeros(200))
    assert not static_scene_mask(det, FP).any()
    # Two windows are too few to learn a background (min_windows = 3) ...
    short = detections(frames[:40], np.tile([0.5, 2.0], (40, 1)), np.zeros(40))
    assert static_scene_mask(short, FP).all()
    assert not static_scene_mask(short, FP, SceneConfig(min_windows=2)).any()


def test_merge_joins_a_split_body_and_keeps_two_people_apart():
    cents = detections([0, 0, 0, 1], [[0.0, 2.0], [0.3, 2.1], [-1.5, 3.0], [0.0, 2.0]],
                       [0.5, 0.7, -0.4, 0.5], snr=[20, 10, 15, 20])
    merged, n = merge_close_centroids(cents)
    assert n == 1 and len(merged) == 3
    xy = np.c_[merged.range_m * merged.omega_rad / np.pi,
               merged.range_m * np.sqrt(1 - (merged.omega_rad / np.pi) ** 2)]
    body = xy[(merged.frame == 0) & (xy[:, 0] > -1)][0]
    w = np.array([20, 10]) / 30                            # SNR-weighted mean
    np.testing.assert_allclose(body, w @ np.array([[0.0, 2.0], [0.3, 2.1]]), atol=1e-4)
    at = np.flatnonzero(merged.frame == 0)[np.argmin(np.abs(xy[merged.frame == 0, 0] - body[0]))]
    assert merged.doppler_mps[at] == pytest.approx(w @ [0.5, 0.7], abs=1e-4)


def test_ghost_is_the_weaker_copy_further_along_the_same_bearing():
    # A person at 2 m, a ghost at 3.2 m on the same bearing with the same
    # Doppler and a weaker return; a second person behind but at another
    # bearing, and one on the same bearing with another Doppler.
    cents = detections([0, 0, 1, 1, 2, 2],
                       [[0.4, 2.0], [0.6, 3.1], [0.4, 2.0], [-1.5, 3.0], [0.4, 2.0], [0.6, 3.1]],
                       [0.8, 0.9, 0.8, 0.8, 0.8, -0.6], snr=[20, 12, 20, 12, 20, 12])
    np.testing.assert_array_equal(ghost_mask(cents), [True, False, True, True, True, True])
    stronger = detections([0, 0], [[0.4, 2.0], [0.6, 3.1]], [0.8, 0.9], snr=[12, 20])
    assert ghost_mask(stronger).all()                      # a ghost is weaker


def test_existence_drops_a_one_frame_blip_and_keeps_a_walker():
    f = np.arange(20)
    walker = np.c_[np.linspace(-1, 1, 20), np.full(20, 2.0)]
    cents = detections(np.r_[f, 7], np.r_[walker, [[1.5, 3.5]]], np.r_[np.full(20, 0.5), 0.5])
    keep = existence_mask(cents, FP)
    assert keep[:20].all() and not keep[20]
    # A walker seen in every third frame (sparse cloud) still exists.
    sparse = detections(f[::3], walker[::3], np.full(7, 0.5))
    assert existence_mask(sparse, FP).all()


def test_filters_report_what_they_dropped_and_switch_off():
    det, kind = room_scene()
    report = SceneReport()
    kept = filter_points(det, FP, SceneConfig(), report)
    assert report.dropped["static"] == int(np.sum(kind == "wall")) == len(det) - len(kept)
    assert report.of["static"] == len(det)
    assert "static-scene points" in report.text()
    off = SceneReport()
    assert len(filter_points(det, FP, SceneConfig(static=False), off)) == len(det)
    assert off.dropped == {} and off.text() == "no scene filter"
    cents = detections([0, 0, 5], [[0.0, 2.0], [0.2, 2.0], [1.0, 1.0]], [0.5, 0.5, 0.5])
    rep = SceneReport()
    out = filter_centroids(cents, FP, SceneConfig(), rep)
    assert rep.dropped == {"merge": 1, "ghosts": 0, "existence": 2} and len(out) == 0
    rep = SceneReport()
    none = SceneConfig(merge=False, ghosts=False, existence=False)
    assert len(filter_centroids(cents, FP, none, rep)) == 3 and rep.dropped == {}


@pytest.mark.parametrize("bad", [dict(cell_m=0.0), dict(min_occupancy=1.5),
                                 dict(zero_doppler_mps=-1.0), dict(static="yes"),
                                 dict(existence_min_frames=1.5), dict(body_m=float("nan"))])
def test_bad_options_are_configuration_errors(bad):
    with pytest.raises(ConfigurationError, match=next(iter(bad))):
        SceneConfig(**bad)

"""``mmsnap plot``'s figure (mmsnap_graph.app.view.plot), on a simulated,
calibrated and fused recording (tests/app/conftest.py's ``fused_b_file``)."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from matplotlib.patches import Polygon

from mmsnap_graph.app.view.plot import PlotOptions, plot_recording, save_plot
from mmsnap_graph.app.view.scene import id_color
from mmsnap_graph.errors import ValidationError
from mmsnap_graph.io import read_fused


def _texts(ax):
    return [t.get_text() for t in ax.texts]


def test_the_figure_shows_radars_points_room_and_each_person_id(fused_b_file):
    fused = read_fused(fused_b_file)
    fig = plot_recording(fused_b_file, PlotOptions(bounds=(-4, 4, -1, 8)))
    ax = fig.axes[0]
    ids = sorted(set(fused.track_id[fused.success].tolist()))
    assert ids and ids[0] >= 0
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(t.startswith("S1 centroids (") for t in labels)
    assert "room (--bounds)" in labels and any("fields of view" in t for t in labels)
    assert f"fused people: path per id ({len(ids)})" in labels
    assert {"S1", "S2"} <= set(_texts(ax)) and {str(i) for i in ids} <= set(_texts(ax))
    # Each id's label is in its colour, at the person's first position.
    for t in ax.texts:
        if t.get_text() in {str(i) for i in ids}:
            tid = int(t.get_text())
            assert np.allclose(t.get_color()[:3] if not isinstance(t.get_color(), str)
                               else (0, 0, 0), id_color(tid))
            rows = np.flatnonzero(fused.success & (fused.track_id == tid))
            first = rows[np.argmin(fused.frame[rows])]
            np.testing.assert_allclose(t.xy, fused.state[first, :2])
    # The filled 2-sigma ellipses lie on the contour of their row's covariance.
    ellipses = [p for p in ax.patches if isinstance(p, Polygon) and len(p.get_xy()) >= 48]
    assert len(ellipses) >= len(ids)
    ok = np.flatnonzero(fused.success)
    for p in ellipses[:5]:
        xy = p.get_xy()[:48]
        c = xy.mean(axis=0)
        k = ok[np.argmin(np.linalg.norm(fused.state[ok, :2] - c, axis=1))]
        d = xy - fused.state[k, :2]
        m2 = np.einsum("ki,ij,kj->k", d, np.linalg.inv(fused.covariance[k][:2, :2]), d)
        np.testing.assert_allclose(m2, 4.0, rtol=1e-6)
    assert ax.get_xlabel().startswith("x (m)") and ax.get_ylabel().startswith("y (m)")


def test_a_recording_not_fused_shows_points_and_radars(fused_b_file, tmp_path):
    rec = tmp_path / "rec.h5"
    shutil.copy(fused_b_file, rec)
    with h5py.File(rec, "a") as f:
        del f["fused"]
    fig = plot_recording(rec)
    title = fig.axes[0].get_title()
    assert "not fused (mmsnap fuse)" in title and "room: not drawn (give --bounds)" in title
    save_plot(fig, tmp_path / "rec.png")
    with pytest.raises(ValidationError, match="written as png or svg"):
        save_plot(fig, tmp_path / "rec.jpg")


@pytest.mark.parametrize("kwargs, match", [
    (dict(bounds=(1, 0, 0, 1)), "x_min < x_max"), (dict(frames=(5, 2)), "first <= last"),
    (dict(source="cube"), "source="), (dict(ellipse_every_s=0.0), "ellipse_every_s"),
    (dict(fov_range_m=-1.0), "fov_range_m"), (dict(dpi=50), "dpi=50"),
    # before: matplotlib's TypeError out of mmsnap plot --dpi 1000000000
    (dict(dpi=10**9), r"dpi=1000000000 must be an integer within \[100, 600\] \(--dpi\)")])
def test_plot_options_are_checked(kwargs, match):
    with pytest.raises(ValidationError, match=match):
        PlotOptions(**kwargs)

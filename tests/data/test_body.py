"""A person's size (mmsnap_graph.data.body): every filter that decides when
two detections are one body takes its default from one named constant, and
docs/CONVENTIONS.md lists them as the code has them. Before: 0.5 m in the
scene filters and the fused-row check and 0.6 m in fusion's merge, each
written where it was used (0.6 twice), all called "a body's width"."""

from __future__ import annotations

import inspect
import re

from mmsnap_graph.data import body
from mmsnap_graph.data.body import BODY_WIDTH_M, CENTROID_MERGE_RADIUS_M, SCENE_MERGE_RADIUS_M
from mmsnap_graph.fusion.config import AssociationOptions
from mmsnap_graph.fusion.recording import regroup, room
from mmsnap_graph.radar.scene import SceneConfig

from _shared import ROOT


def test_each_filter_takes_its_default_from_the_named_constant():
    assert SceneConfig().body_m == SCENE_MERGE_RADIUS_M
    assert AssociationOptions().merge_body_m == CENTROID_MERGE_RADIUS_M
    assert regroup.DEFAULT_MERGE_BODY_M == CENTROID_MERGE_RADIUS_M
    assert room.DEFAULT_BODY_M == BODY_WIDTH_M
    assert inspect.signature(room.screen_room).parameters["body_m"].default == BODY_WIDTH_M


def test_a_merge_radius_covers_at_least_the_body_width():
    # A bare centroid's merge radius is the body's extent plus its centroids'
    # spread: never below the width.
    assert CENTROID_MERGE_RADIUS_M >= BODY_WIDTH_M
    assert SCENE_MERGE_RADIUS_M >= BODY_WIDTH_M


def test_the_conventions_page_lists_each_size_as_the_code_has_it():
    text = (ROOT / "docs" / "CONVENTIONS.md").read_text()
    rows = dict(re.findall(r"^\| `([A-Z_]+_M)` \| ([0-9.]+) m \|", text, flags=re.M))
    assert rows == {name: f"{getattr(body, name):g}" for name in body.__all__}

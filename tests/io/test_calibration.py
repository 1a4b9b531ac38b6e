"""The calibration file formats (mmsnap_graph.io.calibration): the
``/calibration`` group and the calibration JSON, written and read back."""

from __future__ import annotations

import copy
import dataclasses
import json

import h5py
import numpy as np
import pytest

from mmsnap_graph.calibration import calibrate_recording
from mmsnap_graph.data.calibration import PairwiseCalibration, RecordingCalibration
from mmsnap_graph.data.calibration_facts import (
    CalibrationStatus,
    ClockOffsetsTried,
    JointFit,
    LagEvidence,
    LagNotDetermined,
    PoseCovariance,
    PoseNotObservable,
)
from mmsnap_graph.errors import CalibrationError, FileFormatError
from mmsnap_graph.io import read_recording, write_recording
from mmsnap_graph.io.calibration import (
    CALIBRATION_GROUP,
    calibration_to_json,
    fact_to_json,
    load_calibration_poses,
    read_calibration,
    read_calibration_json,
    write_calibration,
    write_calibration_json,
)
from mmsnap_graph.sim import simulate_recording

from _shared import POSES_A, POSES_C
from mmsnap_graph.sim import CLEAN


def _calibration() -> RecordingCalibration:
    """Three nodes, S3 unreachable; a NaN RMSE and an inf in a covariance."""
    cov = np.diag([1e-4, 2e-4, 3e-6])
    evidence = LagEvidence(node_a="S1", node_b="S2", lag_frames=1, outcome="determined", z=7.5,
                           evidence_z=3.0, window_frames=2)
    edge = PairwiseCalibration(node_a="S1", node_b="S2", pose=[0.1, 6.9, 3.1], covariance=cov,
                               rmse_m=0.12, n_frames=250, lag_frames=1, lag_evidence=evidence)
    edge2 = PairwiseCalibration(node_a="S2", node_b="S1", pose=[0.2, 7.0, -3.1],
                                covariance=2 * cov, rmse_m=float("nan"), n_frames=7,
                                lag_frames=-1, lag_ambiguous=True)
    cov2 = cov.copy()
    cov2[2, 2] = np.inf
    return RecordingCalibration(
        reference="S1", node_names=("S1", "S3", "S2"),
        poses={"S1": np.zeros(3), "S2": np.array([0.1, 6.9, 3.1])},
        covariances={"S1": np.zeros((3, 3)), "S2": cov2}, lag_frames={"S1": 0, "S2": 1},
        unreachable=("S3",), edges=(edge, edge2), method="joint", source="centroids",
        status=CalibrationStatus.NODES_UNREACHABLE, failures={"S3": "node S3 has no tracks"},
        facts=(evidence, JointFit(n_nodes=2, n_frames=250, presolve_steps=(6, 4)),
               PoseCovariance(method="long_run", bandwidth_frames=14, max_widening=2.5),
               PoseNotObservable(node="S2", directions=((1.0, 0.0, 0.0),)),
               ClockOffsetsTried(outcome="solve_failed",
                                 solve_status=CalibrationStatus.NOT_OBSERVABLE),
               LagNotDetermined(node_a="S1", node_b="S2", tested=True, kept_shifts=(1,),
                                rejected_shifts=(-1, 2), clock_fraction=0.3)))


def _assert_same(back: RecordingCalibration, cal: RecordingCalibration) -> None:
    for name in ("reference", "node_names", "unreachable", "method", "source", "status"):
        assert getattr(back, name) == getattr(cal, name), name
    # The facts come back equal, NaN fields included (compared as their JSON).
    assert [fact_to_json(f) for f in back.facts] == [fact_to_json(f) for f in cal.facts]
    assert dict(back.failures) == dict(cal.failures)
    assert dict(back.lag_frames) == dict(cal.lag_frames)
    assert set(back.poses) == set(cal.poses) == set(back.covariances)
    for n in cal.poses:
        np.testing.assert_array_equal(back.poses[n], cal.poses[n])
        np.testing.assert_array_equal(back.covariances[n], cal.covariances[n])
    assert len(back.edges) == len(cal.edges)
    for a, b in zip(back.edges, cal.edges):
        assert (a.node_a, a.node_b, a.n_frames, a.lag_frames) == (b.node_a, b.node_b, b.n_frames,
                                                                  b.lag_frames)
        np.testing.assert_array_equal(a.pose, b.pose)
        np.testing.assert_array_equal(a.covariance, b.covariance)
        np.testing.assert_array_equal(a.rmse_m, b.rmse_m)
        assert (a.lag_evidence, a.lag_ambiguous) == (b.lag_evidence, b.lag_ambiguous)


@pytest.fixture(scope="module")
def rec3():
    return simulate_recording({"S1": POSES_C[0], "S2": POSES_C[1], "S3": POSES_A[1]}, "random",
                              CLEAN, levels=["centroids"], n_frames=30, seed=1)


def test_hdf5_group_round_trip(tmp_path, rec3):
    path = tmp_path / "rec.h5"
    write_recording(path, rec3)
    cal = _calibration()
    out = write_calibration(path, rec3, cal, output=tmp_path / "copy.h5")
    assert out == tmp_path / "copy.h5"
    _assert_same(read_calibration(out), cal)
    back = read_recording(out)
    np.testing.assert_array_equal(back.nodes["S2"].pose, cal.poses["S2"])
    assert back.nodes["S3"].pose is None
    with pytest.raises(FileFormatError, match="/calibration is missing"):
        read_calibration(path)  # the original is untouched
    # written in place, a second time: the group is replaced
    write_calibration(path, rec3, cal)
    write_calibration(path, rec3, cal)
    _assert_same(read_calibration(path), cal)


def test_json_round_trip(tmp_path):
    cal = _calibration()
    path = write_calibration_json(tmp_path / "cal.json", cal)
    data = json.loads(path.read_text())
    assert data["nodes"]["S2"]["covariance"][2][2] is None  # inf is not JSON
    assert data["edges"][1]["rmse_m"] is None
    back = read_calibration_json(path)
    assert back.covariances["S2"][2, 2] != back.covariances["S2"][2, 2]  # None -> NaN
    expected = dict(calibration_to_json(cal))
    assert calibration_to_json(back) == expected
    assert read_calibration_json(data).node_names == ("S1", "S3", "S2")
    np.testing.assert_array_equal(load_calibration_poses(path)["S2"], cal.poses["S2"])


def test_a_real_calibration_round_trips(tmp_path):
    rec = simulate_recording("C", "random", CLEAN, levels=["centroids"], n_frames=120, seed=5)
    path = tmp_path / "c.h5"
    write_recording(path, rec)
    cal = calibrate_recording(rec, method="pose_graph")
    write_calibration(path, rec, cal)
    _assert_same(read_calibration(path), cal)
    _assert_same(read_calibration_json(write_calibration_json(tmp_path / "c.json", cal)), cal)


def test_minimal_json_reads_with_defaults():
    back = read_calibration_json({"nodes": {"S1": {"pose": [0, 0, 0]},
                                            "S2": {"pose": [1, 2, 0.5]}}})
    assert back.reference == "S1" and back.node_names == ("S1", "S2") and back.success
    assert np.all(np.isnan(back.covariances["S2"])) and back.lag_frames["S2"] == 0
    with pytest.raises(CalibrationError, match=r"nodes\['S2'\].covariance must be 3 x 3"):
        read_calibration_json({"nodes": {"S2": {"pose": [1, 2, 0], "covariance": [1, 2]}}})
    with pytest.raises(CalibrationError, match="not in node_names"):
        read_calibration_json({"nodes": {"S2": {"pose": [1, 2, 0]}}, "node_names": ["S1"]})
    with pytest.raises(CalibrationError, match=r"edges\[0\] is not a pose edge"):
        read_calibration_json({"nodes": {"S2": {"pose": [1, 2, 0]}}, "edges": [{"node_a": "S1"}]})


def test_read_errors_name_the_problem(tmp_path, rec3):
    with pytest.raises(FileFormatError, match="does not exist"):
        read_calibration(tmp_path / "none.h5")
    bad = tmp_path / "bad.h5"
    bad.write_text("not hdf5")
    with pytest.raises(FileFormatError, match="not a readable HDF5 file"):
        read_calibration(bad)
    path = tmp_path / "rec.h5"
    write_recording(path, rec3)
    write_calibration(path, rec3, _calibration())
    with h5py.File(path, "r+") as f:
        del f[f"{CALIBRATION_GROUP}/edges/pose"]
    with pytest.raises(FileFormatError, match="/calibration/edges/pose is missing"):
        read_calibration(path)
    with pytest.raises(FileFormatError, match="does not exist"):
        write_calibration(tmp_path / "nope.h5", rec3, _calibration())


# ---- calibration JSON: every malformed field is a CalibrationError naming it ---------
_GOOD_JSON = {"reference": "S1", "node_names": ["S1", "S2", "S3"],
              "nodes": {"S1": {"pose": [0, 0, 0], "lag_frames": 0},
                        "S2": {"pose": [0, 7, 3.1], "lag_frames": 2,
                               "covariance": np.eye(3).tolist()}},
              "unreachable": ["S3"], "edges": [], "failures": {}, "success": True}


def _json_with(path, value):
    import copy
    data = copy.deepcopy(_GOOD_JSON)
    obj = data
    for key in path[:-1]:
        obj = obj[key]
    obj[path[-1]] = value
    return data


@pytest.mark.parametrize("path, value, match", [
    (("nodes", "S2", "lag_frames"), "x", r"nodes\['S2'\].lag_frames='x' must be an integer"),
    (("nodes", "S2", "lag_frames"), 1e400, r"lag_frames=inf must be an integer within"),
    (("nodes", "S2", "lag_frames"), 2.5, r"lag_frames=2.5 must be an integer within"),
    (("nodes", "S2", "lag_frames"), True, r"lag_frames=True must be an integer"),
    (("unreachable",), True, r"unreachable must be a list of node names, got True"),
    (("unreachable",), "S3", r"unreachable must be a list of node names"),
    (("node_names",), {"S1": 1}, r"node_names must be a list of node names"),
    (("edges",), {"a": 1}, r"edges must be a list"),
    (("edges",), [{"node_a": "S1", "node_b": "S2", "pose": [0, 7, 3.1],
                   "covariance": np.eye(3).tolist(), "n_frames": 1e400}],
     r"edges\[0\].n_frames=inf must be an integer"),
    (("edges",), [[1, 2]], r"edges\[0\] is not a pose edge"),
    (("failures",), [1], r"failures must be an object"),
    (("success",), "yes", r"success must be true or false"),
    (("reference",), 5, r"reference must be a string"),
    (("nodes", "S2", "pose"), [0, 7, 180], r"phi_rad=180.0 lies outside \[-2 pi, 2 pi\].*degrees"),
])
def test_calibration_json_bad_fields_are_calibration_errors(path, value, match):
    from mmsnap_graph.errors import CalibrationError
    from mmsnap_graph.io.calibration import read_calibration_json
    cal = read_calibration_json(_GOOD_JSON)
    assert cal.lag_frames == {"S1": 0, "S2": 2} and cal.unreachable == ("S3",)
    with pytest.raises(CalibrationError, match=match):
        read_calibration_json(_json_with(path, value))


def test_calibration_json_nested_too_deeply(tmp_path):
    from mmsnap_graph.errors import CalibrationError
    from mmsnap_graph.io.calibration import read_calibration_json
    path = tmp_path / "deep.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(CalibrationError, match="nested too deeply"):
        read_calibration_json(path)


def test_the_range_offset_round_trips(tmp_path, rec3):
    """JSON and the HDF5 group keep the range offset and its variance; a file
    without them reads NaN; a bad value names the field."""
    cal = dataclasses.replace(_calibration(), range_offset_m=0.084, range_offset_variance=0.001)
    back = read_calibration_json(write_calibration_json(tmp_path / "cal.json", cal))
    assert back.range_offset_m == 0.084 and back.range_offset_variance == 0.001
    path = tmp_path / "rec.h5"
    write_recording(path, rec3)
    write_calibration(path, rec3, cal)
    assert read_calibration(path).range_offset_m == 0.084
    assert np.isnan(read_calibration_json(write_calibration_json(
        tmp_path / "none.json", _calibration())).range_offset_m)
    data = calibration_to_json(cal)
    with pytest.raises(CalibrationError, match="range_offset_m must lie within"):
        read_calibration_json({**data, "range_offset_m": 8.4})
    with pytest.raises(CalibrationError, match="range_offset_m must be a number"):
        read_calibration_json({**data, "range_offset_m": "0.08"})


def test_calibration_json_seeded_mutations_raise_only_calibration_errors():
    """Every leaf and container of a calibration JSON replaced by odd values
    (seeded): a calibration or a CalibrationError, never another exception."""
    import copy
    from mmsnap_graph.errors import CalibrationError
    from mmsnap_graph.io.calibration import read_calibration_json

    def paths(obj, path=()):
        yield path
        items = obj.items() if isinstance(obj, dict) else enumerate(obj) \
            if isinstance(obj, list) else ()
        for key, value in items:
            yield from paths(value, path + (key,))

    odd = [None, True, "x", 1e400, -1e400, float("nan"), 10 ** 30, [], {}, [1, 2], {"a": 1},
           2.5, -7, "", 10 ** 400, -10 ** 400, 2 ** 63]  # huge integers: issue 29
    rng = np.random.default_rng(3)
    all_paths = [p for p in paths(_GOOD_JSON) if p]
    read, refused = 0, 0
    for _ in range(400):
        data = copy.deepcopy(_GOOD_JSON)
        path = all_paths[int(rng.integers(len(all_paths)))]
        obj = data
        for key in path[:-1]:
            obj = obj[key]
        obj[path[-1]] = odd[int(rng.integers(len(odd)))]
        try:
            read_calibration_json(data)
            read += 1
        except CalibrationError:
            refused += 1
    assert refused > 200 and read > 10, (read, refused)


@pytest.mark.parametrize(
    "content, match",
    [
        ("{", "is not readable calibration JSON"),
        (json.dumps({"nodes": {}}), "missing or empty 'nodes'"),
        (json.dumps({"nodes": {"S1": {}}}), r"nodes\['S1'\] has no 'pose'"),
        (json.dumps({"nodes": {"S1": {"pose": [0, 0]}}}), r"nodes\['S1'\].pose must be 3 finite"),
        (json.dumps({"nodes": {"S1": {"pose": ["a", 0, 0]}}}), "is not numeric"),
    ],
)
def test_calibration_json_errors(tmp_path, content, match):
    path = tmp_path / "c.json"
    path.write_text(content)
    with pytest.raises(CalibrationError, match=match):
        load_calibration_poses(path)


# ---- status and facts --------------------------------------------------------------
#: The calibration JSON of ``simulate_recording("C", "random", CLEAN,
#: levels=["centroids"], n_frames=120, seed=5)`` as ``calibration_to_json`` wrote
#: it before the status and the facts (commit 80ec03d): the message was the record.
OLD_JSON = {
    "reference": "S1", "node_names": ["S1", "S2"],
    "nodes": {"S1": {"pose": [0.0, 0.0, 0.0], "covariance": [[0.0] * 3] * 3, "lag_frames": 0,
                     "time_offset_s": 0.0, "time_offset_variance_s2": 0.0},
              "S2": {"pose": [-0.04354198428848501, 7.004682855081914, -3.1248043747757697],
                     "covariance": [[0.0024572590965529985, -3.214782957393955e-05,
                                     0.0006400356125753779],
                                    [-3.214782957393955e-05, 5.6088090869322716e-05,
                                     -8.692054296034093e-06],
                                    [0.0006400356125753779, -8.692054296034093e-06,
                                     0.0001798923958992489]],
                     "lag_frames": 0, "time_offset_s": -0.0027402522960746976,
                     "time_offset_variance_s2": 0.000143613296967611}},
    "unreachable": [], "method": "joint", "source": "centroids", "success": True,
    "message": "2 node(s) calibrated from 1 edge(s) (joint least squares on the matched "
               "points); sigmas estimated from residuals for the joint graph: range 0.0555 m "
               "estimated, omega 0.09 rad estimated, doppler 0.0923 m/s estimated; joint "
               "calibration of 2 nodes on 120 frames, 0 outlier detection(s), numpy pre-solve "
               "6+4 step(s) (converged), then 1 GTSAM Gauss-Newton/LM step(s) confirming its "
               "optimum; covariance: the graph's marginals (the long-run covariance over 14 "
               "frames is within their sampling noise); noise from the data (network+temporal): "
               "6 of 6 node sigmas identified",
    "edges": [{"node_a": "S1", "node_b": "S2",
               "pose": [-0.04766172603989677, 7.005164381649461, -3.1231074739288758],
               "covariance": [[0.7718224566924782, -0.014615069709770423, 0.21723976476418883],
                              [-0.014615069709770423, 0.00037569975815833153,
                               -0.004114312828202078],
                              [0.21723976476418883, -0.004114312828202078, 0.0611528937985687]],
               "rmse_m": 0.15255825787190666, "n_frames": 120, "lag_frames": 0}],
    "failures": {}}


def test_a_file_without_status_and_facts_reads_its_status_from_success():
    old = read_calibration_json(OLD_JSON)
    assert old.success and old.status is CalibrationStatus.OK and old.method == "joint"
    assert old.facts == ()  # its message is the status's line, not a fact
    np.testing.assert_array_equal(old.poses["S2"], OLD_JSON["nodes"]["S2"]["pose"])
    assert old.edges[0].lag_evidence is None and not old.edges[0].lag_ambiguous
    # The same recording calibrated now: the same numbers, now with facts.
    rec = simulate_recording("C", "random", CLEAN, levels=["centroids"], n_frames=120, seed=5)
    new = calibration_to_json(calibrate_recording(rec))
    for key in ("pose", "covariance", "time_offset_s", "time_offset_variance_s2"):
        np.testing.assert_allclose(new["nodes"]["S2"][key], OLD_JSON["nodes"]["S2"][key],
                                   rtol=1e-9, atol=1e-15)
    assert new["status"] == "ok" and [f["kind"] for f in new["facts"]][:3] == [
        "pose_graph_fit", "joint_noise", "joint_fit"]
    failed = read_calibration_json({**OLD_JSON, "success": False, "unreachable": ["S3"],
                                    "node_names": ["S1", "S2", "S3"]})
    assert failed.status is CalibrationStatus.NODES_UNREACHABLE
    broken = read_calibration_json({**OLD_JSON, "success": False, "message": ""})
    assert broken.status is CalibrationStatus.SOLVE_FAILED and broken.facts == ()


def test_a_group_without_status_and_facts_reads_its_status_from_success(tmp_path, rec3):
    path = tmp_path / "old.h5"
    write_recording(path, rec3)
    write_calibration(path, rec3, _calibration())
    with h5py.File(path, "r+") as f:  # the group without status and facts
        g = f[CALIBRATION_GROUP]
        del g.attrs["status"]
        data = json.loads(g.attrs["json"])
        for key in ("status", "facts"):
            del data[key]
        for e in data["edges"]:
            e.pop("lag_evidence", None), e.pop("lag_ambiguous", None)
        g.attrs["json"] = json.dumps({**data, "message": "no path from S3"})
        g.attrs["message"] = "no path from S3"
        g.attrs["success"] = False
    back = read_calibration(path)
    assert back.status is CalibrationStatus.NODES_UNREACHABLE and back.unreachable == ("S3",)
    assert back.facts == ()
    assert back.edges[0].lag_evidence is None


@pytest.mark.parametrize("facts, match", [
    ([{"kind": "guess"}], r"facts\[0\]: kind 'guess' is not one of \["),
    (["lag not determined"], r"facts\[0\]: kind 'lag not determined' is not one of"),
    ([{"kind": "joint_rejected", "status": "ok", "why": "x"}],
     r"facts\[0\]: joint_rejected has no field\(s\) \['why'\]"),
    ([{"kind": "joint_rejected"}], r"facts\[0\]: .*missing 1 required keyword-only argument"),
    ([{"kind": "pose_covariance", "method": "guess"}], r"pose_covariance.method='guess'"),
    ({"kind": "joint_fit"}, r"facts must be a list"),
])
def test_bad_facts_are_calibration_errors_naming_them(facts, match):
    with pytest.raises(CalibrationError, match=match):
        read_calibration_json({**_GOOD_JSON, "facts": facts})


def test_a_bad_status_or_lag_evidence_is_named():
    with pytest.raises(CalibrationError, match=r"status 'fine' must be one of"):
        read_calibration_json({**_GOOD_JSON, "status": "fine"})
    edge = {"node_a": "S1", "node_b": "S2", "pose": [0, 7, 3.1],
            "covariance": np.eye(3).tolist(), "lag_evidence": {"kind": "joint_skipped"}}
    with pytest.raises(CalibrationError, match=r"edges\[0\].lag_evidence must be a "
                                               r"lag_evidence fact, got joint_skipped"):
        read_calibration_json({**_GOOD_JSON, "edges": [edge]})


def test_every_fact_kind_is_documented_in_the_format():
    from mmsnap_graph.data.calibration_facts import FACT_KINDS, CalibrationStatus as S
    from _shared import ROOT

    doc = (ROOT / "docs" / "FORMAT.md").read_text()
    for kind in FACT_KINDS:
        assert f"| `{kind}` |" in doc, kind
    for s in S:
        assert f"| `{s.label}` | {s.message} |" in doc, s


@pytest.mark.parametrize("path, match", [
    (("nodes", "S2", "pose", 0), r"nodes\['S2'\].pose must be 3 finite numbers"),
    (("nodes", "S2", "covariance", 0, 0), r"nodes\['S2'\].covariance must be finite"),
    (("nodes", "S2", "lag_frames"), r"lag_frames=inf must be an integer within"),
    (("nodes", "S2", "time_offset_s"), r"time_offset_s must be finite"),
    (("nodes", "S2", "time_offset_variance_s2"), r"time_offset_variance_s2 must be finite"),
    (("range_offset_m",), "range_offset_m must be finite"),
    (("range_offset_variance_m2",), "range_offset_variance_m2 must be finite"),
])
@pytest.mark.parametrize("digits", [401, 5000])
def test_a_huge_integer_in_the_file_is_a_calibration_error(tmp_path, path, match, digits):
    """Before: 10**400 in a calibration JSON raised OverflowError out of
    fuse, noise, replay --calibration and monitor --poses (and an integer of
    more than 4300 digits ValueError out of the parser)."""
    data = copy.deepcopy(_GOOD_JSON)
    data["nodes"]["S2"].setdefault("time_offset_s", 0.0)
    data["nodes"]["S2"].setdefault("time_offset_variance_s2", 1e-4)
    obj = data
    for key in path[:-1]:
        obj = obj[key]
    obj[path[-1]] = "HUGE"
    text = json.dumps(data).replace('"HUGE"', "1" + "0" * (digits - 1))
    file = tmp_path / "huge.json"
    file.write_text(text)
    with pytest.raises(CalibrationError, match=match) as info:
        read_calibration_json(file)
    assert len(str(info.value)) < 300  # the number is not printed in full
    if path[0] == "nodes" and path[2] == "pose":
        data_py = copy.deepcopy(data)
        data_py["nodes"]["S2"]["pose"][0] = 10 ** 400  # a mapping, not a file
        with pytest.raises(CalibrationError, match="beyond the float range"):
            read_calibration_json(data_py)

"""Two real TI recordings (``data/real/darksz/``) through the whole CLI:
``import table`` -> ``process`` -> ``calibrate`` -> ``fuse`` -> ``evaluate
--surveyed``, as a user with these point tables would run it.

There is no ground truth of the people. What can be known is checked: S2's
pose against the tape-measured mounting (0.1 m, 3 degrees), the two halves of
a recording calibrated separately agreeing within their reported covariance,
the fused people inside the room box of the recorder's configuration, and at
most the known number of people in a frame (the recorder tracked at most two
objects in both recordings: ``TRK_obj_bin_number = 2`` in its configuration).
Each test prints the figures it measured (``pytest -s``).
"""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import pickle
from contextlib import redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from _shared import DATA
from mmsnap_graph.app.cli import main
from mmsnap_graph.data.results import Status
from mmsnap_graph.io.fused import read_fused
from mmsnap_graph.io.noise import read_noise

REAL = DATA / "real" / "darksz"
SURVEYED_S2 = (1.70, 1.65, 90.0)            # x_m, y_m, phi_deg in S1's frame (tape)
TAPE_M, TAPE_DEG = 0.1, 3.0
MAX_PEOPLE = 2


@dataclass(frozen=True)
class Real:
    """One recording: its tables, the S2 mounting height and the room box."""

    stem: str
    s2_height_m: float
    room: tuple[float, float, float, float]          # x_min, x_max, y_min, y_max (m)


RECORDINGS = {
    "multiple_tracking": Real("multiple_tracking", 1.1, (-2.0, 1.6, 0.0, 3.6)),
    "fall_detection": Real("fall_detection", 2.45, (-1.7, 1.6, 0.0, 3.6)),
}


def import_args(real: Real, s1: Path, s2: Path, out: Path) -> list[str]:
    """The import of docs/TI.md for these tables: room-frame points, each
    radar's nominal pose and height, floor and ceiling dropped."""
    return ["import", "table", "--node", f"S1={s1}", "--node", f"S2={s2}",
            "--frame-period", "0.05", "--mount", "S1=0.8,0",
            "--mount", f"S2={real.s2_height_m},0", "--room-pose", "S1=0,0,0",
            "--room-pose", "S2={},{},{}".format(*SURVEYED_S2), "--height-band", "0.2,2.0",
            "-o", str(out)]


def run(args: list[str]) -> None:
    assert main(args) == 0, f"mmsnap {' '.join(args)} failed"


def calibrated(real: Real, s1: Path, s2: Path, out: Path) -> dict:
    """import -> process -> calibrate; the calibration JSON."""
    run(import_args(real, s1, s2, out))
    run(["process", str(out)])
    run(["calibrate", str(out)])
    return json.loads(out.with_suffix(".calibration.json").read_text())


def split_table(src: Path, mid: int, first: Path, second: Path) -> None:
    """Rows of frames < mid to ``first``, the others to ``second``."""
    with open(src, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    k = header.index("frame")
    for path, keep in ((first, lambda r: int(r[k]) < mid), (second, lambda r: int(r[k]) >= mid)):
        with open(path, "w", newline="") as f:
            csv.writer(f).writerows([header] + [r for r in body if keep(r)])


def n_frames(real: Real) -> int:
    frames = set()
    for node in ("S1", "S2"):
        with open(REAL / f"{real.stem}_{node}.csv", newline="") as f:
            frames |= {int(r["frame"]) for r in csv.DictReader(f)}
    return max(frames) + 1


class _Runs:
    """The chain run once per recording (whole and halves), on demand."""

    def __init__(self, base: Path):
        self.base, self.whole, self.halves = base, {}, {}

    def full(self, stem: str):
        """(calibration JSON, evaluate JSON, fused sequence with --bounds,
        without, with --in-front) of the whole recording."""
        if stem not in self.whole:
            real = RECORDINGS[stem]
            out = self.base / f"{stem}.h5"
            cal = calibrated(real, REAL / f"{stem}_S1.csv", REAL / f"{stem}_S2.csv", out)
            free = self.base / f"{stem}_no_bounds.h5"
            run(["fuse", str(out), "-o", str(free)])
            front = self.base / f"{stem}_in_front.h5"
            run(["fuse", str(out), "-o", str(front), "--in-front"])
            run(["fuse", str(out), "--bounds={},{},{},{}".format(*real.room)])
            buf = io.StringIO()
            with redirect_stdout(buf):
                assert main(["evaluate", str(out), "--json", "--surveyed", "S1=0,0,0",
                             "--surveyed", "S2={},{},{}".format(*SURVEYED_S2)]) == 0
            self.whole[stem] = (cal, json.loads(buf.getvalue()), read_fused(out),
                                read_fused(free), read_fused(front))
        return self.whole[stem]

    def half_calibrations(self, stem: str) -> list[dict]:
        """The calibration JSON of each half (frames split at the middle)."""
        if stem not in self.halves:
            real, mid = RECORDINGS[stem], n_frames(RECORDINGS[stem]) // 2
            for node in ("S1", "S2"):
                split_table(REAL / f"{stem}_{node}.csv", mid, self.base / f"{stem}_a_{node}.csv",
                            self.base / f"{stem}_b_{node}.csv")
            self.halves[stem] = [calibrated(real, self.base / f"{stem}_{h}_S1.csv",
                                            self.base / f"{stem}_{h}_S2.csv",
                                            self.base / f"{stem}_{h}.h5") for h in "ab"]
        return self.halves[stem]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return _Runs(tmp_path_factory.mktemp("real"))


def inside_fraction(real: Real, fused) -> float:
    ok = np.asarray(fused.success, bool)
    xy = np.asarray(fused.state)[ok, :2]
    x0, x1, y0, y1 = real.room
    return float(np.mean((xy[:, 0] >= x0) & (xy[:, 0] <= x1)
                         & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)))


def people_ok_fraction(real: Real, fused) -> tuple[float, int]:
    """Fraction of the recording's frames with at most MAX_PEOPLE fused
    people (successful rows), and the largest count in a frame."""
    ok = np.asarray(fused.success, bool)
    counts = np.bincount(np.asarray(fused.frame)[ok], minlength=n_frames(real))
    return float(np.mean(counts <= MAX_PEOPLE)), int(counts.max())


def _cases(xfails: dict) -> list:
    """Both recordings; those in ``xfails`` (stem -> today's figures) as
    strict xfails: they must fail until the target is reached."""
    return [pytest.param(stem, marks=pytest.mark.xfail(strict=True, reason=xfails[stem]))
            if stem in xfails else stem for stem in RECORDINGS]


# Measured on these tables; the targets are the asserts. Before the scene
# filters and room checks: 72.4% / 59.1% of fused rows inside the room, <= 2
# people in 6.7% / 54.2% of frames (multiple tracking / fall detection).
POSE_XFAIL = {"multiple_tracking": (
    "S2 heading -3.76 deg from the tape (0.046 m); tape 3 deg. The data do not fix it better: "
    "the halves give -4.47 and -0.04 deg, one person's tracks -9.0 to +9.1 deg (the simulator's "
    "real model in this geometry: +1.06 +- 0.77 deg on 11 of 12 seeds, halves 0.8-1.5 deg apart), "
    "and an angle bias of the radar (no Rx phase compensation in its cfg) is calibrated as "
    "heading at no cost in the fit "
    "(docs/validation/calibration.md, \"A node's heading on real recordings\")")}
# Halves, compared in the reference frame: with the joint graph's marginals
# (`mmsnap calibrate --covariance model`) (0.7, 1.0, 1.2) sigma (multiple
# tracking) and (1.5, 8.2, 6.3) (fall detection); with the default long-run
# covariance (0.4, 0.6, 0.8) and (0.1, 1.4, 1.5).
HALVES_XFAIL: dict = {}
# Without a room box, the walls learned from the multipath images flag what a
# radar sees through a wall: 96.3% / 100% of fused rows inside the room
# (90.1% / 93.7% without them, `mmsnap fuse --no-learned-walls`), 0 / 17 rows
# inside the room flagged; with --in-front 96.9% / 100% (96.6% / 94.4%).
NO_BOUNDS_XFAIL: dict = {}
IN_FRONT_XFAIL: dict = {}
INSIDE_XFAIL: dict = {}
COUNT_XFAIL: dict = {}


@pytest.mark.slow
@pytest.mark.parametrize("stem", _cases(POSE_XFAIL))
def test_s2_pose_within_the_tape_measured_mounting(runs, stem):
    cal, ev = runs.full(stem)[:2]
    pose = ev["poses"]["S2"]
    err_m, err_deg = pose["position_error_m"], np.rad2deg(pose["heading_error_rad"])
    s = np.sqrt(np.diag(cal["nodes"]["S2"]["covariance"]))
    print(f"{stem}: S2 {err_m:.3f} m, {err_deg:+.2f} deg from the tape; reported sigma "
          f"({s[0]:.3f} m, {s[1]:.3f} m, {np.rad2deg(s[2]):.2f} deg)")
    assert err_m <= TAPE_M and abs(err_deg) <= TAPE_DEG


@pytest.mark.slow
@pytest.mark.parametrize("stem", list(RECORDINGS))
def test_s2_pose_against_the_tape_within_its_mounting_sigma(runs, stem):
    """Each radar's uncompensated angle bias (no Rx phase compensation in the
    recorder's cfg) is calibrated as heading: the reported covariance, the
    one fusion needs, leaves it out; against the tape the mounting
    covariance (calibration.angle_bias, 3 deg rms per radar) holds it. With
    the tape's 0.1 m and 3 deg every component of S2's error lies within 2
    of those sigmas (multiple tracking: heading -3.76 deg, 0.68 sigma; 1.05
    of the reported sigma with the tape alone)."""
    from mmsnap_graph.calibration import pose_tangent_error
    from mmsnap_graph.calibration.angle_bias import mounting_covariance

    cal = runs.full(stem)[0]["nodes"]["S2"]
    pose, cov = np.asarray(cal["pose"]), np.asarray(cal["covariance"])
    tape = np.array([*SURVEYED_S2[:2], np.deg2rad(SURVEYED_S2[2])])
    err = pose_tangent_error(pose, tape)
    spread = np.diag([TAPE_M**2, TAPE_M**2, np.deg2rad(TAPE_DEG) ** 2])
    z = err / np.sqrt(np.diag(mounting_covariance(pose, cov) + spread))
    z_reported = err / np.sqrt(np.diag(cov + spread))
    print(f"{stem}: S2 off the tape by ({err[0]:+.3f} m, {err[1]:+.3f} m, "
          f"{np.rad2deg(err[2]):+.2f} deg) (body frame) = {np.round(z, 2)} of the mounting "
          f"sigma with the tape's, {np.round(z_reported, 2)} of the reported")
    assert np.all(np.abs(z) <= 2.0)


@pytest.mark.slow
@pytest.mark.parametrize("stem", list(RECORDINGS))
def test_the_real_poses_are_near_their_room_poses(runs, stem):
    """The other side of `mmsnap calibrate`'s nominal-pose warnings: the
    room poses the import stored are the tape's, and the calibrated poses lie
    near them (no warning)."""
    from mmsnap_graph.app.runs import nominal_texts
    from mmsnap_graph.evaluation.nominal import nominal_poses
    from mmsnap_graph.io import read_recording

    cal = runs.full(stem)[0]
    metadata = read_recording(runs.base / f"{stem}.h5", load_cubes=False).metadata
    nominal = nominal_poses(metadata)
    assert {n: p.source for n, p in nominal.items()} == {"S1": "room_pose", "S2": "room_pose"}
    np.testing.assert_allclose(nominal["S2"].pose, [1.7, 1.65, np.pi / 2])
    poses = {n: np.array(e["pose"]) for n, e in cal["nodes"].items()}
    assert nominal_texts(metadata, poses, reference="S1") == []


def reference_frame(pose, covariance):
    """A pose covariance from the body tangent ``(dx_b, dy_b, dphi)`` (the
    calibration JSON's, docs/CONVENTIONS.md) to ``(x, y, phi)`` of the
    reference frame, where the halves' poses are compared."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot @ covariance @ rot.T


def test_reference_frame_rotates_the_body_tangent():
    """S2 faces along -x (phi = 90 deg): its body x is the room's y."""
    cov = np.diag([0.04, 0.0001, 0.01])
    np.testing.assert_allclose(np.diag(reference_frame(np.array([1.7, 1.65, np.pi / 2]), cov)),
                               [0.0001, 0.04, 0.01], atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("stem", RECORDINGS)
def test_synchronised_radars_get_no_clock_lag(runs, stem):
    """Two radars recorded by one PC: no whole-frame lag and no clock offset
    beyond 10 ms, whole and in halves (the fractions the joint graph finds
    on the associated centroids, -1.9 to +0.35 frames, are not supported by
    the data and 0 is kept: docs/CALIBRATION.md, "Clock offsets")."""
    cals = [runs.full(stem)[0]] + runs.half_calibrations(stem)
    got = [(c["nodes"]["S2"]["lag_frames"], c["nodes"]["S2"]["time_offset_s"]) for c in cals]
    print(f"{stem}: S2 lag (frames), clock offset (ms), whole / first half / second half: "
          + ", ".join(f"{lag}, {1e3 * off:+.1f}" for lag, off in got))
    assert all(lag == 0 and abs(off) <= 0.010 for lag, off in got)


@pytest.mark.slow
@pytest.mark.parametrize("stem", _cases(HALVES_XFAIL))
def test_halves_agree_within_their_reported_covariance(runs, stem):
    a, b = (np.asarray(c["nodes"]["S2"]["pose"]) for c in runs.half_calibrations(stem))
    ca, cb = (reference_frame(np.asarray(c["nodes"]["S2"]["pose"]),
                              np.asarray(c["nodes"]["S2"]["covariance"]))
              for c in runs.half_calibrations(stem))
    d = b - a
    d[2] = (d[2] + np.pi) % (2 * np.pi) - np.pi
    z = d / np.sqrt(np.diag(ca + cb))
    print(f"{stem}: halves differ by ({d[0]:+.3f} m, {d[1]:+.3f} m, "
          f"{np.rad2deg(d[2]):+.2f} deg) = ({abs(z[0]):.1f}, {abs(z[1]):.1f}, "
          f"{abs(z[2]):.1f}) sigma of their combined reported covariance")
    assert np.all(np.abs(z) <= 3.0)


@pytest.mark.slow
@pytest.mark.parametrize("stem", RECORDINGS)
def test_every_node_sigma_is_identified(runs, stem):
    """``/noise`` from the centroids the joint graph associated across the
    nodes: two people, clutter and split clusters leave few frames with one
    centroid per node, where the estimators identified 4 (multiple
    tracking, S2's range 1.49 m from mismatched frames) and 5 (fall
    detection) of the 6 sigmas."""
    runs.full(stem)
    est = read_noise(runs.base / f"{stem}.h5")
    for name, node in est.nodes.items():
        print(f"{stem} {name}: range {node.noise.range_m:.3f} m, omega "
              f"{node.noise.omega_rad:.3f} rad, doppler {node.noise.doppler_mps:.3f} m/s, "
              f"identified {node.identified}")
        assert all(node.identified), (name, node.reasons)
        # A walking person's centroid: centimetres to decimetres, not metres.
        assert 0.02 < node.noise.range_m < 0.3 and 0.05 < node.noise.omega_rad < 0.5
        assert 0.05 < node.noise.doppler_mps < 0.6
    # The heavy tails are counted and stored as factors (multiple tracking:
    # 1.10-2.54), also where the associated and own estimates are merged.
    assert max(max(node.tail_factors) for node in est.nodes.values()) > 1.05


@pytest.mark.slow
@pytest.mark.parametrize("stem", RECORDINGS)
def test_noise_gives_calibrates_sigmas_on_the_same_recording(runs, stem):
    """Before: `mmsnap noise` on the calibrated two-person recording
    estimated S2's range sigma at 1.486 m where `mmsnap calibrate` gave
    0.094 m: noise took the frames with one centroid per node, of two
    people, while calibrate associated the centroids across nodes first.
    Both now go through one estimator (calibration.network.noise_at_poses):
    every sigma within 5 % of calibrate's."""
    runs.full(stem)
    rec = runs.base / f"{stem}.h5"
    copy = runs.base / f"{stem}_noise.h5"
    run(["noise", str(rec), "-o", str(copy), "--overwrite"])
    cal, again = read_noise(rec), read_noise(copy)
    for name, node in cal.nodes.items():
        mine = again.nodes[name]
        print(f"{stem} {name}: calibrate {np.round(node.noise.sigmas, 4)}, "
              f"noise {np.round(mine.noise.sigmas, 4)}")
        assert mine.identified == node.identified
        np.testing.assert_allclose(mine.noise.sigmas, node.noise.sigmas, rtol=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("stem", RECORDINGS)
def test_every_node_sigma_is_identified_on_each_half(runs, stem):
    """Half the frames are enough: 6 of 6 sigmas on each half of both
    recordings. In the first half of the two-person recording S2's walls
    (zero Doppler) made its cloud look dense (median frame 6 points, 3
    without them): DBSCAN's 3-point minimum left 148 centroids and both
    Doppler sigmas unidentified (4 of 6); a cloud is now judged sparse by
    the points left after the scene filters (445 centroids)."""
    runs.half_calibrations(stem)
    for h in "ab":
        est = read_noise(runs.base / f"{stem}_{h}.h5")
        for name, node in est.nodes.items():
            print(f"{stem} half {h} {name}: range {node.noise.range_m:.3f} m, omega "
                  f"{node.noise.omega_rad:.3f} rad, doppler {node.noise.doppler_mps:.3f} m/s, "
                  f"identified {node.identified}")
            assert all(node.identified), (h, name, node.reasons)
            assert 0.02 < node.noise.range_m < 0.3 and 0.05 < node.noise.omega_rad < 0.5
            assert 0.05 < node.noise.doppler_mps < 0.6


@pytest.mark.slow
@pytest.mark.parametrize("stem", _cases(NO_BOUNDS_XFAIL))
def test_fused_people_inside_the_room_without_bounds(runs, stem):
    """The scene filters, the learned walls and the body check (no room box
    given); the walls flag few rows inside the room."""
    fused = runs.full(stem)[3]
    frac = inside_fraction(RECORDINGS[stem], fused)
    most = people_ok_fraction(RECORDINGS[stem], fused)
    x0, x1, y0, y1 = RECORDINGS[stem].room
    xy = np.asarray(fused.state)[:, :2]
    inside = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
    walled = np.array(["beyond a wall learned" in m for m in fused.message])
    print(f"{stem}, no --bounds: {100 * frac:.1f}% of {int(np.sum(fused.success))} fused rows "
          f"inside the room; <= {MAX_PEOPLE} people in {100 * most[0]:.1f}% of frames; "
          f"{int(walled.sum())} rows flagged beyond a learned wall, "
          f"{int(np.sum(walled & inside))} of them inside the room")
    assert frac >= 0.95
    assert np.sum(walled & inside) <= 0.02 * np.sum(inside & (fused.success | walled))


@pytest.mark.slow
@pytest.mark.parametrize("stem", _cases(IN_FRONT_XFAIL))
def test_fused_people_inside_the_room_in_front_of_the_radars(runs, stem):
    """No room box, but the radars hang on the walls (``--in-front``)."""
    fused = runs.full(stem)[4]
    frac = inside_fraction(RECORDINGS[stem], fused)
    most = people_ok_fraction(RECORDINGS[stem], fused)
    print(f"{stem}, --in-front: {100 * frac:.1f}% of {int(np.sum(fused.success))} fused rows "
          f"inside the room; <= {MAX_PEOPLE} people in {100 * most[0]:.1f}% of frames")
    assert frac >= 0.95


@pytest.mark.slow
@pytest.mark.parametrize("stem", _cases(INSIDE_XFAIL))
def test_fused_people_inside_the_room(runs, stem):
    """With the room box (``mmsnap fuse --bounds``): the rows outside, and only
    they, are flagged."""
    fused = runs.full(stem)[2]
    frac = inside_fraction(RECORDINGS[stem], fused)
    flagged = int(np.sum(fused.status == Status.OUTSIDE_BOUNDS))
    print(f"{stem}: {100 * frac:.1f}% of {int(np.sum(fused.success))} fused rows inside the "
          f"room; {flagged} flagged outside")
    x0, x1, y0, y1 = RECORDINGS[stem].room
    xy = np.asarray(fused.state)[fused.status == Status.OUTSIDE_BOUNDS, :2]
    assert frac == 1.0 and flagged > 0
    assert np.all((xy[:, 0] < x0) | (xy[:, 0] > x1) | (xy[:, 1] < y0) | (xy[:, 1] > y1))


@pytest.mark.slow
@pytest.mark.parametrize("stem", _cases(COUNT_XFAIL))
def test_at_most_the_known_number_of_people_per_frame(runs, stem):
    fused = runs.full(stem)[2]
    frac, most = people_ok_fraction(RECORDINGS[stem], fused)
    print(f"{stem}: <= {MAX_PEOPLE} fused people in {100 * frac:.1f}% of frames (max {most})")
    assert frac >= 0.98


# The tables and their conversion script (fast).

def _make_tables():
    spec = importlib.util.spec_from_file_location("make_tables", REAL / "make_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_unpickler_refuses_anything_but_arrays_lists_and_dicts():
    mt = _make_tables()
    arrays = [{"IWR1843_Ori": np.zeros((2, 5), np.float16)}]
    out = mt._ArraysOnly(io.BytesIO(pickle.dumps(arrays))).load()
    assert out[0]["IWR1843_Ori"].shape == (2, 5)
    with pytest.raises(pickle.UnpicklingError, match=r"refusing .*system"):
        mt._ArraysOnly(io.BytesIO(pickle.dumps(_Evil()))).load()


class _Evil:
    def __reduce__(self):
        import os
        return os.system, ("echo unpickled",)


def test_destack_recovers_each_frame_of_a_ten_frame_stack():
    mt = _make_tables()
    rng = np.random.default_rng(0)
    raw = [rng.normal(size=(int(rng.integers(0, 4)), 5)).astype(np.float16) for _ in range(30)]
    stacks = [np.concatenate(raw[k - 9:k + 1]) for k in range(9, 30)]
    frames = mt.destack(stacks)
    assert len(frames) == len(raw)
    for got, want in zip(frames, raw):
        np.testing.assert_array_equal(got, want)


def test_tables_hold_float16_values_and_read_as_point_tables():
    from mmsnap_graph.io.ti.point_table import read_point_table
    for real in RECORDINGS.values():
        for node in ("S1", "S2"):
            cloud = read_point_table(REAL / f"{real.stem}_{node}.csv")
            for col in (cloud.x_m, cloud.y_m, cloud.z_m, cloud.doppler_mps):
                shortest = [float(str(v)) for v in col.astype(np.float16)]   # float16's own
                np.testing.assert_array_equal(shortest, col)
            assert cloud.snr_db is not None and np.all(np.isfinite(cloud.snr_db))
            np.testing.assert_allclose(cloud.time_s, 0.05 * cloud.frame, atol=1e-9)
    assert (REAL / "LICENSE").read_text().startswith("MIT License")


# ---------------------------------------------------------------- the simulator's real model
# The same CLI path on the simulator's real model (docs/validation/simulator.md, "Fused
# consistency on the real model"), with the TRUE node poses, so that only the
# measurement model is on trial.
# Measured (docs/validation/simulator.md, "Fused consistency on the real model"): NEES
# 3.80 of 4 at the true poses (seed 1), was 5.44
# (3.07, 2.39) before the range offset was estimated at poses given from
# outside and the Doppler sigma counted its heavy tails on sparse clouds.
# Seeds 0 and 2-5 give 3.53 (below the band: conservative), 3.78, 3.89, 4.16
# and 3.85; the one-node rows (28-33 %) take the cross-range velocity from
# the paper's 3.5 m/s prior, which keeps their NEES near 3.
def test_fused_states_consistent_on_the_simulated_real_model(tmp_path):
    from mmsnap_graph.evaluation.metrics import nees_check, truth_reference
    from mmsnap_graph.io import read_recording

    rec_path = tmp_path / "r.h5"
    run(["simulate", "-c", "B", "-t", "random", "-n", "600", "--seed", "1", "-o", str(rec_path)])
    run(["process", str(rec_path)])
    run(["calibrate", str(rec_path)])
    truth = read_recording(rec_path, load_cubes=False).truth
    true_json = tmp_path / "true.json"
    true_json.write_text(json.dumps({"nodes": {n: {"pose": [float(v) for v in p]}
                                               for n, p in truth.node_poses.items()}}))
    # The range offset at poses given from outside: estimated and stored by `noise`, read by `fuse`.
    run(["noise", str(rec_path), "--calibration", str(true_json), "--overwrite"])
    run(["fuse", str(rec_path), "--no-progress", "--calibration", str(true_json)])
    fused = read_fused(rec_path)
    ok = np.asarray(fused.success, dtype=bool)
    ref, _ = truth_reference(fused.frame[ok], fused.state[ok, :2], truth.frame,
                             truth.target_id, truth.state)
    check = nees_check(fused.state[ok] - ref, np.asarray(fused.covariance)[ok])
    bias = np.nanmean(fused.state[ok, :2] - ref[:, :2], axis=0)
    print(f"real model, true poses: mean NEES {check.mean:.2f} over {check.n} rows, "
          f"95% band {check.interval}; position bias {bias} m")
    assert check.passed, (check.mean, check.interval)
    assert np.all(np.abs(bias) < 0.02), bias       # measured (-0.005, 0.011) m; was (0.047, -0.023)

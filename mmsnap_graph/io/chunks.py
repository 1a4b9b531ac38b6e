"""Long recordings a window of frames at a time, so that fusing an hour of
ten nodes stays under 500 MB.

- :func:`open_detection_windows` reads a recording file's header (format,
  frame period, node order and poses) and, per node, only the ``frame``
  column of one detection level (``centroids`` or ``point_cloud``): a
  :class:`DetectionWindows` index.
- :meth:`DetectionWindows.read` reads the rows of the frames
  ``[start, stop)`` of every node (a slice of each column when the frames
  are sorted, as the writers store them) and returns a
  :class:`~mmsnap_graph.data.recording.Recording` of those detections, with
  each node's map from its rows to the file's rows.
- :meth:`DetectionWindows.reach_m` is how far each node looks: the farthest
  range of its detections at every level the file holds (the coverage
  check's reach, the same as
  :func:`~mmsnap_graph.fusion.recording.coverage.detection_reach_m` of the
  whole recording).
- :func:`fused_writer` writes a ``/fused`` group (layout
  :data:`mmsnap_graph.io.fused.FUSED_LAYOUT`) window by window into a copy of
  the file, which replaces the destination only when complete
  (:func:`mmsnap_graph._atomic.atomic_path`): incremental, yet atomic.

The values of each window are validated as :func:`read_recording` validates
them (finite, ``range_m >= 0``, ``|omega| <= pi``); errors are
:class:`~mmsnap_graph.errors.FileFormatError` naming the file and dataset.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Mapping

import h5py
import numpy as np
from numpy.typing import NDArray

from .._atomic import scratch_folder
from ..data.recording import (MAX_FRAME_PERIOD_S, MIN_FRAME_PERIOD_S, Detections, NodeData,
                              Recording, Tracks)
from ..data.results import FusedSequence
from ..errors import FileFormatError, MmsnapError
from .fused import FUSED_GROUP, write_fused
from .guard import edited_copy, open_for_reading, read_guard, replace_group
from .hdf5 import FORMAT_NAME, FORMAT_VERSION

__all__ = ["DetectionWindows", "open_detection_windows", "FusedWriter", "fused_writer"]

_COLUMNS = ("range_m", "omega_rad", "doppler_mps")
_OPTIONAL = ("snr_db", "target_id")
#: Rows per HDF5 chunk of the datasets :class:`FusedWriter` grows.
WRITE_CHUNK_ROWS = 4096
#: Rows per read of :meth:`DetectionWindows.reach_m` (8 MB of float64).
_REACH_READ_ROWS = 1 << 20


def _text(value) -> str:
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)


def _check_format(f: h5py.File, path: Path) -> None:
    fmt = _text(f.attrs.get("format", ""))
    version = _text(f.attrs.get("format_version", ""))
    if fmt != FORMAT_NAME:
        raise FileFormatError(f"{path}: / attribute 'format' must be {FORMAT_NAME!r}, got {fmt!r}")
    if version.split(".")[0] != FORMAT_VERSION.split(".")[0]:
        raise FileFormatError(f"{path}: / attribute 'format_version' is {version!r}; this "
                              f"reader reads version {FORMAT_VERSION.split('.')[0]}.x")


def _frame_period(f: h5py.File, path: Path) -> float:
    value = np.asarray(f.attrs.get("frame_period_s", np.nan))
    if value.shape != () or value.dtype.kind not in "iuf" or not np.isfinite(value) \
            or not MIN_FRAME_PERIOD_S <= value <= MAX_FRAME_PERIOD_S:
        raise FileFormatError(f"{path}: / attribute 'frame_period_s' must be a number in "
                              f"[{MIN_FRAME_PERIOD_S:g}, {MAX_FRAME_PERIOD_S:g}] s, got "
                              f"{value.tolist()!r}")
    return float(value)


def _members(group: h5py.Group, path: Path) -> dict:
    """``name -> object`` of every member of ``group``; a member that is
    listed but cannot be opened (a damaged file) is a :class:`FileFormatError`."""
    out = {}
    for key in group.keys():
        obj = group.get(key)
        if obj is None:
            raise FileFormatError(f"{path}: {group.name.rstrip('/')}/{key} cannot be read "
                                  "(damaged file?)")
        out[key] = obj
    return out


def _node_order(f: h5py.File, path: Path) -> tuple[str, ...]:
    if not isinstance(_members(f, path).get("nodes"), h5py.Group):
        raise FileFormatError(f"{path}: group /nodes is missing")
    raw = np.asarray(f.attrs.get("node_order", []))
    order = tuple(_text(v) for v in raw.reshape(-1).tolist())
    if raw.ndim != 1 or not order or sorted(order) != sorted(f["nodes"].keys()) \
            or len(set(order)) != len(order):
        raise FileFormatError(f"{path}: / attribute 'node_order' {order} does not list the "
                              f"groups under /nodes {sorted(f['nodes'].keys())} exactly once")
    return order


def _pose(group: h5py.Group, path: Path) -> NDArray | None:
    if "pose" not in group.attrs:
        return None
    pose = np.asarray(group.attrs["pose"])
    if pose.shape != (3,) or pose.dtype.kind not in "iuf" or not np.all(np.isfinite(pose)):
        raise FileFormatError(f"{path}: {group.name} attribute 'pose' must be 3 finite numbers, "
                              f"got {pose!r}")
    return pose.astype(float)


def _frames(level: h5py.Group, path: Path) -> NDArray:
    """The level's ``frame`` column (int64), after checking every column's
    shape and kind (the values are checked per window)."""
    n = None
    for name in ("frame", *_COLUMNS, *[k for k in _OPTIONAL if k in level]):
        ds = level.get(name)
        if not isinstance(ds, h5py.Dataset):
            raise FileFormatError(f"{path}: dataset {level.name}/{name} is missing")
        integer = name in ("frame", "target_id")
        if ds.ndim != 1 or ds.dtype.kind not in ("iu" if integer else "iuf"):
            raise FileFormatError(f"{path}: dataset {ds.name} must be a 1-D column of "
                                  f"{'integers' if integer else 'numbers'}, got shape "
                                  f"{ds.shape} dtype {ds.dtype}")
        if n is not None and ds.shape[0] != n:
            raise FileFormatError(f"{path}: dataset {ds.name} has {ds.shape[0]} rows but "
                                  f"{level.name}/frame has {n}")
        n = ds.shape[0]
    frame = level["frame"][()]
    if frame.dtype.kind == "u" and frame.size and frame.max() > np.iinfo(np.int64).max:
        raise FileFormatError(f"{path}: dataset {level.name}/frame holds frame numbers beyond "
                              "the int64 range")
    return frame.astype(np.int64, copy=False)


_INT64 = np.iinfo(np.int64)


def _clip64(frame: int) -> int:
    """A frame number in the int64 range (windows reach past the frames)."""
    return min(max(int(frame), int(_INT64.min)), int(_INT64.max))


@dataclass(frozen=True, eq=False)
class DetectionWindows:
    """A recording file's detections of one level, readable by frame windows
    (made by :func:`open_detection_windows`).

    path, source : the file and the level (``"centroids"`` or ``"point_cloud"``).
    frame_period_s, node_names, node_poses : from the file (a pose is None
    when the node has none); metadata : the file's ``/metadata`` attributes.
    first_frame, last_frame : the smallest and largest frame with a
    detection (``last_frame < first_frame`` when there is none).
    targets : what the radars see (``Recording.targets``, the file's
    ``targets`` attribute; ``"people"`` when it has none), given to every
    window read.
    """

    path: Path
    source: str
    frame_period_s: float
    node_names: tuple[str, ...]
    node_poses: dict
    first_frame: int
    last_frame: int
    _frames: dict = field(repr=False)   # name -> (K,) int64 frame column, or None
    _order: dict = field(repr=False)    # name -> argsort of the frames, None when sorted
    targets: str = "people"
    _track_frames: dict = field(default_factory=dict, repr=False)  # name -> tracks' frames

    @property
    def n_rows(self) -> dict[str, int]:
        """Rows of the level per node (0 for a node without it)."""
        return {n: 0 if f is None else int(f.size) for n, f in self._frames.items()}

    def windows(self, window_frames: int, margin: int = 0) -> Iterator[tuple[int, int]]:
        """``(start, stop)`` frame ranges of at most ``window_frames`` frames
        covering every detection, in order (none when there is no
        detection), widened by ``margin`` frames on each side (for nodes read
        with shifts). Frames no detection is near are skipped: the number of
        windows is bounded by the frames present, not by their span (a gap
        of 10^12 frames costs nothing)."""
        w = int(window_frames)
        if w < 1 or w != window_frames:
            raise FileFormatError(f"window_frames must be an integer >= 1, got {window_frames!r}")
        present = [fr for fr in self._frames.values() if fr is not None and fr.size]
        if not present:
            return
        frames = np.unique(np.concatenate(present))
        margin = int(margin)
        last = int(frames[-1]) + margin
        start = int(frames[0]) - margin
        while start <= last:
            stop = min(start + w, last + 1)
            yield start, stop
            # the next frame within `margin` of a detection, at or after `stop`
            i = int(np.searchsorted(frames, _clip64(stop - margin)))
            if i >= frames.size:
                return
            start = max(stop, int(frames[i]) - margin)

    def _rows(self, name: str, start: int, stop: int) -> NDArray:
        frames, order = self._frames[name], self._order[name]
        if frames is None:
            return np.zeros(0, np.int64)
        start, stop = _clip64(start), _clip64(stop)
        if order is None:
            lo, hi = np.searchsorted(frames, [start, stop])
            return np.arange(lo, hi, dtype=np.int64)
        lo, hi = np.searchsorted(frames[order], [start, stop])
        return np.sort(order[lo:hi])

    @property
    def has_tracks(self) -> bool:
        """Whether some node has EKF tracks (``mmsnap process``)."""
        return any(f is not None for f in self._track_frames.values())

    def read(self, start: int, stop: int, shifts: Mapping[str, int] | None = None, *,
             tracks: bool = False) -> tuple[Recording, dict[str, NDArray]]:
        """The detections of the frames ``[start, stop)``: a Recording of the
        level only (nodes' poses kept, no truth), and per node the file row of
        each of its window rows. ``shifts``: name -> whole frames that node's
        clock is behind (its frame ``k`` is reference frame ``k + shift``):
        its frames ``[start - shift, stop - shift)`` are read. ``tracks``:
        the nodes' EKF tracks of those frames too (where they have them)."""
        shifts = {} if shifts is None else shifts
        rows = {name: self._rows(name, start - int(shifts.get(name, 0)),
                                 stop - int(shifts.get(name, 0)))
                for name in self.node_names}
        nodes = {}
        with open_for_reading(self.path) as f:
            for name in self.node_names:
                kw = {}
                if self._frames[name] is not None:
                    kw[self.source] = self._detections(f, name, rows[name])
                if tracks and self._track_frames.get(name) is not None:
                    kw["tracks"] = self._tracks(f, name, start - int(shifts.get(name, 0)),
                                                stop - int(shifts.get(name, 0)))
                nodes[name] = NodeData(name=name, pose=self.node_poses[name], **kw)
        return Recording(frame_period_s=self.frame_period_s, nodes=nodes,
                         targets=self.targets), rows

    def _tracks(self, f: h5py.File, name: str, start: int, stop: int) -> Tracks:
        frames = self._track_frames[name]
        rows = np.flatnonzero((frames >= _clip64(start)) & (frames < _clip64(stop)))
        group = f["nodes"][name]["tracks"]
        sl = slice(int(rows[0]), int(rows[-1]) + 1) if rows.size else slice(0, 0)
        pick = rows - sl.start if rows.size else rows
        cols = {k: group[k][sl][pick] for k in ("track_id", "x_m", "y_m", "vx_mps", "vy_mps")}
        cov = group["covariance"][sl][pick]
        state = np.stack([cols[k] for k in ("x_m", "y_m", "vx_mps", "vy_mps")], axis=-1)
        try:
            return Tracks(frame=frames[rows], track_id=cols["track_id"].astype(np.int64),
                          state=state.astype(float), covariance=cov.astype(float))
        except MmsnapError as exc:
            raise FileFormatError(f"{self.path}: {group.name}: {exc}") from exc

    def reach_m(self) -> dict[str, float]:
        """Each node's farthest detection range (m) over its ``point_cloud``
        and ``centroids`` (0 for a node without any), read a slice at a time."""
        out = {}
        with open_for_reading(self.path) as f:
            for name in self.node_names:
                group, far = f["nodes"][name], 0.0
                for level in ("point_cloud", "centroids"):
                    ds = group[level]["range_m"] if level in group and isinstance(
                        group[level], h5py.Group) and "range_m" in group[level] else None
                    for start in range(0, 0 if ds is None else ds.shape[0], _REACH_READ_ROWS):
                        block = ds[start:start + _REACH_READ_ROWS]
                        block = block[np.isfinite(block)]
                        far = max(far, float(block.max(initial=0.0)))
                out[name] = far
        return out

    def _detections(self, f: h5py.File, name: str, rows: NDArray) -> Detections:
        level = f["nodes"][name][self.source]
        contiguous = rows.size == 0 or rows[-1] - rows[0] + 1 == rows.size
        sl = slice(int(rows[0]), int(rows[-1]) + 1) if rows.size else slice(0, 0)
        cols = {"frame": self._frames[name][rows]}
        for key in (*_COLUMNS, *[k for k in _OPTIONAL if k in level]):
            data = level[key][sl] if contiguous else level[key][rows]
            if key != "target_id" and not np.all(np.isfinite(data)):
                i = int(np.flatnonzero(~np.isfinite(data))[0])
                raise FileFormatError(f"{self.path}: dataset {level.name}/{key} must be finite, "
                                      f"got {data[i]!r} at row {int(rows[i])}")
            cols[key] = data.astype(np.int64 if key == "target_id" else float, copy=False)
        try:
            return Detections(**cols)
        except MmsnapError as exc:
            raise FileFormatError(f"{self.path}: {level.name}: {exc}") from exc


def open_detection_windows(path: str | os.PathLike, *, source: str = "centroids"
                           ) -> DetectionWindows:
    """Index the ``source`` detections of the recording at ``path`` by frame
    (reads the header and the ``frame`` columns only; see the module
    docstring). A missing, unreadable or malformed file raises
    :class:`FileFormatError` naming it."""
    path = Path(path)
    if source not in ("centroids", "point_cloud"):
        raise FileFormatError(f"source must be 'centroids' or 'point_cloud', got {source!r}")
    with open_for_reading(path) as f:
        _check_format(f, path)
        period = _frame_period(f, path)
        names = _node_order(f, path)
        targets = _text(f.attrs["targets"]) if "targets" in f.attrs else "people"
        poses, frames, orders, track_frames = {}, {}, {}, {}
        for name in names:
            group = _members(f["nodes"], path)[name]
            if not isinstance(group, h5py.Group):
                raise FileFormatError(f"{path}: {group.name} must be a group")
            poses[name] = _pose(group, path)
            level = _members(group, path).get(source)
            if level is not None and not isinstance(level, h5py.Group):
                raise FileFormatError(f"{path}: {level.name} must be a group")
            frames[name] = None if level is None else _frames(level, path)
            tr = _members(group, path).get("tracks")
            track_frames[name] = (tr["frame"][()].astype(np.int64) if isinstance(tr, h5py.Group)
                                  and isinstance(tr.get("frame"), h5py.Dataset) else None)
    for name, fr in frames.items():
        orders[name] = None if fr is None or np.all(fr[1:] >= fr[:-1]) else \
            np.argsort(fr, kind="stable")
    present = [fr for fr in frames.values() if fr is not None and fr.size]
    first = min((int(fr.min()) for fr in present), default=0)
    last = max((int(fr.max()) for fr in present), default=-1)
    return DetectionWindows(path=path, source=source, frame_period_s=period, node_names=names,
                            node_poses=poses, first_frame=first, last_frame=last,
                            _frames=frames, _order=orders, targets=targets,
                            _track_frames=track_frames)


# ----------------------------------------------------------------------------
# writing /fused window by window
# ----------------------------------------------------------------------------
#: Fill values of the datasets a window may lack (others: 0, False, "").
_FILL = {"track_id": -1}


class FusedWriter:
    """Appends :class:`FusedSequence` windows to a ``/fused`` group being
    written (use :func:`fused_writer`).

    Each window is written by :func:`mmsnap_graph.io.fused.write_fused` into
    a small scratch file holding only the recording's clock, so the layout
    and attributes are exactly :data:`~mmsnap_graph.io.fused.FUSED_LAYOUT`'s;
    its datasets (all with one row per fused target) are then appended to
    the group's growing datasets. A dataset present in some windows only
    (``rejected``) reads as its fill value (False) in the others.
    """

    def __init__(self, group: h5py.Group, scratch: Path, recording: Path) -> None:
        self._group = group
        self._template = scratch / "clock.h5"
        self._window = scratch / "window.h5"
        self.n_rows = 0
        self.n_success = 0
        self._started = False
        with read_guard(recording), h5py.File(recording, "r") as f, \
                h5py.File(self._template, "w") as t:
            # The recording's clock (write_fused takes time_s from it).
            if "frame_period_s" in f.attrs:
                t.attrs["frame_period_s"] = f.attrs["frame_period_s"]
            meta = f.get("metadata")
            if isinstance(meta, h5py.Group) and "time_origin_s" in meta.attrs:
                t.create_group("metadata").attrs["time_origin_s"] = meta.attrs["time_origin_s"]

    def append(self, fused: FusedSequence) -> None:
        """Append the rows of ``fused`` (the first call also writes the attributes)."""
        write_fused(self._template, fused, output=self._window)
        g, lo, k = self._group, self.n_rows, len(fused)
        with h5py.File(self._window, "r") as w:
            src = w[FUSED_GROUP]
            if not self._started:
                for key, value in src.attrs.items():
                    g.attrs[key] = value
                self._started = True
            for name, ds in src.items():
                if name not in g:
                    tail = ds.shape[1:]
                    g.create_dataset(name, shape=(lo, *tail), maxshape=(None, *tail),
                                     dtype=ds.dtype, chunks=(WRITE_CHUNK_ROWS, *tail),
                                     compression="gzip", compression_opts=1,
                                     fillvalue=_FILL.get(name))
                out = g[name]
                out.resize(lo + k, axis=0)
                if k:
                    out[lo:lo + k] = ds[()]
            for name, out in g.items():
                if name not in src:
                    out.resize(lo + k, axis=0)  # the fill value (False, 0, "")
        self.n_rows += k
        self.n_success += int(np.count_nonzero(fused.success))

    def set_attribute(self, name: str, value) -> None:
        """An attribute of the ``/fused`` group (after the rows: a summary of them)."""
        self._group.attrs[name] = value


@contextlib.contextmanager
def fused_writer(path: str | os.PathLike, *, output: str | os.PathLike | None = None
                 ) -> Iterator[FusedWriter]:
    """A :class:`FusedWriter` of the ``/fused`` group of the recording at
    ``path`` (replacing an existing one), or of a copy of it at ``output``.

    The file is copied to a temporary file beside the destination, the
    group written there window by window, and the copy moved over the
    destination when the block ends without an error; on an error (or a
    kill) the destination is left as it was. The recording's lock is held
    throughout (:func:`mmsnap_graph._atomic.recording_lock`).
    """
    with edited_copy(path, output) as f, \
            scratch_folder(path if output is None else output) as scratch:  # not $TMPDIR
        yield FusedWriter(replace_group(f, FUSED_GROUP, path), Path(scratch), Path(path))

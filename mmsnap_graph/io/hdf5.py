"""The HDF5 recording format (docs/FORMAT.md is the contract; keep both in step).

Layout (``FORMAT_NAME`` = ``"mmsnap_graph.recording"``, version 1)::

    /                      attrs: format, format_version, frame_period_s,
                                  node_order (str array), targets ("people" (default) or "points")
    /metadata              attrs: free-form str / int / float values
    /nodes/<name>          attrs: pose = [x_m, y_m, phi_rad]  (optional)
        radar              attrs: the RadarConfig fields      (optional)
        centroids/         frame, range_m, omega_rad, doppler_mps [, snr_db, target_id]
        point_cloud/       same fields
        tracks/            frame, track_id, x_m, y_m, vx_mps, vy_mps, covariance (K,4,4)
        cube/              attrs: RadarConfig fields; datasets adc (F,S,L,V) complex64, frame (F,)
    /truth                 frame, target_id, x_m, y_m, vx_mps, vy_mps
        node_poses         attrs: <name> = [x_m, y_m, phi_rad]
    /<anything else>       extension groups (e.g. /calibration, /fused): kept
                           intact by update_recording

Writers are atomic (a temporary file in the same folder, then ``os.replace``).
Readers validate every field and raise :class:`FileFormatError` naming the
HDF5 path of the missing or malformed dataset or attribute.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Iterator

import h5py
import numpy as np
from numpy.typing import NDArray

from .._validation import check_count
from .._atomic import atomic_path, recording_lock
from .guard import H5_ERRORS, existing_file, read_guard
from ..errors import ConfigurationError, FileFormatError, MmsnapError
from ..data.radar_config import OPTIONAL_FIELD_DEFAULTS, RadarConfig
from ..data.recording import Detections, NodeData, Recording, Tracks, Truth

__all__ = [
    "FORMAT_NAME", "FORMAT_VERSION",
    "write_recording",
    "update_recording",
    "read_recording",
    "iter_cubes",
    "read_cube_frames", "open_recording_file", "recording_metadata",
    "read_guard", "H5_ERRORS",
]

FORMAT_NAME = "mmsnap_graph.recording"
#: ``major.minor``; readers accept any minor version of their major version.
FORMAT_VERSION = "1.0"
_MAJOR = 1

_DETECTION_REQUIRED = ("frame", "range_m", "omega_rad", "doppler_mps")
_DETECTION_OPTIONAL = ("snr_db", "target_id")
_TRACK_FIELDS = ("frame", "track_id", "x_m", "y_m", "vx_mps", "vy_mps", "covariance")
_TRUTH_FIELDS = ("frame", "target_id", "x_m", "y_m", "vx_mps", "vy_mps")
_INT_FIELDS = {"frame", "target_id", "track_id"}
_NODE_KNOWN = {"centroids", "point_cloud", "tracks", "cube", "radar"}
_ROOT_KNOWN = {"nodes", "truth", "metadata"}
_ROOT_ATTRS = {"format", "format_version", "frame_period_s", "node_order", "targets"}
#: Datasets at least this many elements long are chunked and compressed.
_COMPRESS_MIN = 1024
_STR = h5py.string_dtype(encoding="utf-8")


# --------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------
def _column(group: h5py.Group, name: str, data: NDArray, dtype) -> None:
    arr = np.ascontiguousarray(data, dtype=dtype)
    kw: dict[str, Any] = {}
    if arr.size >= _COMPRESS_MIN:
        kw = dict(chunks=True, compression="gzip", compression_opts=4, shuffle=True)
    group.create_dataset(name, data=arr, **kw)


def _write_detections(group: h5py.Group, det: Detections) -> None:
    _column(group, "frame", det.frame, np.int64)
    for name in ("range_m", "omega_rad", "doppler_mps"):
        _column(group, name, getattr(det, name), np.float64)
    if det.snr_db is not None:
        _column(group, "snr_db", det.snr_db, np.float64)
    if det.target_id is not None:
        _column(group, "target_id", det.target_id, np.int64)


def _write_tracks(group: h5py.Group, tracks: Tracks) -> None:
    _column(group, "frame", tracks.frame, np.int64)
    _column(group, "track_id", tracks.track_id, np.int64)
    for i, name in enumerate(("x_m", "y_m", "vx_mps", "vy_mps")):
        _column(group, name, tracks.state[:, i], np.float64)
    _column(group, "covariance", tracks.covariance, np.float64)


def _radar_attrs(obj: h5py.HLObject, radar: RadarConfig) -> None:
    for key, value in radar.to_dict().items():
        obj.attrs[key] = np.asarray(value, dtype=float) if isinstance(value, list) else value


def _write_cube(group: h5py.Group, node: NodeData, compression: str | None,
                compression_opts: int | None, cube_storage: str, progress=None) -> None:
    _radar_attrs(group, node.radar)
    cube = node.cube
    n_f = cube.shape[0]
    if cube_storage == "int16":
        # ADC counts as a capture holds them: (F, S, L, V, 2) int16 I/Q.
        shape = (*cube.shape, 2)
        dtype = np.int16
        chunks = (1, *shape[1:])
    else:
        shape, dtype, chunks = cube.shape, np.complex64, (1, *cube.shape[1:])
    kw: dict[str, Any] = {"chunks": chunks} if n_f else {}
    if compression and n_f:
        kw.update(compression=compression, shuffle=True)
        if compression_opts is not None:
            kw.update(compression_opts=compression_opts)
    ds = group.create_dataset("adc", shape=shape, dtype=dtype, **kw)
    lim = np.iinfo(np.int16)
    for f in range(n_f):  # frame by frame: cubes may be memory maps larger than RAM
        block = np.asarray(cube[f], dtype=np.complex64)
        if cube_storage == "int16":
            iq = block.view(np.float32).reshape(*block.shape, 2)
            if (not np.all(iq == np.round(iq)) or iq.min() < lim.min or iq.max() > lim.max):
                raise FileFormatError(
                    f"nodes[{node.name}].cube frame {f} is not whole int16 ADC counts; "
                    "use cube_storage='complex64'")
            ds[f] = iq.astype(np.int16)
        else:
            ds[f] = block
        if progress is not None:
            progress(1)
    group.create_dataset("frame", data=np.asarray(node.cube_frame, dtype=np.int64))


def _write_into(f: h5py.File, rec: Recording, compression: str | None,
                compression_opts: int | None, cube_storage: str = "complex64", progress=None):
    f.attrs["format"] = FORMAT_NAME
    f.attrs["format_version"] = FORMAT_VERSION
    f.attrs["frame_period_s"] = float(rec.frame_period_s)
    f.attrs.create("node_order", np.array(rec.node_names, dtype=object), dtype=_STR)
    f.attrs["targets"] = rec.targets
    meta = f.create_group("metadata")
    for key, value in rec.metadata.items():
        if isinstance(value, (bool, np.bool_)):
            meta.attrs[str(key)] = bool(value)
        elif isinstance(value, (str, int, float, np.integer, np.floating)):
            meta.attrs[str(key)] = value
        else:
            try:
                arr = np.asarray(value)
            except Exception as exc:  # pragma: no cover - defensive
                raise FileFormatError(f"metadata[{key!r}]={value!r} cannot be stored") from exc
            if arr.dtype.kind not in "biuf":
                raise FileFormatError(f"metadata[{key!r}]={value!r} must be a str, int, float "
                                      "or a numeric array")
            meta.attrs[str(key)] = arr
    nodes = f.create_group("nodes")
    for name, node in rec.nodes.items():
        g = nodes.create_group(name)
        if node.pose is not None:
            g.attrs["pose"] = np.asarray(node.pose, dtype=float)
        if node.radar is not None and node.cube is None:
            _radar_attrs(g.create_group("radar"), node.radar)
        if node.centroids is not None:
            _write_detections(g.create_group("centroids"), node.centroids)
        if node.point_cloud is not None:
            _write_detections(g.create_group("point_cloud"), node.point_cloud)
        if node.tracks is not None:
            _write_tracks(g.create_group("tracks"), node.tracks)
        if node.cube is not None:
            _write_cube(g.create_group("cube"), node, compression, compression_opts,
                        cube_storage, progress)
    if rec.truth is not None:
        t = f.create_group("truth")
        _column(t, "frame", rec.truth.frame, np.int64)
        _column(t, "target_id", rec.truth.target_id, np.int64)
        for i, name in enumerate(("x_m", "y_m", "vx_mps", "vy_mps")):
            _column(t, name, rec.truth.state[:, i], np.float64)
        poses = t.create_group("node_poses")
        for name, pose in rec.truth.node_poses.items():
            poses.attrs[name] = np.asarray(pose, dtype=float)


def _atomic_write(path: Path, fill) -> None:
    with recording_lock(path), atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            fill(f)


def _check_storage(cube_storage: str) -> None:
    if cube_storage not in ("complex64", "int16"):
        raise FileFormatError(f"cube_storage={cube_storage!r} must be 'complex64' or 'int16'")


def write_recording(path: str | os.PathLike, recording: Recording, *, overwrite: bool = False,
                    compression: str | None = "gzip", compression_opts: int | None = 1,
                    cube_storage: str = "complex64", progress=None) -> Path:
    """Write ``recording`` to a new HDF5 file, atomically.

    ``overwrite=False`` refuses an existing ``path`` (:class:`FileFormatError`); with
    ``overwrite=True`` the old file is replaced (extensions lost: see :func:`update_recording`).
    ``compression``/``compression_opts`` apply to raw ADC cubes (chunked one
    frame per chunk); other datasets of 1024 elements or more are always
    chunked and gzip-compressed. ``cube_storage="int16"`` stores cubes as
    int16 I/Q ADC counts (half the size, compresses well; the cube must hold
    whole counts in the int16 range), else complex64. Returns the path; ``progress(1)``
    (e.g. a tqdm bar's ``update``) is called after each cube frame written.
    """
    _check_storage(cube_storage)
    path = Path(path)
    if not isinstance(recording, Recording):
        raise FileFormatError(f"recording must be a Recording, got {type(recording).__name__}")
    if path.exists() and not overwrite:
        raise FileFormatError(f"{path} exists; pass overwrite=True to replace it")
    _atomic_write(path, lambda f: _write_into(f, recording, compression, compression_opts,
                                              cube_storage, progress))
    return path


def _copy_extensions(old: h5py.File, f: h5py.File, recording: Recording,
                     keep_cubes: bool) -> None:
    """Copy into the new file ``f`` what ``recording`` does not hold (see
    :func:`update_recording`)."""
    for key in old.keys():
        if key not in _ROOT_KNOWN:
            old.copy(old[key], f, name=key)
    for key, value in old.attrs.items():
        if key not in _ROOT_ATTRS:
            f.attrs[key] = value
    if "nodes" not in old:
        return
    for name, node in recording.nodes.items():
        if name not in old["nodes"]:
            continue
        og = old["nodes"][name]
        ng = f["nodes"][name]
        for key in og.keys():
            if key in _NODE_KNOWN:
                continue
            old.copy(og[key], ng, name=key)
        if keep_cubes and node.cube is None and "cube" in og and "cube" not in ng:
            if "radar" in ng:
                del ng["radar"]
            old.copy(og["cube"], ng, name="cube")
        for key, value in og.attrs.items():
            if key != "pose":
                ng.attrs[key] = value


def update_recording(path: str | os.PathLike, recording: Recording, *,
                     keep_cubes: bool = True, compression: str | None = "gzip",
                     compression_opts: int | None = 1, cube_storage: str = "complex64",
                     output: str | os.PathLike | None = None,
                     edit: Callable[[h5py.File], None] | None = None) -> Path:
    """Rewrite the file at ``path`` with ``recording``, atomically, keeping
    what the in-memory recording does not hold.

    Kept from the old file: every extension group or dataset at the root
    (anything but ``nodes``, ``truth``, ``metadata``, e.g. ``/calibration``
    and ``/fused``), unknown root attributes, unknown members of each node's
    group, and -- with ``keep_cubes`` -- a node's raw ADC cube when the
    recording was read with ``load_cubes=False`` (its ``cube`` is None).
    The old file is validated first (:class:`FileFormatError`).

    ``output`` writes the result there instead (``path`` is left as it was);
    ``edit(f)`` may change the new file (open for writing) before it lands.
    One temporary file beside the destination is the only extra copy on
    disk. The file's lock (:func:`mmsnap_graph._atomic.recording_lock`) is
    held throughout. Returns the path written.
    """
    _check_storage(cube_storage)
    path = Path(path)
    dst = path if output is None else Path(output)
    with recording_lock(path):
        if not path.exists():
            raise FileFormatError(f"{path} does not exist; use write_recording for a new file")
        with read_guard(path):
            open_recording_file(path).close()

        def fill(f: h5py.File) -> None:
            _write_into(f, recording, compression, compression_opts, cube_storage)
            try:
                with h5py.File(path, "r") as old:
                    _copy_extensions(old, f, recording, keep_cubes)
            except H5_ERRORS as exc:
                if isinstance(exc, MmsnapError):
                    raise
                raise FileFormatError(f"{path}: its extension groups cannot be copied "
                                      f"(damaged file?): {exc}") from exc
            if edit is not None:
                edit(f)

        _atomic_write(dst, fill)
    return dst


# --------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------
def open_recording_file(path: Path) -> h5py.File:
    """The HDF5 file at ``path``, open for reading, when it is an mmsnap
    recording (its format and major version); else FileFormatError."""
    path = existing_file(path)
    try:
        f = h5py.File(path, "r")
    except H5_ERRORS as exc:
        raise FileFormatError(f"{path} is not a readable HDF5 file (truncated or corrupt): {exc}"
                              ) from exc
    try:
        fmt = _attr_str(f, "format")
        if fmt != FORMAT_NAME:
            raise FileFormatError(f"/ attribute 'format' must be {FORMAT_NAME!r}, got {fmt!r}")
        version = _attr_str(f, "format_version")
        try:
            major = int(version.split(".")[0])
        except ValueError:
            raise FileFormatError(f"/ attribute 'format_version' must look like '1.0', "
                                  f"got {version!r}") from None
        if major != _MAJOR:
            raise FileFormatError(f"/ attribute 'format_version' is {version!r}; this reader "
                                  f"reads version {_MAJOR}.x")
    except BaseException:
        f.close()
        raise
    return f


def _attr(obj: h5py.HLObject, key: str) -> Any:
    try:
        if key not in obj.attrs:
            raise FileFormatError(f"{obj.name} is missing attribute {key!r}")
        return obj.attrs[key]
    except H5_ERRORS as exc:
        if isinstance(exc, MmsnapError):
            raise
        raise FileFormatError(f"{obj.name} attribute {key!r} cannot be read: {exc}") from exc


def _attr_str(obj: h5py.HLObject, key: str) -> str:
    value = _attr(obj, key)
    if isinstance(value, bytes):
        value = value.decode("utf-8")
    if not isinstance(value, str):
        raise FileFormatError(f"{obj.name} attribute {key!r} must be a string, got {value!r}")
    return value


def _attr_float(obj: h5py.HLObject, key: str) -> float:
    value = np.asarray(_attr(obj, key))
    if value.shape != () or value.dtype.kind not in "iuf" or not np.isfinite(value):
        raise FileFormatError(f"{obj.name} attribute {key!r} must be a finite number, "
                              f"got {value!r}")
    return float(value)


def _attr_vector(obj: h5py.HLObject, key: str, n: int) -> NDArray:
    value = np.asarray(_attr(obj, key))
    if value.shape != (n,) or value.dtype.kind not in "iuf" or not np.all(np.isfinite(value)):
        raise FileFormatError(f"{obj.name} attribute {key!r} must be {n} finite numbers, "
                              f"got {value!r}")
    return value.astype(float)


def _member(parent: h5py.Group, key: str, what: str):
    """``parent[key]``, or :class:`FileFormatError` naming it (missing or damaged)."""
    where = f"{parent.name.rstrip('/')}/{key}"
    try:
        if key not in parent:
            raise FileFormatError(f"{what}{where} is missing")
        return parent.get(key)
    except H5_ERRORS as exc:
        if isinstance(exc, MmsnapError):
            raise
        raise FileFormatError(f"{what}{where} cannot be read (damaged file?): {exc}") from exc


def _group(parent: h5py.Group, key: str) -> h5py.Group:
    obj = _member(parent, key, "")
    if not isinstance(obj, h5py.Group):
        raise FileFormatError(f"{obj.name} must be a group, got a {type(obj).__name__}")
    return obj


def _dataset(group: h5py.Group, key: str, *, ndim: int = 1, kind: str = "float") -> h5py.Dataset:
    where = f"{group.name.rstrip('/')}/{key}"
    ds = _member(group, key, "dataset ")
    if not isinstance(ds, h5py.Dataset):
        raise FileFormatError(f"{where} must be a dataset, got a {type(ds).__name__}")
    if ds.ndim != ndim:
        raise FileFormatError(f"dataset {where} must be {ndim}-D, got shape {ds.shape}")
    allowed = {"int": "iu", "float": "iuf", "complex": "c"}[kind]
    if ds.dtype.kind not in allowed:
        raise FileFormatError(f"dataset {where} must hold {kind} values, got dtype {ds.dtype}")
    return ds


def _load(ds: h5py.Dataset) -> NDArray:
    try:
        return ds[()]
    except H5_ERRORS as exc:
        raise FileFormatError(f"dataset {ds.name} cannot be read (damaged file?): {exc}") from exc


def _int64(arr: NDArray, where: str) -> NDArray:
    """Integers as int64; unsigned values beyond int64 (which would wrap) are
    a :class:`FileFormatError`."""
    if arr.dtype.kind == "u" and arr.size and arr.max() > np.iinfo(np.int64).max:
        bad = int(np.flatnonzero(arr > np.iinfo(np.int64).max)[0])
        raise FileFormatError(f"dataset {where} holds {arr[bad]} at row {bad}, beyond the "
                              f"int64 range of frame numbers and ids")
    return arr.astype(np.int64, copy=False)


def _columns(group: h5py.Group, required, optional=()) -> dict[str, NDArray]:
    out: dict[str, NDArray] = {}
    names = list(required) + [k for k in optional if k in group]
    n = None
    for name in names:
        kind = "int" if name in _INT_FIELDS else "float"
        ds = _dataset(group, name, kind=kind)
        if n is None:
            n = ds.shape[0]
        elif ds.shape[0] != n:
            raise FileFormatError(
                f"dataset {ds.name} has {ds.shape[0]} rows but {group.name}/{names[0]} has {n}")
        arr = _load(ds)
        if kind == "int":
            arr = _int64(arr, ds.name)
        if kind == "float" and not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise FileFormatError(f"dataset {ds.name} must be finite, got {arr[bad]!r} at row {bad}")
        out[name] = arr
    return out


def _detections(group: h5py.Group) -> Detections:
    cols = _columns(group, _DETECTION_REQUIRED, _DETECTION_OPTIONAL)
    try:
        return Detections(**cols)
    except MmsnapError as exc:
        raise FileFormatError(f"{group.name}: {exc}") from exc


def _tracks(group: h5py.Group) -> Tracks:
    cols = _columns(group, _TRACK_FIELDS[:-1])
    n = cols["frame"].shape[0]
    cov_ds = _dataset(group, "covariance", ndim=3)
    if cov_ds.shape != (n, 4, 4):
        raise FileFormatError(f"dataset {cov_ds.name} must have shape ({n}, 4, 4), "
                              f"got {cov_ds.shape}")
    cov = _load(cov_ds)
    if not np.all(np.isfinite(cov)):
        raise FileFormatError(f"dataset {cov_ds.name} must be finite")
    state = np.stack([cols[k] for k in ("x_m", "y_m", "vx_mps", "vy_mps")], axis=-1)
    try:
        return Tracks(frame=cols["frame"], track_id=cols["track_id"], state=state, covariance=cov)
    except MmsnapError as exc:
        raise FileFormatError(f"{group.name}: {exc}") from exc


def _radar(obj: h5py.HLObject) -> RadarConfig:
    fields = RadarConfig().to_dict()
    kw: dict[str, Any] = {}
    for key, default in fields.items():
        if isinstance(default, list):
            value = np.asarray(_attr(obj, key))
            if value.ndim != 1 or value.dtype.kind not in "iuf":
                raise FileFormatError(f"{obj.name} attribute {key!r} must be a 1-D numeric "
                                      f"array, got {value!r}")
            kw[key] = tuple(float(v) for v in value)
        elif isinstance(default, int):
            value = _attr_float(obj, key)
            if value != int(value):
                raise FileFormatError(f"{obj.name} attribute {key!r} must be an integer, "
                                      f"got {value!r}")
            kw[key] = int(value)
        else:
            kw[key] = _attr_float(obj, key)
    for key, default in OPTIONAL_FIELD_DEFAULTS.items():  # TI fields, written when set
        if key in obj.attrs:
            value = _attr(obj, key)
            kw[key] = (tuple(np.atleast_1d(value).tolist()) if isinstance(default, list)
                       else value.decode() if isinstance(value, bytes) else type(default)(value))
    try:
        return RadarConfig(**kw)
    except ConfigurationError as exc:
        raise FileFormatError(f"{obj.name}: inconsistent radar configuration: {exc}") from exc


def _cube_meta(group: h5py.Group) -> tuple[RadarConfig, h5py.Dataset, NDArray]:
    radar = _radar(group)
    if "adc" in group and isinstance(group["adc"], h5py.Dataset) and group["adc"].ndim == 5:
        adc = _dataset(group, "adc", ndim=5, kind="int")
        if adc.dtype != np.int16 or adc.shape[1:] != (*radar.cube_shape, 2):
            raise FileFormatError(
                f"dataset {adc.name} stored as ADC counts must be int16 of shape "
                f"(F, {', '.join(map(str, radar.cube_shape))}, 2), got {adc.dtype} {adc.shape}")
    else:
        adc = _dataset(group, "adc", ndim=4, kind="complex")
        if adc.shape[1:] != radar.cube_shape:
            raise FileFormatError(
                f"dataset {adc.name} has shape {adc.shape}, but its radar configuration "
                f"needs (F, {', '.join(map(str, radar.cube_shape))})")
    frame_ds = _dataset(group, "frame", kind="int")
    if frame_ds.shape != (adc.shape[0],):
        raise FileFormatError(f"dataset {frame_ds.name} has {frame_ds.shape[0]} rows but "
                              f"{adc.name} has {adc.shape[0]} frames")
    return radar, adc, _load(frame_ds).astype(np.int64)


def _cube_block(adc: h5py.Dataset, sl: slice) -> NDArray:
    """Frames ``sl`` of a cube dataset as complex64 (either storage)."""
    try:
        block = adc[sl]
    except OSError as exc:
        raise FileFormatError(f"dataset {adc.name} frames {sl.start}:{sl.stop} cannot be read "
                              f"(truncated file?): {exc}") from exc
    if adc.ndim == 5:
        out = np.empty(block.shape[:-1], dtype=np.complex64)
        out.real = block[..., 0]
        out.imag = block[..., 1]
        return out
    return block.astype(np.complex64, copy=False)


def _node(group: h5py.Group, name: str, load_cubes: bool) -> NodeData:
    kw: dict[str, Any] = {"name": name}
    if "pose" in group.attrs:
        kw["pose"] = _attr_vector(group, "pose", 3)
    if "radar" in group:
        kw["radar"] = _radar(_group(group, "radar"))
    for level in ("centroids", "point_cloud"):
        if level in group:
            kw[level] = _detections(_group(group, level))
    if "tracks" in group:
        kw["tracks"] = _tracks(_group(group, "tracks"))
    if "cube" in group:
        radar, adc, frames = _cube_meta(_group(group, "cube"))
        if "radar" in kw and kw["radar"] != radar:
            raise FileFormatError(f"{group.name}/radar and {group.name}/cube disagree on the "
                                  "radar configuration")
        kw["radar"] = radar
        if load_cubes:
            kw["cube"] = _cube_block(adc, slice(0, adc.shape[0]))
            kw["cube_frame"] = frames
    try:
        return NodeData(**kw)
    except MmsnapError as exc:
        raise FileFormatError(f"{group.name}: {exc}") from exc


def _truth(group: h5py.Group) -> Truth:
    cols = _columns(group, _TRUTH_FIELDS)
    poses = {}
    if "node_poses" in group:
        pg = _group(group, "node_poses")
        for key in pg.attrs:
            poses[key] = _attr_vector(pg, key, 3)
    state = np.stack([cols[k] for k in ("x_m", "y_m", "vx_mps", "vy_mps")], axis=-1)
    try:
        return Truth(frame=cols["frame"], target_id=cols["target_id"], state=state,
                     node_poses=poses)
    except MmsnapError as exc:
        raise FileFormatError(f"{group.name}: {exc}") from exc


def _node_order(f: h5py.File) -> list[str]:
    nodes = _group(f, "nodes")
    raw = np.asarray(_attr(f, "node_order"))
    if raw.ndim != 1 or raw.size == 0:
        raise FileFormatError(f"/ attribute 'node_order' must be a non-empty 1-D list of node "
                              f"names, got {raw!r}")
    order = [v.decode("utf-8") if isinstance(v, bytes) else v for v in raw.tolist()]
    if not all(isinstance(v, str) for v in order):
        raise FileFormatError(f"/ attribute 'node_order' must hold strings, got {order!r}")
    if sorted(order) != sorted(nodes.keys()) or len(set(order)) != len(order):
        raise FileFormatError(f"/ attribute 'node_order' {order} does not list the groups "
                              f"under /nodes {sorted(nodes.keys())} exactly once")
    return order


def _has(group: h5py.Group, key: str) -> bool:
    try:
        return key in group
    except H5_ERRORS as exc:
        raise FileFormatError(f"{group.name.rstrip('/')}/{key} cannot be read (damaged "
                              f"file?): {exc}") from exc


def recording_metadata(f: h5py.File) -> dict[str, Any]:
    """The ``/metadata`` attributes of an open recording (:func:`open_recording_file`)."""
    return {key: value.decode("utf-8") if isinstance(value, bytes)
            else value.item() if isinstance(value, np.generic) else value
            for key, value in _group(f, "metadata").attrs.items()}


def read_recording(path: str | os.PathLike, *, load_cubes: bool = True) -> Recording:
    """Read and validate a recording.

    ``load_cubes=False`` skips the raw ADC data (``NodeData.cube`` is None, the
    node's ``radar`` is still set; use :func:`iter_cubes`). Raises
    :class:`FileFormatError` naming the missing or malformed dataset or
    attribute, or when the file is not a readable HDF5 file.
    """
    path = Path(path)
    with read_guard(path), open_recording_file(path) as f:
        frame_period_s = _attr_float(f, "frame_period_s")
        order = _node_order(f)
        nodes_group = _group(f, "nodes")
        nodes = {name: _node(_group(nodes_group, name), name, load_cubes) for name in order}
        truth = _truth(_group(f, "truth")) if _has(f, "truth") else None
        metadata = recording_metadata(f) if _has(f, "metadata") else {}
        targets = _attr_str(f, "targets") if "targets" in f.attrs else "people"
    try:
        return Recording(frame_period_s=frame_period_s, nodes=nodes, truth=truth,
                         metadata=metadata, targets=targets)
    except MmsnapError as exc:
        raise FileFormatError(f"{path}: {exc}") from exc


def iter_cubes(path: str | os.PathLike, node_name: str, *, chunk_frames: int = 16
               ) -> Iterator[tuple[NDArray, NDArray]]:
    """Yield ``(frame (n,), cube (n, n_samples, n_loops, n_virtual) complex64)``
    chunks of a node's raw ADC cube, ``n <= chunk_frames``, without loading
    the whole cube."""
    check_count(chunk_frames, "chunk_frames", error=FileFormatError)
    with read_guard(path), open_recording_file(Path(path)) as f:
        nodes = _group(f, "nodes")
        if node_name not in nodes:
            raise FileFormatError(f"/nodes/{node_name} is missing (nodes: {sorted(nodes.keys())})")
        group = _group(nodes, node_name)
        _, adc, frames = _cube_meta(_group(group, "cube"))
        for start in range(0, adc.shape[0], chunk_frames):
            stop = min(start + chunk_frames, adc.shape[0])
            yield frames[start:stop], _cube_block(adc, slice(start, stop))


def read_cube_frames(path: str | os.PathLike, node_name: str) -> tuple[RadarConfig, NDArray, int]:
    """``(radar, frame (F,), F)`` of a node's cube without loading the ADC data."""
    with read_guard(path), open_recording_file(Path(path)) as f:
        group = _group(_group(f, "nodes"), node_name)
        radar, adc, frames = _cube_meta(_group(group, "cube"))
        return radar, frames, int(adc.shape[0])

"""The ``--config FILE`` TOML file of ``mmsnap process`` and ``mmsnap
calibrate``: every option of the signal chain, the clustering, the local EKF
and the calibration's track matching in one place.

Layout (every key optional; an absent key keeps its default; ``--show-config``
prints the effective file with every default)::

    [chain]            # radar.chain.ChainConfig (windows, ranges, de-aliasing, ...)
    min_range_m = 0.9
    [chain.cfar]       # radar.cfar.CfarConfig
    pfa = 1e-6
    [chain.cluster]    # radar.cluster.ClusterConfig, and:
    point_targets = true
    sparse = "auto"    # stored point clouds: min_samples=1 (true), never (false)
    [ekf]              # tracking.ekf.EkfConfig (thresholds in seconds)
    sigma_a_mps2 = 3.0
    [scene]            # radar.scene.SceneConfig: filters of stored point clouds
    min_occupancy = 0.2
    [matching]         # mmsnap calibrate: track matching, seconds and metres
    min_common_s = 0.5

    [fuse]             # mmsnap fuse, batch, replay: their fusion flags' keys
    robust = "gate"
    bounds = [-2.0, 1.6, 0.0, 3.6]
    learned_walls = false

One file may hold every table: ``mmsnap process`` reads ``[chain]``,
``[chain.*]``, ``[ekf]`` and ``[scene]``; ``mmsnap calibrate`` reads
``[matching]``; ``mmsnap fuse``, ``mmsnap batch`` and ``mmsnap replay`` read
``[fuse]`` (:data:`FUSE_KEYS`: each flag's name, ``--no-X`` as ``X = false``;
a flag given wins). Each ignores the others' tables. Any other table is an
error.

TOML has no null: a key whose default is "unset" (e.g. ``max_range_m``, the
radar's unambiguous range) is set by giving a value and unset by leaving it
out. ``[ekf] measurement_std`` is unset by default: the EKF's measurement
sigmas are estimated from each node's own centroids
(:func:`mmsnap_graph.app.pipeline.ekf_noise_from_centroids`); giving it fixes them. ``[ekf] frame_period_s`` is always the recording's frame period (a value
in the file is an error: the file describes processing, the recording its
timing).
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..calibration.pairwise.matching_options import MatchingOptions
from ..errors import ConfigurationError, ValidationError
from ..radar.cfar import CfarConfig
from ..radar.chain import ChainConfig
from ..radar.cluster import ClusterConfig
from ..radar.scene import SceneConfig
from ..tracking.ekf import EkfConfig

__all__ = ["ProcessConfig", "read_process_config", "process_config_from_mapping",
           "process_config_to_toml", "read_matching_config",
           "matching_config_from_mapping", "matching_config_to_toml", "SPARSE_VALUES",
           "FUSE_KEYS", "fuse_table_from_mapping", "read_fuse_table"]

#: EKF fields the file may not set (the recording gives them).
_EKF_FROM_RECORDING = ("frame_period_s",)
#: Nested configuration objects of ChainConfig: TOML sub-tables.
_CHAIN_TABLES = {"cfar": CfarConfig, "cluster": ClusterConfig}
#: Top-level tables: read by ``process`` and by ``calibrate``.
_PROCESS_TABLES = ("chain", "ekf", "scene")
_CALIBRATE_TABLES = ("matching",)
_FUSE_TABLES = ("fuse",)
_KNOWN_TABLES = ("chain, chain.cfar, chain.cluster, ekf, scene (mmsnap process), matching "
                 "(mmsnap calibrate), fuse (mmsnap fuse, batch, replay)")
#: The keys of the ``[fuse]`` table and the values each takes (a tuple of
#: choices, or a type).
FUSE_KEYS: dict[str, object] = {
    "mode": ("map", "ml"), "covariance": ("laplace", "grid"),
    "solver": ("vectorized", "gtsam", "scalar"), "source": ("centroids", "point_cloud"),
    "robust": ("gate", "huber", "cauchy", "none"), "gate": float, "grid_points": int,
    "motion_check": bool, "coverage_check": bool, "placement_check": bool, "body_merge": bool, "body_check": bool,
    "learned_walls": bool, "in_front": bool, "bounds": list, "bounds_cfg": str,
}
#: ``[chain.cluster] sparse`` (and ``mmsnap process --sparse``): the TOML or
#: option value -> ``process_file(sparse=...)``.
SPARSE_VALUES = {"auto": None, True: True, False: False, "on": True, "off": False}


@dataclass(frozen=True, kw_only=True, slots=True)
class ProcessConfig:
    """What ``mmsnap process`` runs with: the chain (with its CFAR and
    clustering) and the local EKF."""

    chain: ChainConfig = field(default_factory=ChainConfig)
    ekf: EkfConfig = field(default_factory=EkfConfig)
    #: The EKF's measurement sigmas from each node's centroids (True, unless
    #: the file sets ``[ekf] measurement_std``).
    ekf_noise_from_data: bool = True
    #: Clustering of stored point clouds with ``min_samples=1``: None (auto:
    #: when the median non-empty frame holds fewer than 6 points after the
    #: scene filters), True, False
    #: (:func:`mmsnap_graph.app.pipeline.sparse_cluster_config`).
    sparse: bool | None = None
    #: The scene filters of stored point clouds (static scene, one cluster per
    #: body, ghosts, existence; :mod:`mmsnap_graph.radar.scene`).
    scene: SceneConfig = field(default_factory=SceneConfig)


def _coerce(where: str, default: Any, value: Any, annotation: Any = None) -> Any:
    """``value`` in the type of the field's default (TOML arrays become tuples,
    integers are accepted for floats; an unset default's type is its
    annotation's); a clear error otherwise."""
    if default is None and str(annotation).startswith(("float", "int")):
        default = 0.0 if str(annotation).startswith("float") else 0
    if isinstance(value, dict):
        raise ConfigurationError(f"{where}: unknown table (expected a value)")
    if isinstance(default, tuple) or isinstance(value, list):
        if not isinstance(value, list):
            raise ConfigurationError(f"{where} must be an array, got {value!r}")
        return tuple(value)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigurationError(f"{where} must be true or false, got {value!r}")
        return value
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if default is not None and not isinstance(value, type(default)):
        raise ConfigurationError(f"{where} must be of type {type(default).__name__}, "
                                 f"got {value!r}")
    return value


def _build(cls, table: Mapping[str, Any], where: str, *, nested=None, forbidden=()):
    """An instance of the dataclass ``cls`` from a TOML table: unknown keys and
    values the class rejects are errors naming ``where.key``."""
    nested = nested or {}
    if not isinstance(table, Mapping):
        name = where.rsplit(": ", 1)[-1]
        raise ConfigurationError(f"{where} must be a table [{name}], got {table!r}")
    names = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        here = f"{where}.{key}"
        if key in forbidden:
            raise ConfigurationError(f"{here} cannot be set in the file (the recording gives it)")
        if key in nested:
            if not isinstance(value, dict):
                raise ConfigurationError(f"{here} must be a table [{here}]")
            kwargs[key] = _build(nested[key], value, here)
            continue
        if key not in names:
            raise ConfigurationError(f"{here}: unknown option (known: "
                                     f"{', '.join(sorted(set(names) - set(forbidden)))})")
        f = names[key]
        default = f.default_factory() if f.default is dataclasses.MISSING else f.default
        kwargs[key] = _coerce(here, default, value, f.type)
    try:
        return cls(**kwargs)
    except (ConfigurationError, ValidationError) as exc:
        raise ConfigurationError(f"[{where}] {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f"[{where}] {exc}") from None


def _check_tables(data: Any, where: str) -> None:
    if not isinstance(data, Mapping):
        raise ConfigurationError(f"{where}: expected a table, got {type(data).__name__}")
    unknown = set(data) - set(_PROCESS_TABLES) - set(_CALIBRATE_TABLES) - set(_FUSE_TABLES)
    if unknown:
        raise ConfigurationError(f"{where}: unknown table(s) {sorted(unknown)} "
                                 f"(known: {_KNOWN_TABLES})")


def _sparse_of(chain_table: Any, where: str) -> tuple[Any, bool | None]:
    """``[chain.cluster] sparse`` taken out of the chain table (ClusterConfig
    has no such field): the table without it, and its value."""
    if not isinstance(chain_table, Mapping) or not isinstance(chain_table.get("cluster"), Mapping):
        return chain_table, None
    cluster = dict(chain_table["cluster"])
    if "sparse" not in cluster:
        return chain_table, None
    value = cluster.pop("sparse")
    if isinstance(value, (bool, str)) and value in ("auto", True, False):
        return {**chain_table, "cluster": cluster}, SPARSE_VALUES[value]
    raise ConfigurationError(f"{where}: chain.cluster.sparse must be \"auto\", true or false, "
                             f"got {value!r}")


def process_config_from_mapping(data: Mapping[str, Any], *, where: str = "config"
                                ) -> ProcessConfig:
    """A :class:`ProcessConfig` from a parsed TOML document (tables ``chain``,
    ``chain.cfar``, ``chain.cluster``, ``ekf``; ``matching`` is
    ``mmsnap calibrate``'s and is ignored)."""
    _check_tables(data, where)
    chain_table, sparse = _sparse_of(data.get("chain", {}), where)
    chain = _build(ChainConfig, chain_table, f"{where}: chain", nested=_CHAIN_TABLES)
    ekf_table = data.get("ekf", {})
    ekf = _build(EkfConfig, ekf_table, f"{where}: ekf", forbidden=_EKF_FROM_RECORDING)
    from_data = not (isinstance(ekf_table, Mapping) and "measurement_std" in ekf_table)
    scene = _build(SceneConfig, data.get("scene", {}), f"{where}: scene")
    return ProcessConfig(chain=chain, ekf=ekf, ekf_noise_from_data=from_data, sparse=sparse,
                         scene=scene)


def matching_config_from_mapping(data: Mapping[str, Any], *, where: str = "config"
                                 ) -> MatchingOptions:
    """The library's :class:`~mmsnap_graph.calibration.MatchingOptions` from a
    parsed TOML document (table
    ``matching``; ``chain``, ``ekf`` are ``mmsnap process``'s and are
    ignored)."""
    _check_tables(data, where)
    return _build(MatchingOptions, data.get("matching", {}), f"{where}: matching")


def _read_toml(path: str | os.PathLike) -> tuple[dict[str, Any], str]:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")  # a byte-order mark (Windows editors) is read past
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigurationError(f"{p}: cannot read the configuration file: {exc}") from None
    try:
        return tomllib.loads(text), str(p)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigurationError(f"{p}: not valid TOML: {exc}") from None


def fuse_table_from_mapping(data: Mapping[str, Any], *, where: str = "config"
                            ) -> dict[str, Any]:
    """The ``[fuse]`` table of a parsed TOML document, checked key by key
    against :data:`FUSE_KEYS` (``bounds``: four numbers, a tuple)."""
    _check_tables(data, where)
    table = data.get("fuse", {})
    if not isinstance(table, Mapping):
        raise ConfigurationError(f"{where}: fuse must be a table [fuse], got {table!r}")
    out: dict[str, Any] = {}
    for key, value in table.items():
        here = f"{where}: fuse.{key}"
        kind = FUSE_KEYS.get(key)
        if kind is None:
            raise ConfigurationError(f"{here}: unknown option (known: {', '.join(FUSE_KEYS)})")
        if isinstance(kind, tuple):
            if value not in kind or isinstance(value, bool):
                raise ConfigurationError(f"{here} must be one of {', '.join(kind)}, got "
                                         f"{value!r}")
        elif kind is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigurationError(f"{here} must be a number, got {value!r}")
            value = float(value)
        elif kind is list:
            if not (isinstance(value, list) and len(value) == 4 and all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
                raise ConfigurationError(f"{here} must be [x_min, x_max, y_min, y_max] in "
                                         f"metres, got {value!r}")
            value = tuple(float(v) for v in value)
        elif not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise ConfigurationError(f"{here} must be of type {kind.__name__}, got {value!r}")
        out[key] = value
    return out


def read_fuse_table(path: str | os.PathLike) -> dict[str, Any]:
    """Read the ``[fuse]`` table of a ``--config`` TOML file (errors as
    :func:`read_process_config`)."""
    data, where = _read_toml(path)
    return fuse_table_from_mapping(data, where=where)


def read_matching_config(path: str | os.PathLike) -> MatchingOptions:
    """Read the ``[matching]`` table of a ``--config`` TOML file (errors as
    :func:`read_process_config`)."""
    data, where = _read_toml(path)
    return matching_config_from_mapping(data, where=where)


def read_process_config(path: str | os.PathLike) -> ProcessConfig:
    """Read a ``mmsnap process`` TOML file (layout in the module docstring).

    Raises :class:`ConfigurationError` naming the file and the line of a
    syntax error, or the table and key of a bad value.
    """
    data, where = _read_toml(path)
    return process_config_from_mapping(data, where=where)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, float):
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    return str(int(value)) if isinstance(value, int) else repr(value)


def _table_lines(obj, header: str, skip=(), commented=()) -> list[str]:
    lines = [f"[{header}]"]
    for f in dataclasses.fields(obj):
        if f.name in skip or dataclasses.is_dataclass(getattr(obj, f.name)):
            continue
        value = getattr(obj, f.name)
        if f.name in commented:
            lines.append(f"# {f.name} = {_toml_value(value)}  (unset: {commented[f.name]})")
        elif value is None:
            lines.append(f"# {f.name} = (unset)")
        else:
            lines.append(f"{f.name} = {_toml_value(value)}")
    return lines


def process_config_to_toml(config: ProcessConfig) -> str:
    """The configuration as a TOML file that :func:`read_process_config`
    reads back to an equal configuration (unset values as comments)."""
    lines = ["# mmsnap process configuration (docs/TI.md, 'Processing options')"]
    lines += _table_lines(config.chain, "chain")
    for name in _CHAIN_TABLES:
        lines += [""] + _table_lines(getattr(config.chain, name), f"chain.{name}")
        if name == "cluster":  # not a ClusterConfig field (process_file's switch)
            sparse = {None: '"auto"', True: "true", False: "false"}[config.sparse]
            lines.append(f"sparse = {sparse}  # stored point clouds: \"auto\", true or false")
    commented = ({"measurement_std": "estimated from each node's centroids; set it to fix "
                                     "the EKF's range, omega, Doppler sigmas"}
                 if config.ekf_noise_from_data else {})
    lines += [""] + _table_lines(config.ekf, "ekf", skip=_EKF_FROM_RECORDING,
                                 commented=commented)
    lines += [""] + _table_lines(config.scene, "scene")
    return "\n".join(lines) + "\n"


def matching_config_to_toml(config: MatchingOptions) -> str:
    """The ``[matching]`` table that :func:`read_matching_config` reads back
    to an equal configuration (the same file may hold ``mmsnap process``'s
    tables)."""
    lines = ["# mmsnap calibrate configuration (docs/CALIBRATION.md, 'Matching gate and "
             "thresholds in seconds'); seconds and metres"]
    lines += _table_lines(config, "matching")
    return "\n".join(lines) + "\n"

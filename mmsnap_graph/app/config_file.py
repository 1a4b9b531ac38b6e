"""The ``mmsnap process --config FILE`` TOML file: every option of the signal
chain, the clustering and the local EKF in one place.

Layout (every key optional; an absent key keeps its default; ``mmsnap process
--show-config`` prints the effective file with every default)::

    [chain]            # radar.chain.ChainConfig (windows, ranges, de-aliasing, ...)
    min_range_m = 0.9
    [chain.cfar]       # radar.cfar.CfarConfig
    pfa = 1e-6
    [chain.cluster]    # radar.cluster.ClusterConfig
    point_targets = true
    [ekf]              # tracking.ekf.EkfConfig (thresholds in seconds)
    sigma_a_mps2 = 1.0

TOML has no null: a key whose default is "unset" (e.g. ``max_range_m``, the
radar's unambiguous range) is set by giving a value and unset by leaving it
out. ``[ekf] frame_period_s`` is always the recording's frame period (a value
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

from ..errors import ConfigurationError
from ..radar.cfar import CfarConfig
from ..radar.chain import ChainConfig
from ..radar.cluster import ClusterConfig
from ..tracking.ekf import EkfConfig

__all__ = ["ProcessConfig", "read_process_config", "process_config_from_mapping",
           "process_config_to_toml"]

#: EKF fields the file may not set (the recording gives them).
_EKF_FROM_RECORDING = ("frame_period_s",)
#: Nested configuration objects of ChainConfig: TOML sub-tables.
_CHAIN_TABLES = {"cfar": CfarConfig, "cluster": ClusterConfig}


@dataclass(frozen=True, kw_only=True, slots=True)
class ProcessConfig:
    """What ``mmsnap process`` runs with: the chain (with its CFAR and
    clustering) and the local EKF."""

    chain: ChainConfig = field(default_factory=ChainConfig)
    ekf: EkfConfig = field(default_factory=EkfConfig)


def _coerce(where: str, default: Any, value: Any) -> Any:
    """``value`` in the type of the field's default (TOML arrays become tuples,
    integers are accepted for floats); a clear error otherwise."""
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
        kwargs[key] = _coerce(here, default, value)
    try:
        return cls(**kwargs)
    except ConfigurationError as exc:
        raise ConfigurationError(f"[{where}] {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f"[{where}] {exc}") from None


def process_config_from_mapping(data: Mapping[str, Any], *, where: str = "config"
                                ) -> ProcessConfig:
    """A :class:`ProcessConfig` from a parsed TOML document (tables ``chain``,
    ``chain.cfar``, ``chain.cluster``, ``ekf``)."""
    if not isinstance(data, Mapping):
        raise ConfigurationError(f"{where}: expected a table, got {type(data).__name__}")
    unknown = set(data) - {"chain", "ekf"}
    if unknown:
        raise ConfigurationError(f"{where}: unknown table(s) {sorted(unknown)} "
                                 f"(known: chain, chain.cfar, chain.cluster, ekf)")
    chain = _build(ChainConfig, data.get("chain", {}), f"{where}: chain", nested=_CHAIN_TABLES)
    ekf = _build(EkfConfig, data.get("ekf", {}), f"{where}: ekf", forbidden=_EKF_FROM_RECORDING)
    return ProcessConfig(chain=chain, ekf=ekf)


def read_process_config(path: str | os.PathLike) -> ProcessConfig:
    """Read a ``mmsnap process`` TOML file (layout in the module docstring).

    Raises :class:`ConfigurationError` naming the file and the line of a
    syntax error, or the table and key of a bad value.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigurationError(f"{p}: cannot read the configuration file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigurationError(f"{p}: not valid TOML: {exc}") from None
    return process_config_from_mapping(data, where=str(p))


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


def _table_lines(obj, header: str, skip=()) -> list[str]:
    lines = [f"[{header}]"]
    for f in dataclasses.fields(obj):
        if f.name in skip or dataclasses.is_dataclass(getattr(obj, f.name)):
            continue
        value = getattr(obj, f.name)
        if value is None:
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
    lines += [""] + _table_lines(config.ekf, "ekf", skip=_EKF_FROM_RECORDING)
    return "\n".join(lines) + "\n"

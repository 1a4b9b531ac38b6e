"""The CFAR functions and CfarConfig validate their inputs (issue 13: "the
CFAR functions check nothing"; CfarConfig was not type-checked)."""

import numpy as np
import pytest
from hypothesis import given, strategies as st

from mmsnap_graph.errors import ConfigurationError, ValidationError, MmsnapError
from mmsnap_graph.radar.cfar import (
    CfarConfig,
    footprint,
    os_cfar_2d,
    os_cfar_alpha,
    os_cfar_cells,
    os_cfar_noise_scale,
    pad_map,
    os_cfar_detections,
)

from _fuzz import ANY_VALUE, EDGE, FUZZ

CFG = CfarConfig()
MAP = np.random.default_rng(0).exponential(size=(40, 16))


@pytest.mark.parametrize("kwargs, field", [
    ({"guard_cells": "ab"}, "guard_cells"),
    ({"guard_cells": (2.5, 1)}, "guard_cells"),
    ({"guard_cells": (True, 1)}, "guard_cells"),
    ({"train_cells": (8, 3, 1)}, "train_cells"),
    ({"train_cells": (-1, 3)}, "train_cells"),
    ({"train_cells": 8}, "train_cells"),
    ({"rank_fraction": "0.75"}, "rank_fraction"),
    ({"rank_fraction": True}, "rank_fraction"),
    ({"rank_fraction": float("nan")}, "rank_fraction"),
    ({"pfa": None}, "pfa"),
    ({"pfa": "1e-6"}, "pfa"),
    ({"pfa": 1.0}, "pfa"),
])
def test_cfar_config_is_type_checked(kwargs, field):
    with pytest.raises(ConfigurationError, match=field):
        CfarConfig(**kwargs)


def test_cfar_config_accepts_numpy_scalars():
    cfg = CfarConfig(guard_cells=(np.int64(2), 1), rank_fraction=np.float32(0.5), pfa=1e-4)
    assert cfg.guard_cells == (2, 1) and type(cfg.rank_fraction) is float


@pytest.mark.parametrize("power, match", [
    (np.ones(16), "shape"),
    (np.ones((0, 16)), "shape"),
    (np.ones((40, 16), complex), "real"),
    (np.array([["a"] * 16] * 40), "real"),
    (np.full((40, 16), np.nan), "finite"),
    (-np.ones((40, 16)), ">= 0"),
])
@pytest.mark.parametrize("fn", ["os_cfar_2d", "os_cfar_cells", "pad_map"])
def test_power_maps_are_checked(fn, power, match):
    call = {"os_cfar_2d": lambda: os_cfar_2d(power, CFG),
            "os_cfar_cells": lambda: os_cfar_cells(power, [1], [1], CFG),
            "pad_map": lambda: pad_map(power, CFG)}[fn]
    with pytest.raises(ValidationError, match=match):
        call()


@pytest.mark.parametrize("rows, cols, match", [
    ([1.5], [1], "rows"),
    ([[1]], [1], "rows"),
    ([1, 2], [1], "one shape"),
    ([1], [True], "cols"),
    ([40], [1], "outside"),
    ([1], [-1], "outside"),
])
def test_cells_are_checked(rows, cols, match):
    with pytest.raises(ConfigurationError, match=match):
        os_cfar_cells(MAP, rows, cols, CFG)


def test_configs_and_channels_are_checked():
    with pytest.raises(ConfigurationError, match="CfarConfig"):
        os_cfar_2d(MAP, {"pfa": 1e-3})
    with pytest.raises(ConfigurationError, match="CfarConfig"):
        footprint(None)
    for bad in (0, 2.0, True):
        with pytest.raises(ConfigurationError, match="n_channels"):
            os_cfar_cells(MAP, [1], [1], CFG, bad)
        with pytest.raises(ConfigurationError, match="n_channels"):
            os_cfar_2d(MAP, CFG, bad)
    with pytest.raises(ConfigurationError, match="pfa"):
        os_cfar_alpha(10, 5, 2.0)
    with pytest.raises(ConfigurationError, match="rank"):
        os_cfar_noise_scale(10, 11)
    with pytest.raises(ConfigurationError, match="n_train"):
        os_cfar_alpha(0, 1, 1e-3)
    with pytest.raises(ValidationError, match="padded"):
        os_cfar_cells(MAP, [1], [1], CFG, padded=MAP)


def test_valid_calls_still_agree():
    det, z = os_cfar_2d(MAP, CFG, 2)
    rows, cols = np.nonzero(np.ones_like(MAP, bool))
    det_c, z_c = os_cfar_cells(MAP, rows, cols, CFG, 2)
    np.testing.assert_array_equal(det_c, det.ravel())
    np.testing.assert_allclose(z_c, z.ravel())
    assert os_cfar_cells(MAP, [], [], CFG)[0].shape == (0,)


@pytest.mark.parametrize("cfg", [
    CfarConfig(),
    CfarConfig(rank_fraction=0.5, pfa=1e-3),
    CfarConfig(rank_fraction=1.0, pfa=1e-2),
    CfarConfig(guard_cells=(0, 0), train_cells=(1, 1), rank_fraction=0.9),
    CfarConfig(guard_cells=(1, 2), train_cells=(3, 0)),
])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_os_cfar_detections_are_the_detected_cells_of_os_cfar_cells(cfg, dtype):
    rng = np.random.default_rng(3)
    power = rng.gamma(12, size=(60, 32)).astype(dtype)
    hot = rng.integers(0, power.size, 40)
    power.ravel()[hot] *= rng.uniform(1, 30, hot.size)  # some pass, some fail
    rows, cols = np.nonzero(np.ones(power.shape, bool))
    det, z = os_cfar_cells(power, rows, cols, cfg, 12)
    keep, z_keep = os_cfar_detections(power, rows, cols, cfg, 12)
    assert det.sum() > 0 and det.sum() < det.size
    np.testing.assert_array_equal(keep, np.flatnonzero(det))
    np.testing.assert_array_equal(z_keep, z[det])
    keep2, z2 = os_cfar_detections(power, rows, cols, cfg, 12, padded=pad_map(power, cfg))
    np.testing.assert_array_equal(keep2, keep)
    np.testing.assert_array_equal(z2, z_keep)
    empty = os_cfar_detections(power, rows[:0], cols[:0], cfg, 12)
    assert empty[0].shape == (0,) and empty[1].shape == (0,)


@pytest.mark.parametrize("shape", [(1, 1), (3, 2), (5, 9), (21, 9), (40, 16), (486, 32)])
def test_pad_map_equals_numpy_pad(shape):
    cfg = CfarConfig()
    power = np.random.default_rng(1).random(shape).astype(np.float32)
    hr, hd = 10, 4
    want = np.pad(np.pad(power, ((0, 0), (hd, hd)), mode="wrap"), ((hr, hr), (0, 0)),
                  mode="symmetric")
    got = pad_map(power, cfg)
    assert got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)


# Fuzzing: only the project's errors, and the cell-by-cell OS-CFAR agrees with
# the whole-map one.


def power_maps():
    shape = st.tuples(st.integers(1, 12), st.integers(1, 9))
    return shape.flatmap(lambda s: st.lists(st.one_of(st.floats(0, 1e3), EDGE),
                                            min_size=s[0] * s[1], max_size=s[0] * s[1])
                         .map(lambda v: np.array(v, dtype=float).reshape(s)))


cfar_configs = st.builds(
    dict, guard_cells=st.tuples(st.integers(0, 3), st.integers(0, 2)),
    train_cells=st.tuples(st.integers(0, 4), st.integers(0, 3)),
    rank_fraction=st.one_of(st.floats(0.05, 1.0), EDGE), pfa=st.one_of(
        st.floats(1e-12, 0.5), st.sampled_from([1e-300, 1e-100, 0.999999]), EDGE))


@FUZZ
@given(power=power_maps(), cfg=cfar_configs, channels=st.one_of(st.integers(1, 4), ANY_VALUE))
def test_os_cfar_raises_only_typed_errors_and_agrees_cell_by_cell(power, cfg, channels):
    try:
        config = CfarConfig(**cfg)
        detected, z = os_cfar_2d(power, config, channels)
    except MmsnapError:
        return
    assert detected.shape == power.shape and detected.dtype == bool
    assert np.all(np.isfinite(z))
    r, c = np.nonzero(np.ones(power.shape, bool))
    cells, z_cells = os_cfar_cells(power, r, c, config, channels)
    np.testing.assert_array_equal(cells, detected.ravel())
    np.testing.assert_allclose(z_cells, z.ravel())


@FUZZ
@given(rows_=st.one_of(st.lists(st.integers(-3, 14), max_size=4), ANY_VALUE),
       cols_=st.one_of(st.lists(st.integers(-3, 10), max_size=4), ANY_VALUE))
def test_os_cfar_cells_rejects_bad_cells_with_typed_errors(rows_, cols_):
    power = np.random.default_rng(1).exponential(size=(12, 8))
    try:
        detected, z = os_cfar_cells(power, rows_, cols_, CfarConfig())
    except MmsnapError:
        return
    assert detected.shape == z.shape and np.all(np.isfinite(z))


@FUZZ
@given(n_train=ANY_VALUE, rank=ANY_VALUE, pfa=st.one_of(EDGE, st.sampled_from([1e-300, 1e-200])),
       channels=ANY_VALUE)
def test_os_cfar_alpha_raises_only_typed_errors(n_train, rank, pfa, channels):
    """Found: unhashable arguments gave TypeError (the cache), a pfa near 1
    brentq's ValueError, a pfa of 1e-300 the bracket's end as the factor."""
    try:
        alpha = os_cfar_alpha(n_train, rank, pfa, channels)
    except MmsnapError:
        return
    assert np.isfinite(alpha) and alpha > 0


@pytest.mark.parametrize("args", [([16], 12, 1e-6, 1), (16, 12, 0.999999, 1), (16, 12, 1e-300, 1),
                                  (16, 12, 1e-6, [2])])
def test_os_cfar_alpha_found_cases_are_configuration_errors(args):
    from mmsnap_graph.errors import ConfigurationError

    with pytest.raises(ConfigurationError):
        os_cfar_alpha(*args)

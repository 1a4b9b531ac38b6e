"""The CFAR functions and CfarConfig validate their inputs (issue 13: "the
CFAR functions check nothing"; CfarConfig was not type-checked)."""

import numpy as np
import pytest

from mmsnap_graph.errors import ConfigurationError, ValidationError
from mmsnap_graph.radar.cfar import (
    CfarConfig,
    footprint,
    os_cfar_2d,
    os_cfar_alpha,
    os_cfar_cells,
    os_cfar_noise_scale,
    pad_map,
)

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

from dataclasses import fields

import numpy as np
import pytest
from hydra.utils import instantiate

from spacetrack.config import compose_config
from spacetrack.enhance import DwtHsvEnhancer, NoEnhancement, enhance_dwt_hsv


def _enhance_cfg(name: str, *overrides: str):
    return compose_config("track", [f"enhance={name}", *overrides]).enhance


def test_none_config_builds_the_identity(dim_frame):
    enhancer = instantiate(_enhance_cfg("none"))
    assert isinstance(enhancer, NoEnhancement) and enhancer.name == "none"
    np.testing.assert_array_equal(enhancer(dim_frame.rgb), dim_frame.rgb)


def test_dwt_hsv_config_holds_every_parameter_and_matches_the_defaults(dim_frame):
    cfg = _enhance_cfg("dwt_hsv")
    enhancer = instantiate(cfg)
    assert isinstance(enhancer, DwtHsvEnhancer) and enhancer.name == "dwt_hsv"
    assert enhancer == DwtHsvEnhancer(), "the YAML and the code defaults must agree"
    params = {k: v for k, v in cfg.items() if k != "_target_"}
    assert set(params) == {f.name for f in fields(DwtHsvEnhancer)}
    assert enhancer(dim_frame.rgb).tobytes() == enhance_dwt_hsv(dim_frame.rgb, **params).tobytes()


def test_config_keys_override_from_the_command_line(dim_frame):
    default = instantiate(_enhance_cfg("dwt_hsv"))
    enhancer = instantiate(_enhance_cfg("dwt_hsv", "enhance.wavelet=haar", "enhance.level=3"))
    assert (default.wavelet, default.level) != ("haar", 3)
    assert (enhancer.wavelet, enhancer.level) == ("haar", 3)
    # the overrides reach the computation: the picture changes
    assert not np.array_equal(enhancer(dim_frame.rgb), default(dim_frame.rgb))


def test_a_bad_override_fails_at_construction():
    with pytest.raises(Exception, match="low_percentile=99.95"):
        instantiate(_enhance_cfg("dwt_hsv", "enhance.low_percentile=99.95"))

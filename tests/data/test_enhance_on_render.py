"""The DWT/HSV enhancement on a dim rendered frame: target pixels stand out more from the background."""

from __future__ import annotations

import cv2
import numpy as np
from hydra.utils import instantiate
from omegaconf import OmegaConf

from spacetrack.config import compose_config
from spacetrack.data.raster import Camera
from spacetrack.data.render import SequenceRenderer
from spacetrack.data.scenario import scenario_params
from spacetrack.data.scene import plan_sequence
from spacetrack.enhance import DwtHsvEnhancer, NoEnhancement


def _dim_frame():
    params = scenario_params(
        "dim", OmegaConf.merge(compose_config("build_data").data.scenario.dim, {"num_targets": [3, 3]})
    )
    camera = Camera.from_fov(640, 480, 40.0)
    plan = plan_sequence(name="dim", scenario="dim", params=params, camera=camera, num_frames=30, seed=[1, 2])
    rgb, truth = SequenceRenderer(plan).render(15)
    return rgb, truth.motion_mask


def _contrast(rgb: np.ndarray, target: np.ndarray) -> float:
    """Mean brightness (HSV value) of target pixels minus that of the background, in grey levels."""
    value = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)[..., 2].astype(float)
    background = ~cv2.dilate(target.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    return value[target].mean() - value[background].mean()


def test_dwt_hsv_raises_target_contrast_on_a_dim_rendered_frame():
    rgb, target = _dim_frame()
    assert target.sum() > 200, "the frame should show targets"
    assert np.percentile(rgb, 99) < 60, "the frame should be dim"
    enhancer = instantiate(compose_config("build_data", ["enhance=dwt_hsv"]).enhance)
    assert isinstance(enhancer, DwtHsvEnhancer)
    before, after = _contrast(rgb, target), _contrast(enhancer(rgb), target)
    assert after > 1.5 * before, f"contrast {before:.1f} -> {after:.1f} grey levels"
    np.testing.assert_array_equal(NoEnhancement()(rgb), rgb)

"""Input enhancement for dark space frames: the DWT/HSV pipeline (paper Fig. 10) and the identity.

Three ways to use it: the function `enhance_dwt_hsv(rgb, **params)`, an object built from
`conf/enhance/<name>.yaml` with `hydra.utils.instantiate(cfg.enhance)` (`DwtHsvEnhancer`,
`NoEnhancement`; both have a `name` and map RGB uint8 (H, W, 3) to the same), and the albumentations
transform `EnhanceTransform(enhancer, p=1.0)`.
"""

from spacetrack.enhance.base import NoEnhancement, check_rgb
from spacetrack.enhance.dwt_hsv import DwtHsvEnhancer, enhance_dwt_hsv
from spacetrack.enhance.transforms import EnhanceTransform

__all__ = ["DwtHsvEnhancer", "EnhanceTransform", "NoEnhancement", "check_rgb", "enhance_dwt_hsv"]

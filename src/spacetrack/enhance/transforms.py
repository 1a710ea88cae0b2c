"""Any enhancer as an albumentations image-only transform, so it can sit inside `A.Compose`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import albumentations as A
import numpy as np


class EnhanceTransform(A.ImageOnlyTransform):
    """Apply `enhancer` (RGB uint8 (H, W, 3) -> same) to the image; boxes, masks and keypoints are untouched.

    The enhancers keep the image size, so spatial targets stay valid.
    """

    def __init__(self, enhancer: Callable[[np.ndarray], np.ndarray], p: float = 1.0) -> None:
        super().__init__(p=p)
        self.enhancer = enhancer

    def apply(self, img: np.ndarray, **params: Any) -> np.ndarray:
        return self.enhancer(img)

    def get_transform_init_args_names(self) -> tuple[str, ...]:
        return ("enhancer",)

import pickle

import albumentations as A
import numpy as np
import pytest

from spacetrack.enhance import DwtHsvEnhancer, EnhanceTransform, NoEnhancement, enhance_dwt_hsv


# Compose warns that no transform in this pipeline moves boxes, which is the point here.
@pytest.mark.filterwarnings("ignore:Got processor for bboxes")
def test_transform_in_compose_equals_the_function_and_keeps_boxes(dim_frame):
    pipeline = A.Compose(
        [EnhanceTransform(DwtHsvEnhancer(), p=1.0)],
        bbox_params=A.BboxParams(format="pascal_voc", label_fields=["labels"]),
    )
    boxes = [(68.0, 48.0, 93.0, 73.0), (202.0, 142.0, 219.0, 159.0)]
    out = pipeline(image=dim_frame.rgb, bboxes=boxes, labels=[0, 1])
    assert out["image"].tobytes() == enhance_dwt_hsv(dim_frame.rgb).tobytes()
    np.testing.assert_allclose(np.asarray(out["bboxes"]), boxes)


def test_transform_with_p_zero_leaves_the_image(dim_frame):
    out = A.Compose([EnhanceTransform(DwtHsvEnhancer(), p=0.0)])(image=dim_frame.rgb)
    np.testing.assert_array_equal(out["image"], dim_frame.rgb)


def test_no_enhancement_is_the_identity(dim_frame):
    none = NoEnhancement()
    assert none.name == "none"
    out = none(dim_frame.rgb)
    assert out is dim_frame.rgb
    via_transform = A.Compose([EnhanceTransform(none)])(image=dim_frame.rgb)["image"]
    np.testing.assert_array_equal(via_transform, dim_frame.rgb)


def test_transform_survives_pickling_for_loader_workers(dim_frame):
    transform = EnhanceTransform(DwtHsvEnhancer(level=2), p=1.0)
    clone = pickle.loads(pickle.dumps(transform))
    assert clone.enhancer == transform.enhancer
    np.testing.assert_array_equal(
        clone(image=dim_frame.rgb)["image"], enhance_dwt_hsv(dim_frame.rgb, level=2)
    )

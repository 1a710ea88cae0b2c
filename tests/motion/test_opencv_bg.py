import numpy as np
import pytest

from spacetrack.motion import KNN, MOG2


@pytest.mark.parametrize("cls", [MOG2, KNN])
def test_square_moving_over_black_field_with_a_static_star(scene, run, cls):
    frames, truth = scene(30, shape=(64, 400), velocity=(10, 0), stars=((5, 5), (90, 60)))
    masks = run(cls(), frames)
    assert cls.latency == 0 and sorted(masks) == list(range(30))
    for t in range(5, 30):
        iou = (masks[t] & truth[t]).sum() / (masks[t] | truth[t]).sum()
        assert iou > 0.8
        assert not masks[t][5, 5] and not masks[t][60, 90]


@pytest.mark.parametrize("cls", [MOG2, KNN])
def test_a_global_flash_is_motion_to_the_peers(scene, run, cls):
    # the peers have no light-adaptive threshold: what the differences ignore, they report
    frames, _ = scene(20, velocity=(0, 0), flash_at=15)
    masks = run(cls(), frames)
    assert not masks[14].any()
    assert masks[15].mean() > 0.9


def test_shadow_label_is_not_motion():
    mog2 = MOG2(detect_shadows=True, grey=True)
    dark = np.full((8, 8), 100, np.uint8)
    for _ in range(20):
        mog2.apply(dark)
    # a uniformly darkened pixel is a shadow (127) to MOG2, not part of the 0/255 mask
    assert set(np.unique(mog2.apply(np.full((8, 8), 70, np.uint8)))) <= {0}

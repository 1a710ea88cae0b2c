import pytest
from hydra.utils import instantiate

from spacetrack.config import compose_config
from spacetrack.models.yolo import count_parameters


@pytest.mark.parametrize(
    ("name", "gam_position", "gam_groups"),
    [("yolov5s", None, 1), ("yolov5s_gam", "after_sppf", 1), ("yolov5s_gam_light", "after_sppf", 4)],
)
def test_model_configs_build_what_they_say(name, gam_position, gam_groups):
    cfg = compose_config("train", [f"model={name}", "logger=none"])
    model = instantiate(cfg.model, num_classes=80)
    assert (model.arch["gam_position"], model.arch["gam_groups"]) == (gam_position, gam_groups)
    if name == "yolov5s":
        assert count_parameters(model) == 7_235_389

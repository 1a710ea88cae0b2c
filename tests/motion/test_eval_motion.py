import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from hydra.utils import instantiate

from spacetrack.config import CONF_DIR, compose_config
from spacetrack.eval_motion import run


def _write_sequence(root: Path, name: str, frames: list[np.ndarray], truth: list[np.ndarray]) -> None:
    seq = root / name
    for sub in ("img", "masks", "gt"):
        (seq / sub).mkdir(parents=True)
    rows = []
    for i, (frame, mask) in enumerate(zip(frames, truth, strict=True), start=1):
        cv2.imwrite(str(seq / "img" / f"{i:06d}.png"), frame)
        cv2.imwrite(str(seq / "masks" / f"{i:06d}.png"), mask.astype(np.uint8) * 255)
        ys, xs = np.nonzero(mask)
        rows.append(f"{i},1,{xs.min()},{ys.min()},{np.ptp(xs) + 1},{np.ptp(ys) + 1},1,0,1.0")
    (seq / "gt" / "gt.txt").write_text("\n".join(rows) + "\n")


@pytest.fixture
def dataset(tmp_path, scene):
    root = tmp_path / "tiny"
    sequences = []
    for k, (name, scenario) in enumerate((("seq_000_nominal", "nominal"), ("seq_001_slew", "slew"))):
        frames, truth = scene(12, size=10, velocity=(4, 1), stars=((5, 5), (90, 60)), seed=k)
        _write_sequence(root, name, frames, truth)
        sequences.append({"name": name, "scenario": scenario, "fold": k, "num_frames": 12})
    manifest = {"name": "tiny", "format_version": 1, "num_folds": 2, "sequences": sequences}
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root


def test_every_motion_config_builds_its_object():
    names = {p.stem for p in (CONF_DIR / "motion").glob("*.yaml")}
    assert {"two_frame", "three_frame", "five_frame", "vibe", "mog2", "knn", "fusion", "dynamic"} <= names
    cfg = compose_config("eval_motion", ["logger=none"])
    for method in cfg.methods.values():
        assert hasattr(instantiate(method), "apply")
    assert instantiate(cfg.dynamic).min_overlap == cfg.dynamic.min_overlap


def test_scores_every_method_per_scenario_and_writes_the_report(dataset, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    cfg = compose_config("eval_motion", [f"dataset={dataset}", f"output_dir={out}", "logger=none"])
    metrics = run(cfg)
    for label in ("nominal", "slew", "slew_off", "slew_gmc", "overall"):
        for method in cfg.methods:
            assert 0.0 <= metrics[f"{label}.{method}.pixel_f1"] <= 1.0
    # a bright square on a still black field: the fusion finds it, blob for blob
    assert metrics["nominal.fusion.pixel_f1"] > 0.8
    assert metrics["nominal.fusion.blob_recall"] == 1.0
    assert metrics["nominal.fusion.dynamic_recall"] == 1.0
    record = json.loads((out / "accuracy.json").read_text(), parse_constant=pytest.fail)
    assert record["results"]["nominal"]["fusion"]["static_rejection"] is None  # no static object
    assert record["also_scored_off_and_on"] == ["slew"]
    assert set(record["results"]) == {"nominal", "slew", "slew_off", "slew_gmc", "overall"}
    # the overall row pools the rows as configured: frames of nominal and slew, not of _off and _gmc
    assert record["results"]["overall"]["fusion"]["frames"] == 2 * (12 - 2 - 2)
    assert record["results"]["nominal"]["fusion"]["frames"] == 12 - 2 - 2
    report = (out / "accuracy.md").read_text()
    assert "| nominal |" in report
    # the pixel F1 table ends in the visible ceiling, which every method's score of that row shares
    ceiling = record["results"]["nominal"]["fusion"]["pixel_f1_ceiling"]
    assert record["results"]["nominal"]["knn"]["pixel_f1_ceiling"] == ceiling
    assert f"| {ceiling:.3f} |" in report.split("### pixel_f1")[1].split("###")[0]
    assert cv2.imread(str(out / "sheet_slew_gmc.jpg")) is not None


def test_unknown_scenario_and_missing_output_folder_are_named(dataset, tmp_path):
    cfg = compose_config("eval_motion", [f"dataset={dataset}", f"output_dir={tmp_path}", "logger=none"])
    cfg.scenarios = ["dim"]
    with pytest.raises(ValueError, match=r"scenario\(s\) \['dim'\]"):
        run(cfg)
    cfg.output_dir = str(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match="nowhere"):
        run(cfg)

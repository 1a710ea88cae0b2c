"""The dataset on disk: layout, agreement between files, folds, determinism and failure handling."""

from __future__ import annotations

import configparser
import json

import cv2
import numpy as np
import pytest
from hydra.errors import MissingConfigException

from spacetrack import build_data
from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.data.layout import frame_paths, load_manifest, read_mot, rendered_truth, split_sequences
from spacetrack.data.yolo_dataset import read_labels


def _tiny(root, *extra):
    """A fast build: two nominal sequences of 12 frames at 160x120 in two folds."""
    return compose_config(
        "build_data",
        [
            "data=smoke",
            "data/scenario=[nominal]",
            "data.num_sequences=2",
            "data.num_folds=2",
            "data.num_frames=12",
            "data.width=160",
            "data.height=120",
            "logger=none",
            "progress=false",
            "workers=1",
            f"data_root={root}",
            *extra,
        ],
    )


def test_layout_and_manifest(smoke_dataset):
    manifest = load_manifest(smoke_dataset)
    assert manifest["class_names"] == ["satellite", "rocket_body", "debris"]
    assert len(manifest["sequences"]) == 9
    assert {s["scenario"] for s in manifest["sequences"]} >= {
        "nominal",
        "dim",
        "strong_light",
        "occlusion",
        "multi_target",
        "static_distractors",
    }
    for seq in manifest["sequences"]:
        d = smoke_dataset / seq["name"]
        assert len(frame_paths(smoke_dataset, seq["name"])) == seq["num_frames"] == 48
        assert len(list((d / "masks").glob("*.png"))) == 48
        assert len(list((d / "labels").glob("*.txt"))) == 48
        info = configparser.ConfigParser()
        info.read(d / "seqinfo.ini")
        assert info["Sequence"]["seqLength"] == "48" and info["Sequence"]["imWidth"] == "320"
        assert info["Sequence"]["scenario"] == seq["scenario"]
    for name in ("CARD.md", "card_stats.png", "contact_sheet.jpg"):
        assert (smoke_dataset / name).stat().st_size > 0


def test_mot_and_yolo_boxes_are_identical(smoke_dataset):
    manifest = load_manifest(smoke_dataset)
    w, h, compared = manifest["width"], manifest["height"], 0
    for seq in manifest["sequences"]:
        d = smoke_dataset / seq["name"]
        rows = np.concatenate([read_mot(d / "gt" / "gt.txt"), read_mot(d / "gt" / "static.txt")])
        for frame in range(1, seq["num_frames"] + 1):
            visible = rows[(rows[:, 0] == frame) & (rows[:, 8] > 0)]
            labels = read_labels(d / "labels" / f"{frame:06d}.txt", num_classes=3).astype(float)
            boxes = (
                np.stack(
                    [
                        (labels[:, 1] - labels[:, 3] / 2) * w,
                        (labels[:, 2] - labels[:, 4] / 2) * h,
                        labels[:, 3] * w,
                        labels[:, 4] * h,
                    ],
                    1,
                )
                if len(labels)
                else np.zeros((0, 4))
            )
            # every label is a visible ground-truth box of the same class; tiny slivers may lack a label
            assert len(labels) <= len(visible)
            for label, box in zip(labels, boxes, strict=True):
                match = np.all(np.abs(visible[:, 2:6] - box) < 0.01, axis=1) & (visible[:, 7] == label[0])
                assert match.any(), f"{seq['name']} frame {frame}: label {label} has no matching gt row"
                compared += 1
            assert np.all(visible[:, 2] >= 0) and np.all(visible[:, 2] + visible[:, 4] <= w)
    assert compared > 500


def test_hidden_rows_have_zero_visibility_and_no_label(smoke_dataset):
    manifest = load_manifest(smoke_dataset)
    seq = next(s for s in manifest["sequences"] if s["scenario"] == "occlusion")
    rows = read_mot(smoke_dataset / seq["name"] / "gt" / "gt.txt")
    hidden = rows[rows[:, 8] == 0]
    assert len(hidden) >= 10
    assert np.all(hidden[:, 6] == 0)  # conf 0: evaluation ignores a target nobody can see
    assert np.all(rows[rows[:, 8] > 0, 6] == 1)


def test_masks_cover_only_moving_targets(smoke_dataset):
    manifest = load_manifest(smoke_dataset)
    for seq in manifest["sequences"]:
        d = smoke_dataset / seq["name"]
        rows = read_mot(d / "gt" / "gt.txt")
        for frame in (1, 24, 48):
            mask = cv2.imread(str(d / "masks" / f"{frame:06d}.png"), cv2.IMREAD_UNCHANGED)
            assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
            inside = np.zeros_like(mask, dtype=bool)
            for _, _, x, y, bw, bh, *_ in rows[rows[:, 0] == frame]:
                inside[int(y) : int(y + bh), int(x) : int(x + bw)] = True
            assert not (mask.astype(bool) & ~inside).any(), (
                f"{seq['name']} frame {frame}: mask outside targets"
            )


def test_folds_are_disjoint_cover_everything_and_spread_scenarios(smoke_dataset):
    manifest = load_manifest(smoke_dataset)
    names = {s["name"] for s in manifest["sequences"]}
    seen = set()
    for fold in range(manifest["num_folds"]):
        train, val = split_sequences(manifest, fold)
        assert val and not set(train) & set(val)
        assert set(train) | set(val) == names
        assert not seen & set(val)
        seen |= set(val)
    assert seen == names
    with pytest.raises(ValueError, match="fold 9"):
        split_sequences(manifest, 9)


def test_same_seed_same_bytes_whatever_the_workers_other_seed_differs(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for root in (a, b, c):
        root.mkdir()
    build_data.run(_tiny(a))
    build_data.run(_tiny(b, "workers=2"))
    build_data.run(_tiny(c, "seed=1"))
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files_a == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for rel in files_a:
        if rel.name != "manifest.json":  # the manifest records the (different) data_root
            assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    hash_of = lambda root: json.loads((root / "space_smoke" / "manifest.json").read_text())["content_hash"]  # noqa: E731
    assert hash_of(a) == hash_of(b) != hash_of(c)


def test_seen_truth_labels_the_same_images_and_says_so(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for root in (a, b):
        root.mkdir()
    assert _tiny(a).data.truth == "seen"  # the default
    build_data.run(_tiny(a, "data.scenario.nominal.sun_phase_deg=[100,120]", "data.truth=silhouette"))
    build_data.run(_tiny(b, "data.scenario.nominal.sun_phase_deg=[100,120]"))
    a, b = a / "space_smoke", b / "space_smoke"
    images = sorted(p.relative_to(a) for p in a.rglob("img/*"))
    assert images and all((a / rel).read_bytes() == (b / rel).read_bytes() for rel in images)
    assert "whole silhouette" in (a / "CARD.md").read_text()
    assert "pixels the camera shows" in (b / "CARD.md").read_text()
    assert json.loads((b / "manifest.json").read_text())["config"]["data"]["truth"] == "seen"
    assert (rendered_truth(load_manifest(a)), rendered_truth(load_manifest(b))) == ("silhouette", "seen")
    assert rendered_truth({"config": {"data": {"name": "older"}}}) == "silhouette"  # rendered before the key
    assert rendered_truth({"name": "hand_made"}) is None  # not rendered here: nothing to check
    shrunk = 0
    for seq in load_manifest(a)["sequences"]:
        outline, seen = (read_mot(root / seq["name"] / "gt" / "gt.txt") for root in (a, b))
        np.testing.assert_array_equal(outline[:, :2], seen[:, :2])
        inside = (seen[:, 2] >= outline[:, 2]) & (seen[:, 3] >= outline[:, 3])
        inside &= seen[:, 2] + seen[:, 4] <= outline[:, 2] + outline[:, 4]
        inside &= seen[:, 3] + seen[:, 5] <= outline[:, 3] + outline[:, 5]
        shown = seen[:, 6] > 0
        assert inside[shown].all()  # a seen box lies within its silhouette box
        shrunk += int((seen[shown, 4] * seen[shown, 5] < outline[shown, 4] * outline[shown, 5]).sum())
    assert shrunk > 0  # side- and back-lit targets lose their night side


@pytest.mark.parametrize("name", sorted(p.stem for p in (REPO_ROOT / "conf" / "data").glob("*.yaml")))
def test_every_dataset_config_passes_the_checks_a_render_makes_first(tmp_path, name):
    cfg = compose_config("build_data", [f"data={name}", f"data_root={tmp_path}"])
    build_data.check_config(cfg)  # every key a render reads is there and valid
    assert cfg.data.truth in ("seen", "silhouette")


def test_bad_input_is_refused_before_any_work(tmp_path):
    with pytest.raises(MissingConfigException):
        compose_config("build_data", ["data/scenario=[nominal,moonbase]"])
    with pytest.raises(ValueError, match="data.width x data.height = 10x120"):
        build_data.run(_tiny(tmp_path, "data.width=10"))
    with pytest.raises(FileNotFoundError, match="does not exist"):
        build_data.run(_tiny(tmp_path / "missing"))
    with pytest.raises(ValueError, match="unknown key"):
        build_data.run(_tiny(tmp_path, "+data.scenario.nominal.brightness=2"))
    with pytest.raises(ValueError, match="num_sequences=1"):
        build_data.run(_tiny(tmp_path, "data.num_sequences=1"))


def test_existing_dataset_is_kept_and_a_failed_build_leaves_nothing(tmp_path, monkeypatch):
    build_data.run(_tiny(tmp_path))
    target = tmp_path / "space_smoke"
    before = json.loads((target / "manifest.json").read_text())["content_hash"]
    with pytest.raises(FileExistsError, match="overwrite=true"):
        build_data.run(_tiny(tmp_path))

    calls = {"n": 0}
    real = build_data.render_one

    def failing(*args):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("disk full")
        return real(*args)

    monkeypatch.setattr(build_data, "render_one", failing)
    with pytest.raises(RuntimeError, match="disk full"):
        build_data.run(_tiny(tmp_path, "overwrite=true", "seed=4"))
    assert json.loads((target / "manifest.json").read_text())["content_hash"] == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["space_smoke"]  # no temporary folder left

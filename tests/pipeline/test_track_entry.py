"""The whole pipeline through `spacetrack.track.run` on rendered smoke sequences, with the dataset's own
boxes standing in for the detector: outputs, the motion filter, the cache, and the errors a user meets."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from pipeline_helpers import track_config

from spacetrack import track
from spacetrack.pipeline import build as build_module
from spacetrack.pipeline.cache import CacheMismatchError
from spacetrack.pipeline.weights import MissingWeightsError
from spacetrack.tracking.io import load_detections

STATIC_SEQ = "seq_005_static_distractors"
# ground-truth boxes through SORT on the sequence with parked objects, no clip
GT_SORT_STATIC = [
    "detector=ground_truth",
    "reid.weights=none",
    "tracker=sort",
    f"sequence={STATIC_SEQ}",
    "video=false",
]


def _static_overlap(mot_path, static_path) -> int:
    """Tracker rows whose box overlaps a static object's box in the same frame."""
    rows = np.loadtxt(mot_path, delimiter=",", ndmin=2)
    static = np.loadtxt(static_path, delimiter=",", ndmin=2)
    hits = 0
    for f, _, x, y, w, h, *_ in rows:
        for _, _, sx, sy, sw, sh, *_ in static[static[:, 0] == f]:
            hits += int(x < sx + sw and sx < x + w and y < sy + sh and sy < y + h)
    return hits


@pytest.mark.slow
def test_pipeline_writes_results_video_metrics_and_cache(smoke_dataset, random_reid, tmp_path):
    cfg = track_config(
        smoke_dataset, tmp_path, "detector=ground_truth", f"reid.weights={random_reid}",
        "tracker=deepsort_original", "tracker.max_cosine_distance=1.0", f"sequence={STATIC_SEQ}",
        "max_frames=16",
    )  # fmt: skip
    metrics = track.run(cfg)
    out = tmp_path / "out"
    rows = np.loadtxt(out / f"{STATIC_SEQ}.txt", delimiter=",", ndmin=2)
    assert rows.shape[1] == 10 and set(rows[:, 6]) == {1} and set(rows[:, 7:].ravel()) == {-1}
    assert rows[:, 0].max() <= 16 and (out / f"{STATIC_SEQ}.mp4").stat().st_size > 0
    assert json.loads((out / "metrics.json").read_text())["mota"] == metrics["mota"]
    assert metrics["mota"] > 0.5 and metrics["num_frames"] == 16 and metrics["cached_sequences"] == 0
    assert {"detector_ms", "reid_ms", "motion_ms", "tracker_ms"} <= set(metrics)
    # The filter keeps the parked satellite away from the tracker.
    assert _static_overlap(out / f"{STATIC_SEQ}.txt", smoke_dataset / STATIC_SEQ / "gt" / "static.txt") == 0
    # The cache holds detection rows (docs/contracts.md), 128-dim features, readable by track_detections.
    cache_dir = next((tmp_path / "cache").iterdir())
    dets = load_detections(cache_dir / f"{STATIC_SEQ}.npy")
    assert dets.shape[1] == 10 + 128
    assert np.allclose(np.linalg.norm(dets[:, 10:], axis=1), 1.0, atol=1e-4)


@pytest.mark.slow
def test_cache_serves_retracking_without_networks_and_filter_switch(smoke_dataset, tmp_path, monkeypatch):
    common = GT_SORT_STATIC
    first = track.run(track_config(smoke_dataset, tmp_path, *common))

    def no_networks(*args, **kwargs):
        raise AssertionError("a cached sequence must not build the detection stream")

    monkeypatch.setattr(track, "build_stream", no_networks)
    again = track.run(track_config(smoke_dataset, tmp_path, *common))
    assert again["cached_sequences"] == 1 and again["mota"] == first["mota"]
    unfiltered = track.run(track_config(smoke_dataset, tmp_path, *common, "dynamic_filter=false"))
    assert unfiltered["fp"] > first["fp"]
    overlap = _static_overlap(
        tmp_path / "out" / f"{STATIC_SEQ}.txt", smoke_dataset / STATIC_SEQ / "gt" / "static.txt"
    )
    assert overlap > 10  # without the filter the parked satellite becomes a track


@pytest.mark.slow
def test_stale_cache_is_refused_or_rebuilt(smoke_dataset, tmp_path):
    common = ["detector=ground_truth", "reid.weights=none", "tracker=sort", f"sequence={STATIC_SEQ}"]
    common += ["video=false", "max_frames=8"]
    track.run(track_config(smoke_dataset, tmp_path, *common))
    meta = next((tmp_path / "cache").glob(f"*/{STATIC_SEQ}.json"))
    before = meta.read_text()
    changed = [*common, "detector.score=0.9"]
    with pytest.raises(
        CacheMismatchError, match=r"detector: cached '[^']+', configured '[^']+'.*cache.rebuild=true"
    ):
        track.run(track_config(smoke_dataset, tmp_path, *changed, "cache.rebuild=false"))
    assert meta.read_text() == before
    rebuilt = track.run(track_config(smoke_dataset, tmp_path, *changed))
    assert rebuilt["cached_sequences"] == 0 and meta.read_text() != before
    assert track.run(track_config(smoke_dataset, tmp_path, *changed))["cached_sequences"] == 1


@pytest.mark.slow
def test_the_cache_follows_the_frames_and_the_truth_files_not_the_folder_name(smoke_dataset, tmp_path):
    """A dataset rendered again under the same name (other truth, other frames) is tracked afresh."""
    dataset = tmp_path / "copy" / smoke_dataset.name
    shutil.copytree(smoke_dataset / STATIC_SEQ, dataset / STATIC_SEQ)
    shutil.copy(smoke_dataset / "manifest.json", dataset / "manifest.json")
    common = ["detector=ground_truth", "reid.weights=none", "tracker=sort", f"sequence={STATIC_SEQ}"]
    common += ["video=false", "max_frames=16", "dynamic_filter=false"]
    first = track.run(track_config(dataset, tmp_path, *common))
    assert first["cached_sequences"] == 0
    tracked_rows = len(np.loadtxt(tmp_path / "out" / f"{STATIC_SEQ}.txt", delimiter=",", ndmin=2))
    assert track.run(track_config(dataset, tmp_path, *common))["cached_sequences"] == 1
    # other truth boxes: the ground-truth detector's detections are the new rows, not the cached ones
    gt_file = dataset / STATIC_SEQ / "gt" / "gt.txt"
    gt = np.loadtxt(gt_file, delimiter=",", ndmin=2)
    np.savetxt(gt_file, gt[gt[:, 1] != gt[0, 1]], delimiter=",", fmt="%g")  # one target gone
    fewer = track.run(track_config(dataset, tmp_path, *common))
    assert fewer["cached_sequences"] == 0
    assert len(np.loadtxt(tmp_path / "out" / f"{STATIC_SEQ}.txt", delimiter=",", ndmin=2)) < tracked_rows
    fresh = track.run(track_config(dataset, tmp_path / "fresh", *common, "cache.enabled=false"))
    for k in ("mota", "fp", "fn", "idsw"):
        assert fewer[k] == fresh[k], k
    # other frames, same names
    frame = dataset / STATIC_SEQ / "img" / "000003.jpg"
    frame.write_bytes(frame.read_bytes() + b"\0")
    assert track.run(track_config(dataset, tmp_path, *common))["cached_sequences"] == 0
    assert track.run(track_config(dataset, tmp_path, *common))["cached_sequences"] == 1


def _no_networks(*args, **kwargs):
    raise AssertionError("cached detections must not build the detection stream")


@pytest.mark.slow
def test_new_motion_settings_rerun_the_motion_stage_only(smoke_dataset, tmp_path, monkeypatch):
    common = ["detector=ground_truth", "reid.weights=none", "tracker=sort", f"sequence={STATIC_SEQ}"]
    common += ["max_frames=40"]
    default = track.run(track_config(smoke_dataset, tmp_path, *common, "video=false"))
    folder = next((tmp_path / "cache").iterdir())
    detections_meta = folder / f"{STATIC_SEQ}.json"
    detections_before = detections_meta.read_text()
    (first_blobs,) = folder.glob(f"{STATIC_SEQ}.blobs-*.json")
    changed = [*common, "motion.min_area=400"]  # drops the small blobs: fewer moving boxes
    fresh = track.run(
        track_config(smoke_dataset, tmp_path / "fresh", *changed, "cache.enabled=false", "video=false")
    )
    assert fresh["fn"] > default["fn"]  # the setting matters
    monkeypatch.setattr(track, "build_stream", _no_networks)
    rerun = track.run(
        track_config(smoke_dataset, tmp_path, *changed, "video=true")
    )  # one pass over the frames
    assert rerun["cached_sequences"] == 1 and detections_meta.read_text() == detections_before
    assert (tmp_path / "out" / f"{STATIC_SEQ}.mp4").stat().st_size > 0
    assert len(list(folder.glob(f"{STATIC_SEQ}.blobs-*.json"))) == 2 and first_blobs.is_file()
    # the same tracks as the whole pipeline run afresh with those settings
    for k in ("mota", "fp", "fn", "idsw"):
        assert rerun[k] == fresh[k], k
    monkeypatch.setattr(track, "build_motion_stream", _no_networks)  # both settings' blobs are cached now
    assert track.run(track_config(smoke_dataset, tmp_path, *changed, "video=false"))["mota"] == fresh["mota"]
    assert track.run(track_config(smoke_dataset, tmp_path, *common, "video=false"))["mota"] == default["mota"]
    # blobs that do not belong to the source are refused, or made again
    first_blobs.write_text(first_blobs.read_text().replace("(40 frames)", "(41 frames)"))
    with pytest.raises(CacheMismatchError, match=r"blobs-\w+\.json is stale: source: cached"):
        track.run(track_config(smoke_dataset, tmp_path, *common, "cache.rebuild=false", "video=false"))


@pytest.mark.slow
def test_new_dynamic_thresholds_retrack_from_the_cache(smoke_dataset, tmp_path, monkeypatch):
    common = ["detector=ground_truth", "reid.weights=none", "tracker=sort", f"sequence={STATIC_SEQ}"]
    common += ["video=false", "max_frames=40"]
    default = track.run(track_config(smoke_dataset, tmp_path, *common))
    strict = [*common, "dynamic.min_overlap=1.0", "dynamic.min_coverage=1.0", "dynamic.max_distance=0"]
    fresh = track.run(track_config(smoke_dataset, tmp_path / "fresh", *strict, "cache.enabled=false"))
    assert fresh["fn"] > default["fn"]  # the thresholds matter: fewer boxes count as moving
    monkeypatch.setattr(track, "build_stream", _no_networks)
    monkeypatch.setattr(track, "build_motion_stream", _no_networks)
    cached = track.run(track_config(smoke_dataset, tmp_path, *strict))
    assert cached["cached_sequences"] == 1
    for k in ("mota", "fp", "fn", "idsw"):
        assert cached[k] == fresh[k], k


def test_fold_without_trained_model_names_the_command(smoke_dataset, tmp_path):
    cfg = track_config(smoke_dataset, tmp_path, "fold=4", f"logger.tracking_uri=sqlite:///{tmp_path}/m.db")
    with pytest.raises(MissingWeightsError, match="make train FOLD=4") as err:
        build_module.resolve_weights(cfg)
    assert err.value.train == ("spacetrack.train", ["fold=4"])
    gam = ["detector_run.gam_position=after_sppf", "enhance=dwt_hsv"]
    cfg = track_config(
        smoke_dataset, tmp_path, "fold=4", *gam, f"logger.tracking_uri=sqlite:///{tmp_path}/m.db"
    )
    with pytest.raises(
        MissingWeightsError, match='make train FOLD=4 ARGS="model=yolov5s_gam enhance=dwt_hsv"'
    ) as err:
        build_module.resolve_weights(cfg)
    assert err.value.train == ("spacetrack.train", ["fold=4", "model=yolov5s_gam", "enhance=dwt_hsv"])
    for extra, args in (
        ([], ["model=yolov5s_p2"]),
        (gam, ["model=yolov5s_gam", "enhance=dwt_hsv", "model.p2=true"]),
    ):
        cfg = track_config(
            smoke_dataset,
            tmp_path,
            "fold=4",
            *extra,
            "detector_run.p2=true",
            f"logger.tracking_uri=sqlite:///{tmp_path}/m.db",
        )
        with pytest.raises(MissingWeightsError, match="head_levels=4") as err:
            build_module.resolve_weights(cfg)
        assert err.value.train == ("spacetrack.train", ["fold=4", *args])
    cfg = track_config(
        smoke_dataset,
        tmp_path,
        "fold=4",
        "detector=ground_truth",
        f"logger.tracking_uri=sqlite:///{tmp_path}/m.db",
    )
    with pytest.raises(MissingWeightsError, match="make train-reid FOLD=4"):
        build_module.resolve_weights(cfg)


def test_appearance_tracker_without_reid_and_nothing_to_track_are_errors(smoke_dataset, tmp_path):
    cfg = track_config(
        smoke_dataset, tmp_path, "detector=ground_truth", "reid.weights=none", f"sequence={STATIC_SEQ}"
    )
    with pytest.raises(ValueError, match="tracker=sort"):
        track.run(cfg)
    with pytest.raises(ValueError, match="fold=K, sequence=NAME|all or source="):
        track.run(track_config(smoke_dataset, tmp_path, "detector=ground_truth", "reid.weights=none"))
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_sequence_all_tracks_the_whole_dataset_and_the_hold_never_tracks_parked_objects(
    smoke_dataset, tmp_path
):
    common = ["detector=ground_truth", "reid.weights=none", "tracker=sort", "sequence=all", "video=false"]
    names = sorted(p.parent.parent.name for p in smoke_dataset.glob("seq_*/gt/gt.txt"))
    paper = track.run(track_config(smoke_dataset, tmp_path / "paper", *common, "dynamic_hold.frames=0"))
    held = track.run(track_config(smoke_dataset, tmp_path / "held", *common))
    assert sorted(p.stem for p in (tmp_path / "held" / "out").glob("seq_*.txt")) == names
    assert held["fn"] <= paper["fn"]
    for run_dir in ("paper", "held"):
        overlap = _static_overlap(
            tmp_path / run_dir / "out" / f"{STATIC_SEQ}.txt", smoke_dataset / STATIC_SEQ / "gt" / "static.txt"
        )
        assert overlap <= 2, run_dir


@pytest.mark.slow
@pytest.mark.parametrize("use_filter", ["true", "false"])
def test_the_video_draws_apart_exactly_the_static_boxes(smoke_dataset, tmp_path, monkeypatch, use_filter):
    from spacetrack.pipeline import runner

    drawn, real_call = [], runner.Annotator.__call__

    def spy(self, rgb, tracks, static_tlwh, info="", **kwargs):
        drawn.append(np.asarray(static_tlwh))
        return real_call(self, rgb, tracks, static_tlwh, info, **kwargs)

    monkeypatch.setattr(runner.Annotator, "__call__", spy)
    common = ["detector=ground_truth", "reid.weights=none", "tracker=sort", f"sequence={STATIC_SEQ}"]
    track.run(track_config(smoke_dataset, tmp_path, *common, "video=true", f"dynamic_filter={use_filter}"))
    static = np.loadtxt(smoke_dataset / STATIC_SEQ / "gt" / "static.txt", delimiter=",", ndmin=2)
    assert len(drawn) > 0 and sum(len(d) for d in drawn) > 0
    for frame, boxes in enumerate(drawn, start=1):
        assert boxes.ndim == 2 and boxes.shape[1] == 4
        parked = static[static[:, 0] == frame, 2:6]
        for box in boxes:  # every box drawn as static is a parked object of that frame
            assert np.abs(parked - box).max(axis=1).min() < 1e-6, (frame, box)


def test_offline_post_processing_only_adds_rows_and_closes_the_confirmation_gap(smoke_dataset, tmp_path):
    common = ["detector=ground_truth", "reid.weights=none", "tracker=sort", "tracker.n_init=5",
              "sequence=all", "video=false"]  # fmt: skip
    online = track.run(track_config(smoke_dataset, tmp_path / "on", *common))
    offline = track.run(track_config(smoke_dataset, tmp_path / "off", *common, "offline.enabled=true"))
    for mot in sorted((tmp_path / "on" / "out").glob("*.txt")):
        before = {tuple(r[:2]) for r in np.loadtxt(mot, delimiter=",", ndmin=2)}
        after = {
            tuple(r[:2]) for r in np.loadtxt(tmp_path / "off" / "out" / mot.name, delimiter=",", ndmin=2)
        }
        assert before <= after, mot.name  # every online (frame, id) stays
    # the first n_init - 1 frames of each track come back: fewer misses, no more false positives
    assert offline["fn"] < online["fn"] and offline["fp"] <= online["fp"]
    assert offline["mota"] > online["mota"]


def test_each_track_is_named_by_its_class_vote_and_scored_on_it(smoke_dataset, tmp_path):
    common = GT_SORT_STATIC
    metrics = track.run(track_config(smoke_dataset, tmp_path / "on", *common))
    out = tmp_path / "on" / "out"
    ids = set(np.loadtxt(out / f"{STATIC_SEQ}.txt", delimiter=",", ndmin=2)[:, 1].astype(int))
    named = json.loads((out / f"{STATIC_SEQ}.classes.json").read_text())["tracks"]
    assert ids <= {int(k) for k in named}  # every output track has its class (static ones too)
    assert {v["name"] for v in named.values()} <= {"satellite", "rocket_body", "debris"}
    assert all(v["share"] == 1.0 for v in named.values())  # ground-truth boxes never change their name
    # ground-truth boxes carry the true classes: every matched box named right, by frame and by vote
    assert (
        metrics["class_accuracy"] == metrics["class_accuracy_frame"] == 1.0 and metrics["class_matches"] > 0
    )
    offline = track.run(track_config(smoke_dataset, tmp_path / "off", *common, "offline.enabled=true"))
    assert "class_accuracy" not in offline  # interpolated boxes were named by no detection
    assert (tmp_path / "off" / "out" / f"{STATIC_SEQ}.classes.json").is_file()

"""Pretraining: its dataset must share no sequence with the cross-validation data; its config is the
training one on the pretraining set."""

from __future__ import annotations

import json

import pytest

from spacetrack.config import compose_config
from spacetrack.pretrain import check_disjoint, check_rendered


def manifest(root, seeds, content_hash):
    root.mkdir()
    sequences = [
        {"name": f"seq_{i:03d}_nominal", "seed": seed, "fold": i % 2} for i, seed in enumerate(seeds)
    ]
    (root / "manifest.json").write_text(
        json.dumps({"format_version": 1, "sequences": sequences, "content_hash": content_hash})
    )
    return root


def test_a_pretraining_set_rendered_from_the_folds_seeds_is_refused(tmp_path):
    cv = manifest(tmp_path / "space_default", [[0, 0], [0, 1], [0, 2]], "sha256:cv")
    same = manifest(tmp_path / "same_seed", [[0, 2], [0, 3]], "sha256:other")
    with pytest.raises(ValueError, match="shares 1 sequences .*seq_000_nominal.*seed=1000"):
        check_disjoint(same, cv)
    with pytest.raises(ValueError, match="is the cross-validation dataset itself"):
        check_disjoint(cv, cv)
    apart = manifest(tmp_path / "space_pretrain", [[1000, 0], [1000, 1]], "sha256:pre")
    check_disjoint(apart, cv)  # no error: disjoint seeds
    check_disjoint(apart, tmp_path / "not_built")  # nothing to compare with yet


def test_a_pretraining_set_of_another_size_than_its_config_is_refused(tmp_path):
    older = manifest(tmp_path / "space_pretrain", [[1000, i] for i in range(42)], "sha256:pre")
    check_rendered(older, 42)  # as configured: no error
    with pytest.raises(ValueError, match="space_pretrain holds 42 sequences.*asks for 84.*overwrite=true"):
        check_rendered(older, 84)


def test_pretrain_config_trains_on_the_pretraining_set_from_scratch():
    cfg = compose_config("pretrain", ["model=yolov5s_gam"])
    assert cfg.data.name == "space_pretrain" and cfg.weights == "none" and cfg.resume == "auto"
    assert cfg.train.input == "crops" and cfg.train.frame_stride == 2
    assert cfg.logger.experiment == "pretrain" and cfg.model.gam_position == "after_sppf"
    assert "slew" in cfg.data.scenario
    assert cfg.data.truth == "silhouette"  # what the shipped pretrained files learnt from


def windows(cfg) -> int:
    """Windows in a pretraining epoch: training sequences (all folds but one) x frames the stride reads."""
    training = cfg.data.num_sequences * (cfg.data.num_folds - 1) // cfg.data.num_folds
    return training * -(-cfg.data.num_frames // cfg.train.frame_stride)


def test_second_stage_renders_the_first_stages_scenes_and_more_and_keeps_an_epochs_size():
    first = compose_config("pretrain")
    second = compose_config("pretrain", ["data=pretrain_252", "train=pretrain_252"])
    assert (
        second.data.name == "space_pretrain_252" and second.data.num_sequences == 3 * first.data.num_sequences
    )
    # the same scenes but for their count: with the same seed its first 84 sequences are the first stage's
    differs = {k for k in first.data if first.data[k] != second.data[k]}
    assert differs == {"name", "num_sequences"}

    # an epoch holds as many windows as the first stage's
    assert windows(first) == windows(second) == 5400
    assert second.train.trainer.epochs == 12 and second.weights == "none"  # make pretrain passes the start
    assert second.train.image_size == first.train.image_size and second.train.input == "crops"


def test_fourth_stage_reads_every_rendered_scene_in_short_sequences():
    third = compose_config("pretrain", ["data=pretrain_756", "train=pretrain_756"])
    fourth = compose_config("pretrain", ["data=pretrain_2016", "train=pretrain_2016"])
    # the same scenarios, truth and camera; only the count, length and folds of the sequences differ
    differs = {k for k in third.data if third.data[k] != fourth.data[k]}
    assert differs == {"name", "num_sequences", "num_frames", "num_folds"}
    # long enough for the occlusion scenario's hidden run, which the builder refuses below 40 frames
    assert fourth.data.num_frames >= 40
    # the folds are of one size: 72 held-out sequences monitor it, the rest train
    held_out = fourth.data.num_sequences // fourth.data.num_folds
    assert fourth.data.num_sequences % fourth.data.num_folds == 0 and held_out == 72
    # the frame store keeps every gcd(stride, val stride)-th frame: the validation frames are training ones
    assert fourth.train.val_frame_stride % fourth.train.frame_stride == 0
    assert windows(fourth) == 13608
    assert fourth.train.trainer.epochs == 8 and fourth.train.trainer.lr0 == third.train.trainer.lr0


def test_side_lit_set_adds_dim_side_lit_targets_to_the_pretraining_scenarios():
    from spacetrack.data.scenario import scenario_params

    first = compose_config("pretrain")
    side = compose_config("pretrain", ["data=pretrain_side_lit"])
    # the seven pretraining scenarios and one more, eight sequences each, labelled as the folds are
    assert list(side.data.scenario) == [*first.data.scenario, "dim_side_lit"]
    assert side.data.num_sequences == 8 * len(side.data.scenario)
    assert side.data.num_sequences % side.data.num_folds == 0
    assert side.data.truth == compose_config("train").data.truth == "seen"
    # dim's sensor and exposure, the sun at the side and rocket bodies twice as likely
    dim = scenario_params("dim", side.data.scenario.dim)
    lit = scenario_params("dim_side_lit", side.data.scenario.dim_side_lit)
    differs = {k for k in vars(dim) if getattr(dim, k) != getattr(lit, k)}
    assert differs == {"sun_phase_deg", "class_weights"}
    assert lit.sun_phase_deg[0] > dim.sun_phase_deg[0] and lit.sun_phase_deg[1] > dim.sun_phase_deg[1]
    assert lit.class_weights[1] == 2 * lit.class_weights[0] == 2 * lit.class_weights[2]

import json
import os

import mlflow
import pytest
from hydra.utils import instantiate
from omegaconf import OmegaConf, open_dict

from spacetrack.config import compose_config
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.engine import trainer as trainer_module
from spacetrack.engine import training as training_module
from spacetrack.engine.cross_validation import PARENT_ENV, CrossValidationCallback
from spacetrack.engine.training import build_datasets
from spacetrack.train import run


def config(tiny_dataset, tmp_path, *overrides):
    cfg = compose_config(
        "train",
        [
            "train=smoke",
            "logger=none",
            f"data_root={tiny_dataset.parent}",
            f"data.name={tiny_dataset.name}",
            f"output_dir={tmp_path / 'run'}",
            "train.frame_stride=4",
            *overrides,
        ],
    )
    with open_dict(cfg):
        cfg.cv_parent_run_id = None  # not resolvable outside a Hydra job, and not wanted here
    return cfg


def test_one_fold_trains_from_the_real_config(tiny_dataset, tmp_path):
    result = run(config(tiny_dataset, tmp_path, "fold=3", "model=yolov5s_gam_light"))
    assert set(result) == {"map50", "map50_95", "precision", "recall", "recall_at_score", "fitness"}
    assert (tmp_path / "run" / "weights" / "best.pt").is_file()
    assert (tmp_path / "run" / "plots" / "pr_curve.png").is_file()
    assert (tmp_path / "run" / "plots" / "val_predictions.png").is_file()
    assert (tmp_path / "run" / "plots" / "confusion_matrix.png").is_file()
    # Resuming the finished run from its last checkpoint goes to the same folder and changes nothing.
    last = tmp_path / "run" / "weights" / "last.pt"
    again = run(
        config(tiny_dataset, tmp_path / "elsewhere", "fold=3", "model=yolov5s_gam_light", f"resume={last}")
    )
    assert again == result
    with pytest.raises(ValueError, match="crops: checkpoint .*'jitter': 0.8.*configured .*'jitter': 0.5"):
        run(
            config(
                tiny_dataset,
                tmp_path,
                "fold=3",
                "model=yolov5s_gam_light",
                f"resume={last}",
                "train.crops.jitter=0.5",
            )
        )


def test_a_resumed_training_continues_its_mlflow_run(tiny_dataset, tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    logged = ("logger=mlflow", f"logger.tracking_uri={uri}", "model.width_multiple=0.125", "fold=3")
    run(config(tiny_dataset, tmp_path, *logged))
    client = mlflow.MlflowClient(uri)
    (first,) = client.search_runs([client.get_experiment_by_name("detector").experiment_id])
    client.set_terminated(first.info.run_id, "KILLED")  # as if the job had been stopped
    run(config(tiny_dataset, tmp_path, *logged, f"resume={tmp_path / 'run' / 'weights' / 'last.pt'}"))
    (again,) = client.search_runs([first.info.experiment_id])
    assert again.info.run_id == first.info.run_id
    assert again.info.status == "FINISHED"
    assert again.data.tags["resumes"] == "1"
    assert again.data.tags["data_content"] == "sha256:0"  # the manifest's content_hash
    assert again.data.metrics["planned_epochs"] == 1  # the smoke profile's one epoch fits its time budget


def test_a_dataset_rendered_again_under_its_name_is_not_resumed(tiny_dataset, tmp_path):
    """Same name, other content (labels made by other code, another seed): another training."""
    common = ("fold=3", "model.width_multiple=0.125")
    run(config(tiny_dataset, tmp_path, *common))
    manifest = tiny_dataset / "manifest.json"
    manifest.write_text(manifest.read_text().replace('"sha256:0"', '"sha256:1"'))
    last = tmp_path / "run" / "weights" / "last.pt"
    with pytest.raises(ValueError, match=r"data_content.*sha256:0.*sha256:1"):
        run(config(tiny_dataset, tmp_path / "again", *common, f"resume={last}"))


def test_resume_auto_finds_the_unfinished_run_of_the_same_settings(
    tiny_dataset, tmp_path, monkeypatch, capsys
):
    common = ("fold=3", "model.width_multiple=0.125", "train.trainer.epochs=2", f"resume_dirs=[{tmp_path}]")
    unbroken = run(config(tiny_dataset, tmp_path / "unbroken", *common))
    real_evaluate, calls = trainer_module.evaluate, []

    def stop_in_the_second_epoch(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_evaluate(*args, **kwargs)

    monkeypatch.setattr(trainer_module, "evaluate", stop_in_the_second_epoch)
    with pytest.raises(KeyboardInterrupt):
        run(config(tiny_dataset, tmp_path / "stopped", *common))
    calls.clear()
    with pytest.raises(KeyboardInterrupt):  # a newer unfinished run, of other crop settings
        run(config(tiny_dataset, tmp_path / "other", *common, "train.crops.jitter=0.5"))
    monkeypatch.setattr(trainer_module, "evaluate", real_evaluate)
    stopped = tmp_path / "stopped" / "run" / "weights" / "last.pt"
    capsys.readouterr()
    again = run(config(tiny_dataset, tmp_path / "fresh", *common, "resume=auto"))
    assert f"resuming {stopped}" in capsys.readouterr().out
    assert again == unbroken
    assert not (tmp_path / "fresh" / "run").exists()  # the stopped run's folder was reused
    # Now nothing of these settings is left unfinished: a new run starts in its own folder.
    run(config(tiny_dataset, tmp_path / "new", *common, "resume=auto"))
    assert "nothing to resume, starting afresh" in capsys.readouterr().out
    assert (tmp_path / "new" / "run" / "weights" / "last.pt").is_file()


@pytest.mark.parametrize("fold", [-1, 9])
def test_fold_outside_the_nine_is_refused(tiny_dataset, tmp_path, fold):
    with pytest.raises(ValueError, match=f"fold {fold} is outside 0..8"):
        run(config(tiny_dataset, tmp_path, f"fold={fold}"))


def test_a_dataset_rendered_with_another_truth_is_refused_naming_both(tiny_dataset, tmp_path):
    manifest = tiny_dataset / "manifest.json"
    content = json.loads(manifest.read_text())
    content["config"] = {"data": {"name": tiny_dataset.name}}  # rendered before data.truth: silhouettes
    manifest.write_text(json.dumps(content))
    with pytest.raises(
        ValueError,
        match=r"manifest\.json: rendered with data\.truth=silhouette, the config asks data\.truth=seen",
    ):
        run(config(tiny_dataset, tmp_path, "fold=3"))
    # Asked for the truth it holds, the dataset passes that check and meets the next one.
    with pytest.raises(ValueError, match="fold 9 is outside 0..8"):
        run(config(tiny_dataset, tmp_path, "fold=9", "data.truth=silhouette"))


def test_cross_validation_parent_gets_mean_and_std(tiny_dataset, tmp_path, monkeypatch):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cfg = config(
        tiny_dataset, tmp_path, "logger=mlflow", f"logger.tracking_uri={uri}", "model.width_multiple=0.125"
    )
    monkeypatch.setenv(PARENT_ENV, "")  # restored after the test whatever happens
    callback = CrossValidationCallback(metrics=["best_map50", "best_map50_95"])
    with open_dict(cfg):
        cfg.hydra = {"overrides": {"task": ["fold=0,1"]}}
    callback.on_multirun_start(cfg)
    parent = os.environ[PARENT_ENV]
    for fold in (0, 1):
        with open_dict(cfg):
            cfg.fold = fold
            cfg.cv_parent_run_id = parent
            cfg.output_dir = str(tmp_path / f"fold{fold}")
        run(cfg)
    callback.on_multirun_end(cfg)
    client = mlflow.MlflowClient(uri)
    parent_run = client.get_run(parent)
    assert parent_run.info.status == "FINISHED"
    assert {"best_map50_mean", "best_map50_std", "best_map50_95_mean", "best_map50_95_std"} <= set(
        parent_run.data.metrics
    )
    children = client.search_runs(
        [parent_run.info.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent}'"
    )
    artifacts = {a.path for a in client.list_artifacts(children[0].info.run_id, "plots")}
    assert artifacts == {"plots/pr_curve.png", "plots/confusion_matrix.png", "plots/val_predictions.png"}
    assert sorted(c.data.tags["fold"] for c in children) == ["0", "1"]


def test_training_starts_from_the_shipped_pretrained_weights_of_its_model(
    tiny_dataset, tmp_path, monkeypatch, capsys
):
    import torch

    from spacetrack.engine import pretrained
    from spacetrack.export_weights import _half
    from spacetrack.models.yolo import YOLOv5

    narrow = YOLOv5(num_classes=5, width_multiple=0.125)  # another class count: the head starts afresh
    torch.save({"arch": narrow.arch, "ema": _half(narrow.state_dict())}, tmp_path / "pre.pt")
    monkeypatch.setitem(pretrained.PRETRAINED, None, tmp_path / "pre.pt")
    run(config(tiny_dataset, tmp_path, "fold=3", "model.width_multiple=0.125"))
    out = capsys.readouterr().out
    assert f"from {tmp_path / 'pre.pt'}" in out and "the head was re-initialised" in out
    run(config(tiny_dataset, tmp_path / "scratch", "fold=3", "model.width_multiple=0.125", "weights=none"))
    assert "training from scratch (weights=none)" in capsys.readouterr().out
    with pytest.raises(ValueError, match="another architecture .*gam_position"):
        run(
            config(
                tiny_dataset,
                tmp_path / "gam",
                "fold=3",
                "model=yolov5s_gam_light",
                f"weights={tmp_path / 'pre.pt'}",
            )
        )


def test_training_caches_only_the_frames_its_strides_read(tiny_dataset, tmp_path):
    cfg = config(tiny_dataset, tmp_path, "fold=3", "train.frame_stride=4", "train.val_frame_stride=6")
    train_names, val_names = split_sequences(load_manifest(tiny_dataset), 3)
    train_set, val_set = build_datasets(
        cfg, tiny_dataset, train_names, val_names, 3, instantiate(cfg.enhance)
    )
    assert train_set.store is val_set.store
    assert train_set.store.frame_stride == 2 and train_set.store.folder.name.endswith("-every2")
    assert {frame for _, frame, _, _ in train_set.samples} <= set(range(0, 1000, 4))
    # the store holds every other frame: just what the two strides read
    seq = train_names[0]
    assert len(train_set.store.frames(seq)) == len(
        range(0, len(list((tiny_dataset / seq / "img").iterdir())), 2)
    )


@pytest.mark.parametrize("enhance", ["none", "dwt_hsv"])
def test_reexposure_comes_before_an_enhancement(tiny_dataset, tmp_path, enhance):
    cfg = config(tiny_dataset, tmp_path, "fold=3", f"enhance={enhance}", "train.augment.exposure=0.5")
    train_names, val_names = split_sequences(load_manifest(tiny_dataset), 3)
    train_set, val_set = build_datasets(
        cfg, tiny_dataset, train_names, val_names, 3, instantiate(cfg.enhance)
    )
    exposure = train_set.augment.transforms[0]
    assert type(exposure).__name__ == "Exposure"
    if enhance == "none":  # re-exposure commutes with cutting the window: done on the window
        assert train_set.reexposure is None and exposure.p == 0.5
    else:  # the enhancement adapts to the frame: whole unenhanced frames are re-exposed, then enhanced
        assert exposure.p == 0.0 and train_set.reexposure.p == 0.5
        assert train_set.reexposure.raw.folder.name.split("-")[0] == "img"
        assert train_set.reexposure.raw.enhancer is None and train_set.store.enhancer is not None
        assert val_set.reexposure is None
    image, _ = train_set[0]
    assert image.shape[:2] == (cfg.train.image_size, cfg.train.image_size)


def test_a_frozen_backbone_ends_the_fine_tuning_as_the_pretrained_file_has_it(tiny_dataset, tmp_path, capsys):
    import torch

    from spacetrack.export_weights import _half
    from spacetrack.models.yolo import YOLOv5

    torch.manual_seed(1)
    start = YOLOv5(num_classes=3, width_multiple=0.125)
    torch.save({"arch": start.arch, "ema": _half(start.state_dict())}, tmp_path / "pre.pt")
    pre = torch.load(tmp_path / "pre.pt")["ema"]
    common = ("fold=3", "model.width_multiple=0.125", f"weights={tmp_path / 'pre.pt'}")
    run(config(tiny_dataset, tmp_path, *common, "train.freeze=3"))
    assert "stem, stage2, stage3 frozen (train.freeze=3)" in capsys.readouterr().out
    last = torch.load(tmp_path / "run" / "weights" / "last.pt")
    params = [name for name, _ in start.named_parameters()]
    frozen = [n for n in params if n.startswith(("stem.", "stage2.", "stage3."))]
    trained = [n for n in params if n not in frozen]
    for state in (last["model"], last["ema"]):
        bad = [
            (n, (state[n] - pre[n].float()).abs().max().item())
            for n in frozen
            if not torch.equal(state[n], pre[n].float())
        ]
        assert not bad, bad[:4]
        assert sum(not torch.equal(state[n], pre[n].float()) for n in trained) > len(trained) // 2
    # the BatchNorm statistics of the frozen blocks follow the data, as in YOLOv5
    assert not torch.equal(last["model"]["stem.bn.running_mean"], pre["stem.bn.running_mean"].float())
    with pytest.raises(ValueError, match="freeze: checkpoint 3, configured 5"):
        run(
            config(
                tiny_dataset,
                tmp_path,
                *common,
                "train.freeze=5",
                f"resume={tmp_path / 'run/weights/last.pt'}",
            )
        )
    for bad in ("6", "2.5", "true"):
        with pytest.raises(ValueError, match=f"freeze: expected 0-5 backbone stages .*got {bad.title()}"):
            run(config(tiny_dataset, tmp_path / "bad", *common, f"train.freeze={bad}"))
        assert not (tmp_path / "bad").exists()


def test_the_float32_profiles_are_the_cpu_profile_frozen_and_shortened():
    def profile(name):
        overrides = ["logger=none", f"train={name}"]
        return OmegaConf.to_container(compose_config("train", overrides).train)

    default, float32, float32_gam = (profile(n) for n in ("default", "cpu_float32", "cpu_float32_gam"))
    assert (default["freeze"], default["trainer"]["epochs"]) == (0, 16)
    assert (float32["freeze"], float32["trainer"]["epochs"]) == (2, 8)
    assert (float32_gam["freeze"], float32_gam["trainer"]["epochs"]) == (2, 6)
    for each in (default, float32, float32_gam):
        del each["freeze"], each["trainer"]["epochs"]
    assert float32 == default  # nothing else differs: same crops, rates, augmentation
    assert float32_gam == default


def test_a_float32_cpu_on_the_default_profile_is_pointed_to_the_float32_one(monkeypatch):
    import torch

    from spacetrack.engine import precision

    cpu = torch.device("cpu")
    monkeypatch.setattr(precision, "native_bfloat16", lambda: False)
    hint = training_module.float32_hint("default", amp=True, device=cpu)
    assert hint is not None and "train=cpu_float32 fits 30 minutes on a CPU as fast as" in hint
    assert "YOLOv5s fold would take about an hour" in hint
    assert "its time budget (train.trainer.max_minutes) leaves out the epochs that do not fit" in hint
    assert training_module.float32_hint("cpu_float32", amp=True, device=cpu) is None
    unbudgeted = training_module.float32_hint("default", amp=True, device=cpu, budget=False)
    assert "max_minutes" not in unbudgeted and "with train=default; train=cpu_float32 fits" in unbudgeted
    # GAM's attention makes a float32 step slower: cpu_float32 is over the budget too, cpu_float32_gam fits
    for over in ("default", "cpu_float32"):
        hint = training_module.float32_hint(over, amp=True, device=cpu, gam=True)
        assert hint is not None and f"with train={over}, so its time budget" in hint
        assert "train=cpu_float32_gam fits 30 minutes" in hint
    assert training_module.float32_hint("cpu_float32_gam", amp=True, device=cpu, gam=True) is None
    assert training_module.float32_hint("full", amp=True, device=cpu, gam=True) is None
    assert training_module.float32_hint("default", amp=False, device=cpu) is None  # float32 chosen
    assert training_module.float32_hint("default", amp=True, device=torch.device("cuda")) is None
    assert training_module.float32_hint(None, amp=True, device=cpu) is None  # not a Hydra run
    monkeypatch.setattr(precision, "native_bfloat16", lambda: True)
    assert training_module.float32_hint("default", amp=True, device=cpu) is None

"""BoxMOT's trackers behind our step interface: they track, take our features, never build a network."""

import socket
import sys
import types

import numpy as np
import pytest

from spacetrack.config import compose_config
from spacetrack.pipeline.runner import build_tracker
from spacetrack.tracking.dynamic import TrackDynamics
from spacetrack.tracking.peers import BOXMOT_VERSION, PEERS, PeerUnavailableError, load_boxmot


def test_a_missing_boxmot_names_make_peers(monkeypatch):
    monkeypatch.setitem(sys.modules, "boxmot", None)  # import boxmot now raises ImportError
    with pytest.raises(PeerUnavailableError, match="make peers"):
        load_boxmot()


def test_another_boxmot_release_is_refused_with_both_versions(monkeypatch):
    monkeypatch.setitem(sys.modules, "boxmot", types.SimpleNamespace(__version__="99.1.0"))
    with pytest.raises(PeerUnavailableError, match=rf"BoxMOT 99\.1\.0 .* BoxMOT {BOXMOT_VERSION}"):
        load_boxmot()


def test_the_makefile_installs_the_release_the_adapter_expects():
    from spacetrack.config import REPO_ROOT

    assert f"BOXMOT := boxmot=={BOXMOT_VERSION}\n" in (REPO_ROOT / "Makefile").read_text()


@pytest.fixture
def boxmot(monkeypatch):
    """BoxMOT, with its re-ID encoder factory and the network cut off: nothing may be downloaded."""
    module = pytest.importorskip("boxmot", reason="BoxMOT is an optional extra: `make peers` installs it")
    import boxmot.reid.factory

    def refuse(*args, **kwargs):
        raise AssertionError("a peer tried to build its own re-ID network")

    monkeypatch.setattr(boxmot.reid.factory, "create_reid_encoder", refuse)
    monkeypatch.setattr(socket.socket, "connect", refuse)
    return module


def _frames(num_frames: int = 30, seed: int = 0):
    """Two targets crossing a textured sky: (tlwh, confidences, features, image) per frame."""
    rng = np.random.default_rng(seed)
    sky = rng.integers(0, 60, (240, 320, 3), dtype=np.uint8)
    appearance = rng.normal(size=(2, 16))
    appearance /= np.linalg.norm(appearance, axis=1, keepdims=True)
    for f in range(num_frames):
        tlwh = np.array([[20 + 6 * f, 100, 16, 16], [250 - 6 * f, 110, 16, 16]], float)
        image = sky.copy()
        for x, y, w, h in tlwh.astype(int):
            image[y : y + h, x : x + w] = 220
        yield tlwh, np.array([0.9, 0.9]), appearance + 0.01 * rng.normal(size=(2, 16)), image


def _peer(name: str, **overrides):
    cfg = compose_config("track", [f"tracker={name}", "dynamic_filter=false"])
    cfg.tracker.update(overrides)
    return build_tracker(cfg)


@pytest.mark.parametrize("name", PEERS)
def test_each_peer_keeps_two_crossing_targets_apart_on_our_features(boxmot, name):
    tracker = _peer(name)
    assert type(tracker.tracker).__module__.startswith("boxmot.")
    ids_by_target: dict[int, set] = {0: set(), 1: set()}
    for tlwh, conf, feature, image in _frames():
        out = tracker.step(tlwh, conf, feature, image=image if tracker.needs_images else None)
        for track_id, *box in out:
            target = int(np.argmin(np.abs(tlwh[:, 0] - box[0])))
            ids_by_target[target].add(int(track_id))
    assert all(len(ids) == 1 for ids in ids_by_target.values()), ids_by_target
    assert ids_by_target[0] != ids_by_target[1]
    assert min(min(ids) for ids in ids_by_target.values()) >= 1  # MOT ids start at 1
    assert getattr(tracker.tracker, "_reid_encoder", None) is None


def test_an_appearance_peer_without_features_says_what_to_give(boxmot):
    tracker = _peer("strongsort")
    tlwh, conf, _, image = next(_frames())
    with pytest.raises(ValueError, match="no re-ID features.*reid.weights=none"):
        tracker.step(tlwh, conf, np.zeros((2, 0)), image=image)


def test_output_box_detection_gives_the_matched_boxes(boxmot):
    tracker = _peer("bytetrack", output_box="detection")
    for tlwh, conf, feature, _ in _frames(10):
        out = tracker.step(tlwh, conf, feature)
    assert len(out) == 2
    assert {tuple(row[1:]) for row in out} == {tuple(b) for b in tlwh}


def test_dynamics_output_only_the_track_that_moves(boxmot):
    cfg = compose_config("track", ["tracker=bytetrack"])  # dynamic_filter=track: per-track decision
    tracker = build_tracker(cfg)
    assert isinstance(tracker.dynamics, TrackDynamics)
    for f in range(20):
        # a target moving across, no blob on it; a parked object; a blob on neither: only the mover's
        # own motion (far beyond dynamic_track.min_displacement) can make it dynamic
        tlwh = np.array([[20 + 5 * f, 100, 16, 16], [200, 40, 16, 16]], float)
        out = tracker.step(tlwh, np.array([0.9, 0.9]), None, dynamic=np.array([False, False]))
    assert len(out) == 1 and out[0, 1] == pytest.approx(tlwh[0, 0], abs=3)
    static = tracker.static_tracks()
    assert len(static) == 1 and static[0, 1] == pytest.approx(200, abs=1)


def test_a_peer_votes_each_tracks_class_over_its_matched_boxes(boxmot):
    tracker = _peer("bytetrack")
    for f, (tlwh, conf, feature, _) in enumerate(_frames(12)):
        # target 0 named satellite (0) but debris (2) on every 4th frame; target 1 always rocket body (1)
        out = tracker.step(tlwh, conf, feature, classes=np.array([2 if f % 4 == 0 else 0, 1]))
    named = tracker.output_classes()
    assert named.shape == (len(out), 2) and len(out) == 2
    by_target = {
        int(np.argmin(np.abs(tlwh[:, 0] - row[1]))): tuple(k) for row, k in zip(out, named, strict=True)
    }
    assert by_target == {0: (0, 0), 1: (1, 1)}  # the frame's own name and the vote, both right on frame 11
    votes = tracker.class_votes.table()
    assert sorted(c for c, _ in votes.values()) == [0, 1]
    assert min(share for _, share in votes.values()) < 1.0  # target 0's debris frames count against it

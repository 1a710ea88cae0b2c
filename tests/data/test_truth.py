"""The renderer's ground truth checked against an independent reading of the same silhouettes."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from omegaconf import OmegaConf

from spacetrack.build_data import check_config, make_plan
from spacetrack.config import compose_config
from spacetrack.data.raster import Camera, Layer
from spacetrack.data.render import SequenceRenderer, frame_truth
from spacetrack.data.scenario import scenario_params
from spacetrack.data.scene import plan_sequence

CAMERA = Camera.from_fov(320, 240, 40.0)


def _plan(scenario: str, overrides: dict, seed: int, num_frames: int = 48):
    params = scenario_params(scenario, OmegaConf.create(overrides))
    spec = {"name": f"t_{scenario}", "scenario": scenario, "seed": [seed, 0]}
    return make_plan(spec, params, CAMERA, num_frames)


def visible_pixels(renderer: SequenceRenderer, t: int) -> dict[int, np.ndarray]:
    """Per object id, a full-frame boolean image of the pixels it shows: its silhouette inside the frame
    minus the silhouettes of every object nearer to the camera (painted independently of the renderer)."""
    layers = renderer.layers(t)
    full = {}
    for obj, layer in zip(renderer.plan.objects, layers, strict=True):
        if layer is None:
            continue
        ys, xs = np.nonzero(layer.mask)
        ys, xs = ys + layer.y0, xs + layer.x0
        keep = (ys >= 0) & (ys < CAMERA.height) & (xs >= 0) & (xs < CAMERA.width)
        canvas = np.zeros((CAMERA.height, CAMERA.width), dtype=bool)
        canvas[ys[keep], xs[keep]] = True
        full[obj.id] = (canvas, layer.depth, layer.area)
    out = {}
    for oid, (mask, depth, area) in full.items():
        nearer = [m for other, (m, d, _) in full.items() if other != oid and d < depth]
        hidden = np.logical_or.reduce(nearer) if nearer else np.zeros_like(mask)
        out[oid] = (mask & ~hidden, mask, area)
    return out


def tight_box(pixels: np.ndarray) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(pixels)
    return int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)


@pytest.mark.parametrize(
    "scenario,overrides",
    [("multi_target", {"num_targets": [6, 6]}), ("slew", {"num_static": [2, 2], "slew_px": [2.0, 2.0]})],
)
def test_boxes_and_visibility_match_an_independent_composite(scenario, overrides):
    renderer = SequenceRenderer(_plan(scenario, overrides, seed=5))
    checked = 0
    for t in range(0, 48, 4):
        truth = renderer.truth(t)
        expected = visible_pixels(renderer, t)
        rows = {r.id: r for r in truth.rows}
        in_frame = {oid for oid, (_, amodal, _) in expected.items() if amodal.any()}
        assert set(rows) == in_frame, (
            f"frame {t}: rows for {sorted(rows)}, objects in frame {sorted(in_frame)}"
        )
        for oid, (visible, amodal, area) in expected.items():
            if oid not in rows:
                continue
            row = rows[oid]
            assert row.visible_px == int(visible.sum())
            assert row.visibility == pytest.approx(visible.sum() / area)
            box = tight_box(visible) if visible.any() else tight_box(amodal)
            assert (row.x, row.y, row.w, row.h) == box, f"frame {t} id {oid}"
            checked += 1
        moving_now = [
            o.id for o in renderer.plan.objects if not o.static and o.moving(t) and o.id in expected
        ]
        expected_mask = np.logical_or.reduce(
            [expected[i][0] for i in moving_now] + [np.zeros_like(truth.motion_mask)]
        )
        np.testing.assert_array_equal(truth.motion_mask, expected_mask)
    assert checked > 20


def test_static_objects_never_in_motion_masks_even_when_the_camera_slews():
    plan = _plan("slew", {"num_static": [2, 2], "slew_px": [2.5, 2.5]}, seed=11)
    renderer = SequenceRenderer(plan)
    statics = [o.id for o in plan.static]
    assert len(statics) == 2 and np.linalg.norm(plan.slew) > 1.0
    seen_static = 0
    for t in range(0, 48, 3):
        expected = visible_pixels(renderer, t)
        mask = renderer.truth(t).motion_mask
        for sid in statics:
            if sid in expected:
                seen_static += int(expected[sid][0].sum())
                assert not (mask & expected[sid][0]).any(), (
                    f"frame {t}: static object {sid} in the motion mask"
                )
    assert seen_static > 100  # the static objects were really in view


def test_stopped_target_leaves_the_motion_mask_but_not_the_ground_truth():
    params = scenario_params(
        "stop", OmegaConf.create({"num_targets": [1, 1], "stop_prob": 1.0, "stop_frames": [15, 15]})
    )
    plan = None
    for seed in range(20):
        candidate = plan_sequence(
            name="s", scenario="stop", params=params, camera=CAMERA, num_frames=60, seed=[seed]
        )
        obj = candidate.objects[0]
        still = [t for t in range(60) if not obj.moving(t)]
        if still and all(0 <= c < d for c, d in zip(obj.centre(still[0]), (320, 240), strict=True)):
            plan = candidate
            break
    assert plan is not None
    renderer = SequenceRenderer(plan)
    t = still[len(still) // 2]
    truth = renderer.truth(t)
    assert [r.id for r in truth.rows] == [1] and truth.rows[0].visible_px > 0
    assert not truth.motion_mask.any()
    moving_t = next(t for t in range(60) if plan.objects[0].moving(t) and renderer.truth(t).rows)
    assert renderer.truth(moving_t).motion_mask.any()


def test_occluded_target_is_fully_hidden_for_ten_frames_then_reappears():
    plan = _plan("occlusion", {"occlusion_pair": True, "num_targets": [0, 0]}, seed=3)
    renderer = SequenceRenderer(plan)
    vis = []
    for t in range(plan.num_frames):
        row = next((r for r in renderer.truth(t).rows if r.id == 2), None)
        vis.append(None if row is None else row.visibility)
    hidden = [t for t, v in enumerate(vis) if v == 0.0]
    assert len(hidden) >= 10
    runs = np.split(np.array(hidden), np.flatnonzero(np.diff(hidden) > 1) + 1)
    longest = max(runs, key=len)
    assert len(longest) >= 10
    assert any(v is not None and v > 0 for v in vis[longest[-1] + 1 :]), "the hidden target never re-appears"
    assert any(v is not None and v > 0 for v in vis[: longest[0]]), "the target was never seen before hiding"


def test_night_side_is_as_black_as_space():
    params = scenario_params("side", OmegaConf.create({"num_targets": [1, 1], "sun_phase_deg": [95.0, 95.0]}))
    plan = plan_sequence(name="s", scenario="side", params=params, camera=CAMERA, num_frames=10, seed=[4])
    layer = SequenceRenderer(plan).layers(0)[0]
    inside = layer.radiance[layer.mask]
    dark = (inside.max(axis=1) == 0).mean()
    lit = (inside.max(axis=1) > 0.05).mean()
    assert dark > 0.1 and lit > 0.05, f"dark fraction {dark:.2f}, lit fraction {lit:.2f}"


def test_targets_turn_over_time():
    plan = _plan("nominal", {"num_targets": [1, 1], "stop_prob": 0.0}, seed=2)
    obj = plan.objects[0]
    r0, _ = obj.pose(0, CAMERA)
    r1, _ = obj.pose(20, CAMERA)
    assert np.degrees(np.arccos(np.clip((np.trace(r0.T @ r1) - 1) / 2, -1, 1))) > 5.0


# The "seen" truth: boxes frame only the object pixels the camera shows above its noise.


def _lit_plan(phase: float, **extra):
    params = scenario_params(
        "lit", OmegaConf.create({"num_targets": [2, 2], "sun_phase_deg": [phase, phase], **extra})
    )
    return plan_sequence(name="s", scenario="lit", params=params, camera=CAMERA, num_frames=24, seed=[7])


def test_seen_boxes_frame_the_visible_pixels_that_clear_the_noise():
    plan = _plan("multi_target", {"num_targets": [6, 6], "sun_phase_deg": [80.0, 110.0]}, seed=5)
    seen, outline = SequenceRenderer(plan, truth="seen"), SequenceRenderer(plan)
    checked = shrunk = 0
    for t in range(0, 48, 6):
        sky, floor, sigma = seen.seen_reference(t)
        assert sigma == plan.params.psf_sigma_px > 0
        layers = seen.layers(t)
        painted = {}  # per object: its radiance where its silhouette lies in the frame (NaN elsewhere)
        for obj, layer in zip(plan.objects, layers, strict=True):
            if layer is None:
                continue
            canvas = np.full((CAMERA.height, CAMERA.width, 3), np.nan, dtype=np.float32)
            ys, xs = np.nonzero(layer.mask)
            keep = (ys + layer.y0 >= 0) & (ys + layer.y0 < CAMERA.height)
            keep &= (xs + layer.x0 >= 0) & (xs + layer.x0 < CAMERA.width)
            canvas[ys[keep] + layer.y0, xs[keep] + layer.x0] = layer.radiance[ys[keep], xs[keep]]
            painted[obj.id] = (canvas, layer.depth)
        radiance = {}
        for oid, (canvas, depth) in painted.items():
            behind = sky.copy()  # the sky, then every farther object over it, farthest first
            for c, d in sorted(painted.values(), key=lambda v: -v[1]):
                if d > depth:
                    behind = np.where(np.isnan(c), behind, c)
            contrast = np.abs(np.nan_to_num(canvas, nan=0.0) - behind).max(axis=-1)
            contrast = np.where(np.isnan(canvas[..., 0]), 0.0, contrast).astype(np.float32)
            # spread by the optics' blur over the object's own pixels, as the image spreads it
            contrast = cv2.GaussianBlur(contrast, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
            radiance[oid] = np.where(np.isnan(canvas[..., 0]), -1.0, contrast)
        rows = {r.id: r for r in seen.truth(t).rows}
        whole = {r.id: r for r in outline.truth(t).rows}
        assert set(rows) == set(whole)
        for oid, (visible, amodal, area) in visible_pixels(seen, t).items():
            if oid not in rows:
                continue
            shown = visible & (radiance[oid] >= floor)  # contrast with what lies behind
            row = rows[oid]
            assert row.visible_px == int(shown.sum())
            assert row.visibility == pytest.approx(shown.sum() / area)
            box = tight_box(shown) if shown.any() else tight_box(amodal)
            assert (row.x, row.y, row.w, row.h) == box, f"frame {t} id {oid}"
            assert row.visible_px <= whole[oid].visible_px
            assert row.occluded_px == whole[oid].occluded_px  # shadow is not occlusion
            shrunk += row.w * row.h < whole[oid].w * whole[oid].h
            checked += 1
    assert checked > 20
    assert shrunk > 0  # at these phase angles some targets are partly in their own shadow


def test_the_image_is_the_same_whichever_truth_labels_it():
    plan = _lit_plan(100.0)
    a, b = SequenceRenderer(plan).render(5)[0], SequenceRenderer(plan, truth="seen").render(5)[0]
    np.testing.assert_array_equal(a, b)


def test_an_unlit_target_is_hidden_in_seen_truth_but_keeps_its_outline():
    plan = _lit_plan(60.0, sun=0.0)
    outline, seen = SequenceRenderer(plan), SequenceRenderer(plan, truth="seen")
    outlined = [r for t in range(0, 24, 4) for r in outline.truth(t).rows]
    assert outlined and all(r.visible_px > 0 for r in outlined)
    assert all(r.visible_px == 0 for t in range(0, 24, 4) for r in seen.truth(t).rows)
    assert not any(seen.truth(t).motion_mask.any() for t in range(0, 24, 4))


def test_an_unlit_target_against_a_bright_background_is_seen_whole():
    plan = _lit_plan(60.0, sun=0.0)
    outline, seen = SequenceRenderer(plan), SequenceRenderer(plan, truth="seen")
    seen.sky = np.full_like(seen.sky, 0.5)  # a lit planet filling the field behind the black targets
    for t in range(0, 24, 4):
        whole = [(r.id, r.visible_px, r.x, r.y, r.w, r.h) for r in outline.truth(t).rows]
        assert [(r.id, r.visible_px, r.x, r.y, r.w, r.h) for r in seen.truth(t).rows] == whole


def test_front_lit_targets_keep_most_of_their_outline_back_lit_ones_lose_most():
    def kept(phase: float) -> float:
        plan = _lit_plan(phase)
        outline, seen = SequenceRenderer(plan), SequenceRenderer(plan, truth="seen")
        total = sum(r.visible_px for t in range(0, 24, 3) for r in outline.truth(t).rows)
        shown = sum(r.visible_px for t in range(0, 24, 3) for r in seen.truth(t).rows)
        assert total > 200
        return shown / total

    front, back = kept(10.0), kept(170.0)
    assert front > 0.9, f"front-lit targets keep {front:.2f} of their pixels"
    assert back < 0.3, f"back-lit targets keep {back:.2f} of their pixels"


def test_a_higher_snr_shows_fewer_pixels():
    plan = _lit_plan(90.0)
    counts = [
        sum(r.visible_px for t in range(0, 24, 4) for r in SequenceRenderer(plan, "seen", snr).truth(t).rows)
        for snr in (1.0, 3.0, 30.0)
    ]
    assert counts[0] >= counts[1] > counts[2], counts


@pytest.mark.parametrize(
    "kwargs,match", [({"truth": "lit"}, "truth='lit'"), ({"seen_snr": 0.0}, "seen_snr=0.0")]
)
def test_renderer_rejects_unknown_truth_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SequenceRenderer(_lit_plan(30.0), **kwargs)


@pytest.mark.parametrize(
    "override,match",
    [("data.truth=outline", "data.truth='outline'"), ("data.seen_snr=-1", "data.seen_snr=-1")],
)
def test_build_data_rejects_unknown_truth_settings(tmp_path, override, match):
    cfg = compose_config("build_data", [f"data_root={tmp_path}", override])
    with pytest.raises(ValueError, match=match):
        check_config(cfg)


@pytest.mark.parametrize(("psf_sigma", "height"), [(0.0, 32), (0.7, 7)])
def test_a_lone_faint_pixel_does_not_stretch_a_seen_box_once_blurred(psf_sigma, height):
    # a lit end (6x12 px, ten times the needed contrast) and, 26 px along the dark body, one pixel just
    # above it before the optics' blur: the image shows the end only (and the blur its light a pixel beyond)
    mask = np.ones((32, 12), dtype=bool)
    radiance = np.zeros((32, 12, 3), dtype=np.float32)
    radiance[26:, :] = 1.0
    radiance[0, 6] = 0.12
    layer = Layer(x0=40, y0=20, radiance=radiance, mask=mask, depth=10.0)
    target = SimpleNamespace(id=1, class_id=1, static=False, moving=lambda t: True)
    sky = np.zeros((80, 100, 3), dtype=np.float32)
    floor = np.full((80, 100), 0.1, dtype=np.float32)
    (row,) = frame_truth([target], [layer], 0, 100, 80, (sky, floor, psf_sigma)).rows
    assert (row.x, row.y, row.w, row.h) == (40, 20 + 32 - height, 12, height)

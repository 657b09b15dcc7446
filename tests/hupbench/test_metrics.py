"""Metric tests: hand-computed answers, invariances, degenerate sets, numpy vs torch agreement."""

import itertools
import math

import numpy as np
import pytest
import torch

from hupbench import metrics as M
from hupbench.core import probe_symmetry as PS
from hupbench.evaluation import breakdowns as B


def _rotation(axis, angle):
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _symmetric_mm(pred, gt, permutations=M.PROBE_SYMMETRIES["half_turn"]):
    """The probe MPJPE minimised per frame over the group (eval's probe_symmetric_mpjpe_mm)."""
    return M.probe_symmetric_errors_mm(pred, gt, permutations)[0].mean()


def _pck_auc(pred, gt):
    return M.pck_auc_from_errors(M.keypoint_errors_mm(pred, gt))


def _random_points(n=4, k=29, seed=0):
    rng = np.random.default_rng(seed)
    gt = rng.normal(0.0, 0.05, (n, k, 3)) + np.array([0.0, 0.0, 0.6])
    pred = gt + rng.normal(0.0, 0.01, (n, k, 3))
    return pred, gt


def test_keypoint_errors_known_answer():
    gt = np.zeros((1, 2, 3))
    pred = np.array([[[0.003, 0.004, 0.0], [0.0, 0.0, -0.012]]])  # 3-4-5 triangle and 12 mm along z
    np.testing.assert_allclose(M.keypoint_errors_mm(pred, gt), [[5.0, 12.0]])
    assert M.mpjpe_mm(pred, gt) == pytest.approx(8.5)
    assert M.mpjpe_mm(pred, gt, keypoints=[1]) == pytest.approx(12.0)
    assert M.mpjpe_mm(pred, gt, keypoints=slice(0, 1)) == pytest.approx(5.0)


def test_split_is_keypoint_weighted():
    # hand keypoints off by 1 mm along x, probe corners by 10 mm: all = (21 + 80) / 29
    gt = np.zeros((2, 29, 3))
    pred = gt.copy()
    pred[:, :21, 0] = 0.001
    pred[:, 21:, 1] = -0.010
    split = M.mpjpe_split_mm(pred, gt)
    assert split == pytest.approx({"all": 101.0 / 29.0, "hand": 1.0, "probe": 10.0})
    assert all(type(v) is float for v in split.values())
    split_t = M.mpjpe_split_mm(torch.from_numpy(pred).float(), torch.from_numpy(gt).float())
    assert all(type(v) is float for v in split_t.values())
    assert split_t == pytest.approx(split, rel=1e-6)


def test_paper_all_is_not_keypoint_weighted():
    # HUP-3D (Birlo et al.) reports all 8.65 mm for hand 5.33 and probe 17.05: not (21 x 5.33 + 8 x 17.05) / 29
    assert (21 * 5.33 + 8 * 17.05) / 29 == pytest.approx(8.56, abs=0.005)
    assert "29 keypoints" in M.ALL_AVERAGING


def test_root_relative_known_answer():
    gt = np.zeros((1, 21, 3))
    gt[0, :, 2] = 0.5
    pred = gt + np.array([0.02, 0.0, 0.0])  # pure translation: root-relative error 0
    pred[0, 8, 1] += 0.021  # one joint 21 mm off after root alignment -> mean 1 mm over 21 joints
    assert M.root_relative_mpjpe_mm(pred, gt) == pytest.approx(1.0)
    assert M.mpjpe_mm(pred, gt) > 19.0  # the absolute error keeps the 20 mm shift


def test_middle_mcp_relative_known_answer():
    """Only the reference joint wrong: absolute and wrist-relative errors see one joint off, the error relative
    to that joint sees the 20 others off by as much (why the reference point matters, docs/metrics.md)."""
    gt = np.zeros((2, 21, 3))
    gt[..., 2] = 0.5
    pred = gt.copy()
    pred[:, M.MIDDLE_MCP_INDEX, 0] += 0.021  # the middle MCP 21 mm off
    assert M.MIDDLE_MCP_INDEX == 9
    assert M.mpjpe_mm(pred, gt) == pytest.approx(1.0)
    assert M.root_relative_mpjpe_mm(pred, gt) == pytest.approx(1.0)
    assert M.root_relative_mpjpe_mm(pred, gt, root=M.MIDDLE_MCP_INDEX) == pytest.approx(20 * 21.0 / 21)
    # a joint error shared by the wrist and the hand (a translation) is what subtracting a root removes
    moved = gt + np.array([0.0, 0.0, 0.03])
    assert M.root_relative_mpjpe_mm(moved, gt, root=M.MIDDLE_MCP_INDEX) == pytest.approx(0.0, abs=1e-9)


def test_pa_mpjpe_zero_for_similarity_copy():
    _, gt = _random_points(n=3, k=21)
    R = _rotation([0.3, -1.0, 0.5], 2.1)
    pred = 1.7 * gt @ R.T + np.array([0.1, -0.2, 0.3])
    assert M.pa_mpjpe_mm(pred, gt) == pytest.approx(0.0, abs=1e-6)
    assert M.mpjpe_mm(pred, gt) > 100.0
    aligned = M.procrustes_align(pred, gt)
    np.testing.assert_allclose(aligned, gt, atol=1e-9)


def test_pa_known_answer_scale_only():
    # gt = two points 2 cm apart; pred the same direction but 1 cm apart and shifted: aligns exactly
    gt = np.array([[[0.0, 0.0, 0.5], [0.02, 0.0, 0.5]]])
    pred = np.array([[[1.0, 1.0, 1.0], [1.01, 1.0, 1.0]]])
    np.testing.assert_allclose(M.procrustes_align(pred, gt), gt, atol=1e-12)
    # a noisy point cannot be aligned: a square vs a rectangle, error is hand-computable
    gt = np.array([[[1.0, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, -1, 0]]]) * 0.01
    pred = np.array([[[2.0, 1, 0], [-2, 1, 0], [-2, -1, 0], [2, -1, 0]]]) * 0.01
    # best similarity: s = tr(S)/var(p) = (2 + 1) * 1e-4 / (5e-4) = 0.6 -> points (1.2, 0.6):
    # error per point sqrt(0.2^2 + 0.4^2) cm
    assert M.pa_mpjpe_mm(pred, gt, keypoints=None) == pytest.approx(10 * math.sqrt(0.2 ** 2 + 0.4 ** 2))


def test_procrustes_never_reflects():
    # a mirror image cannot be aligned by a rotation: the error must stay > 0 and the fit be proper
    _, gt = _random_points(n=2, k=21, seed=3)
    mirrored = gt * np.array([-1.0, 1.0, 1.0])
    aligned = M.procrustes_align(mirrored, gt)
    assert M.mpjpe_mm(aligned, gt) > 1.0
    # the aligned set is a rotated + scaled copy of the mirrored set: its own handedness is kept
    c = aligned[0] - aligned[0].mean(0)
    m = mirrored[0] - mirrored[0].mean(0)
    det_fit = np.linalg.det(np.linalg.lstsq(m, c, rcond=None)[0])
    assert det_fit > 0


@pytest.mark.parametrize("case", ["collinear", "coplanar", "all_equal", "zero_pred", "zero_both", "single_point"])
@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_procrustes_degenerate_sets_finite(case, backend):
    rng = np.random.default_rng(7)
    gt = rng.normal(0, 0.05, (2, 21, 3))
    if case == "collinear":
        t = rng.normal(0, 1, (2, 21, 1))
        pred = t * np.array([0.01, 0.02, 0.0]) + 0.5
        gt = t * np.array([0.0, 0.0, 0.03])  # both collinear: exact alignment exists
    elif case == "coplanar":
        pred = rng.normal(0, 0.05, (2, 21, 3))
        pred[..., 2] = 0.4
        gt = pred @ _rotation([1, 1, 0], 0.7).T * 0.5
    elif case == "all_equal":
        pred = np.full((2, 21, 3), 0.3)
    elif case == "zero_pred":
        pred = np.zeros((2, 21, 3))
    elif case == "zero_both":
        pred = np.zeros((2, 21, 3))
        gt = np.zeros((2, 21, 3))
    else:
        pred = rng.normal(0, 0.05, (2, 1, 3))
        gt = gt[:, :1]
    if backend == "torch":
        pred, gt = torch.from_numpy(pred), torch.from_numpy(gt)
    aligned = M.procrustes_align(pred, gt)
    assert bool(np.isfinite(np.asarray(aligned)).all())
    err = float(M.pa_mpjpe_mm(pred, gt, keypoints=None))
    assert math.isfinite(err)
    gt_np = np.asarray(gt)
    if case in ("collinear", "coplanar", "zero_both", "single_point"):
        assert err == pytest.approx(0.0, abs=1e-6)
    if case in ("all_equal", "zero_pred"):
        # no scale: every point goes to the target centroid
        np.testing.assert_allclose(np.asarray(aligned), np.broadcast_to(gt_np.mean(1, keepdims=True), gt_np.shape),
                                   atol=1e-12)


def test_pck_auc_known_answers():
    th = M.PCK_THRESHOLDS_MM
    assert th[0] == 0.0 and th[-1] == 50.0 and len(th) == 101
    assert M.pck_auc_from_errors(np.zeros((3, 29))) == pytest.approx(1.0)
    assert M.pck_auc_from_errors(np.full((3, 29), 60.0)) == pytest.approx(0.0)
    # a single error of 25 mm: PCK is 0 below 25 and 1 from 25 on; trapezoid area (50 - 25 + 0.25) / 50
    assert M.pck_auc_from_errors(np.array([[25.0]])) == pytest.approx(25.25 / 50.0)
    # coarse thresholds, hand-computable: errors 0 and 10 mm, thresholds 0, 10, 20
    assert M.pck_auc_from_errors(np.array([[0.0, 10.0]]), [0.0, 10.0, 20.0]) == pytest.approx(
        (0.5 * (0.5 + 1.0) * 10 + 1.0 * 10) / 20)
    gt = np.zeros((1, 2, 3))
    pred = np.array([[[0.0, 0.0, 0.0], [0.06, 0.0, 0.0]]])
    assert _pck_auc(pred, gt) == pytest.approx(0.5)


def test_pixel_error_known_answer():
    gt = np.zeros((1, 3, 2))
    pred = np.array([[[3.0, 4.0], [0.0, 1.0], [6.0, 8.0]]])
    assert M.pixel_error_px(pred, gt) == pytest.approx(16.0 / 3.0)
    mask = np.array([[True, True, False]])
    assert M.pixel_error_px(pred, gt, mask) == pytest.approx(3.0)


def test_numpy_torch_agree():
    pred, gt = _random_points(n=5)
    pt, gtt = torch.from_numpy(pred), torch.from_numpy(gt)
    for fn in (M.mpjpe_mm, M.root_relative_mpjpe_mm, M.pa_mpjpe_mm, _pck_auc):
        a, b = fn(pred, gt), fn(pt, gtt)
        assert isinstance(a, float) and isinstance(b, torch.Tensor), fn.__name__
        assert float(b) == pytest.approx(a, rel=1e-9, abs=1e-9), fn.__name__
    np.testing.assert_allclose(M.keypoint_errors_mm(pt, gtt).numpy(), M.keypoint_errors_mm(pred, gt), rtol=1e-12)
    np.testing.assert_allclose(M.procrustes_align(pt, gtt).numpy(), M.procrustes_align(pred, gt), rtol=1e-12)
    px_pred, px_gt = pred[..., :2] * 100, gt[..., :2] * 100
    assert float(M.pixel_error_px(torch.from_numpy(px_pred), torch.from_numpy(px_gt))) == pytest.approx(
        M.pixel_error_px(px_pred, px_gt))
    # float32 tensors keep their dtype and agree to float32 precision
    e32 = M.mpjpe_mm(pt.float(), gtt.float())
    assert e32.dtype == torch.float32 and float(e32) == pytest.approx(M.mpjpe_mm(pred, gt), rel=1e-5)


def test_breakdowns():
    errors = np.zeros((4, 29))
    errors[:, :21] = np.array([1.0, 2.0, 3.0, 4.0])[:, None]
    errors[:, 21:] = 10.0
    theta = np.array([0.3, 1.0, math.pi / 2, 2.5])
    lat = B.latitude_labels(theta)
    assert lat.tolist() == ["egocentric", "egocentric", "non_egocentric", "non_egocentric"]
    table = M.breakdown_mpjpe_mm(errors, lat)
    assert table["egocentric"]["frames"] == 2
    assert table["egocentric"]["mpjpe_mm"] == pytest.approx({"hand": 1.5, "probe": 10.0,
                                                             "all": (21 * 1.5 + 80) / 29})
    assert table["non_egocentric"]["mpjpe_mm"]["hand"] == pytest.approx(3.5)
    z = B.z_ego_labels([0.5, 0.8, 0.5, 0.8])
    assert z.tolist() == ["0.5 m", "0.8 m", "0.5 m", "0.8 m"]
    assert M.breakdown_mpjpe_mm(torch.from_numpy(errors), z)["0.8 m"]["mpjpe_mm"]["hand"] == pytest.approx(3.0)
    # a distance per frame (a swaying head): 5 cm bins, a frame on an edge in the bin above it
    swaying = B.z_ego_labels([0.351, 0.3529, 0.399, 0.40, 0.4489, 0.45, 0.6, 0.6012])
    assert swaying.tolist() == ["0.35-0.40 m"] * 3 + ["0.40-0.45 m"] * 2 + ["0.45-0.50 m"] + ["0.60-0.65 m"] * 2
    assert B.background_labels([0, 2], ["white", "room", "phantom"]).tolist() == ["white", "phantom"]
    assert B.background_labels([1]).tolist() == ["background 1"]
    with pytest.raises(ValueError, match="no name"):
        B.background_labels([5], ["white"])


def test_hand_visible_buckets_count_the_hand_keypoints_shown():
    # frames showing 0, 5, 6, 10, 11, 15, 16 and 21 hand keypoints, every probe corner visible (not counted)
    counts = [0, 5, 6, 10, 11, 15, 16, 21]
    visible = np.zeros((len(counts), 29), bool)
    visible[:, 21:] = True
    for row, count in enumerate(counts):
        visible[row, 21 - count:21] = True
    assert B.hand_visible_labels(visible).tolist() == ["0-5 of 21"] * 2 + ["6-10 of 21"] * 2 + ["11-15 of 21"] * 2 \
        + ["16-21 of 21"] * 2
    # the hidden hands' error shows in their bucket
    errors = _frames_with_errors([(100.0, 50.0), (100.0, 50.0)] + [(10.0, 20.0)] * 6)
    table = M.breakdown_mpjpe_mm(errors, B.hand_visible_labels(visible))
    assert table["0-5 of 21"]["mpjpe_mm"]["hand"] == pytest.approx(100.0)
    assert table["16-21 of 21"]["frames"] == 2 and table["16-21 of 21"]["mpjpe_mm"]["probe"] == pytest.approx(20.0)


def _frames_with_errors(hand_probe_mm):
    """(N, 29) errors: every hand keypoint of frame n has error hand_n, every probe corner probe_n (mm)."""
    errors = np.zeros((len(hand_probe_mm), 29))
    errors[:, :21] = np.array([h for h, _ in hand_probe_mm])[:, None]
    errors[:, 21:] = np.array([p for _, p in hand_probe_mm])[:, None]
    return errors


def test_grasp_and_theta_vol_breakdowns_known_answer():
    # grasp 3: two frames, 7: three, 12: one (orientation not recorded), 5: one
    grasp_id = np.array([3, 3, 7, 7, 7, 12, 5], np.int64)
    errors = _frames_with_errors([(1, 10), (3, 20), (2, 4), (4, 8), (6, 12), (10, 0), (5, 30)])
    by_grasp = M.breakdown_mpjpe_mm(errors, B.grasp_labels(grasp_id))
    assert list(by_grasp) == ["12", "3", "5", "7"]  # labels are the ids in decimal, sorted as text
    assert {g: b["frames"] for g, b in by_grasp.items()} == {"3": 2, "7": 3, "12": 1, "5": 1}
    assert by_grasp["3"]["mpjpe_mm"] == pytest.approx({"hand": 2.0, "probe": 15.0, "all": (21 * 2 + 8 * 15) / 29})
    assert by_grasp["7"]["mpjpe_mm"] == pytest.approx({"hand": 4.0, "probe": 8.0, "all": (21 * 4 + 8 * 8) / 29})
    assert by_grasp["12"]["mpjpe_mm"] == pytest.approx({"hand": 10.0, "probe": 0.0, "all": 210 / 29})

    theta_vol = {3: [0.0, -0.0, 180.0], 5: [0, 0, 180], 7: [0.0, 0.0, 90.0], 12: None}
    labels = B.theta_vol_labels(grasp_id, theta_vol)
    assert labels.tolist() == ["theta_vol_z=180"] * 2 + ["theta_vol_z=90"] * 3 + ["unknown", "theta_vol_z=180"]
    by_theta = M.breakdown_mpjpe_mm(torch.from_numpy(errors), labels)
    assert {k: b["frames"] for k, b in by_theta.items()} == {"theta_vol_z=180": 3, "theta_vol_z=90": 3, "unknown": 1}
    # z = 180 pools grasps 3 and 5 frame by frame: hand (1 + 3 + 5) / 3, probe (10 + 20 + 30) / 3
    assert by_theta["theta_vol_z=180"]["mpjpe_mm"] == pytest.approx({"hand": 3.0, "probe": 20.0,
                                                                     "all": (21 * 3 + 8 * 20) / 29})
    assert by_theta["theta_vol_z=90"]["mpjpe_mm"] == by_grasp["7"]["mpjpe_mm"]
    assert by_theta["unknown"]["mpjpe_mm"] == by_grasp["12"]["mpjpe_mm"]
    # a grasp the map does not name has no recorded orientation either
    assert B.theta_vol_labels([4, 7], {7: (0, 0, 90)}).tolist() == ["unknown", "theta_vol_z=90"]


@pytest.mark.parametrize("theta_vol_deg, label", [
    ((0, 0, 0), "theta_vol_z=0"),
    ((0, 0, 180), "theta_vol_z=180"),
    ((30, 0, -90), "theta_vol_x=30_z=-90"),
    ((0, 45.5, 0), "theta_vol_y=45.5_z=0"),
    ((10, 20, 30), "theta_vol_x=10_y=20_z=30"),
    ((0, 0, 359.99999), "theta_vol_z=360"),     # rounded to 3 decimals, not wrapped
    ((0, 0, -359.125), "theta_vol_z=-359.125"),
    ((0, 0, 270.0004), "theta_vol_z=270"),
    ((-0.0, 0.0001, -0.0001), "theta_vol_z=0"),  # no "-0" after rounding
])
def test_theta_vol_label(theta_vol_deg, label):
    assert B.theta_vol_label(theta_vol_deg) == label


def test_misuse_fails_loudly():
    """The metrics trust their callers, but a mismatch that numpy would broadcast into a wrong number stops."""
    for pred, gt in [(np.zeros((2, 3)), np.zeros((2, 3))), (np.zeros((2, 29, 3)), np.zeros((2, 21, 3))),
                     (np.zeros((1, 2, 3)), torch.zeros(1, 2, 3))]:
        with pytest.raises(AssertionError):
            M.mpjpe_mm(pred, gt)
    with pytest.raises(AssertionError):
        M.breakdown_mpjpe_mm(np.zeros((4, 29)), ["a"] * 3)


# ----------------------------------------------------------------------------- symmetric probe error

HALF_TURN_PERM = (6, 7, 4, 5, 2, 3, 0, 1)


def _probe_frames(n=3, seed=0):
    """(n, 29, 3) truth: random hands and an axis-centred probe box, rotated and moved per frame."""
    rng = np.random.default_rng(seed)
    bits = np.array(list(itertools.product((0, 1), repeat=3)), np.float64)
    box = (2 * bits - 1) * [0.036, 0.015, 0.0825] + [0.0, 0.0, 0.0825]          # probe frame
    frames = np.empty((n, 29, 3))
    for i in range(n):
        R = _rotation(rng.normal(size=3), rng.uniform(0, np.pi))
        t = np.array([0.0, 0.0, 0.6]) + rng.normal(0, 0.05, 3)
        frames[i, :21] = rng.normal(0, 0.05, (21, 3)) + t
        frames[i, 21:] = box @ R.T + t
    return frames, box


def test_half_turn_permutation_is_read_from_the_corners():
    # the documented corner order (ix, iy, iz) -> (1 - ix, 1 - iy, iz)
    assert M.PROBE_SYMMETRIES["half_turn"] == (tuple(range(8)), HALF_TURN_PERM)
    assert M.PROBE_SYMMETRIES["none"] == (tuple(range(8)),)
    for k, (ix, iy, iz) in enumerate(itertools.product((0, 1), repeat=3)):
        assert HALF_TURN_PERM[k] == 4 * (1 - ix) + 2 * (1 - iy) + iz
    _, box = _probe_frames()
    assert PS.symmetry_permutation(box, PS.HALF_TURN_Z) == HALF_TURN_PERM
    assert PS.symmetry_permutation(box, np.eye(3)) == tuple(range(8))


def test_the_probe_box_is_symmetric_under_the_half_turn():
    from hupbench.datagen.assets.probe import build_probe

    corners = build_probe().corners_probe
    assert PS.symmetry_permutation(corners, PS.HALF_TURN_Z) == HALF_TURN_PERM


def test_symmetry_permutation_refuses_an_asymmetric_set():
    _, box = _probe_frames()
    with pytest.raises(ValueError, match="not symmetric under the rotation: .* mm from the nearest point"):
        PS.symmetry_permutation(box + [0.002, 0.0, 0.0], PS.HALF_TURN_Z)   # box off the axis by 2 mm


def test_symmetric_probe_error_known_answers():
    gt, _ = _probe_frames(n=4)
    turned = gt.copy()
    turned[:, 21:] = gt[:, 21:][:, list(HALF_TURN_PERM)]   # the half-turned labelling of the same box
    # the plain probe error of the swapped labels is large, the symmetric one is zero
    assert M.mpjpe_split_mm(turned, gt)["probe"] > 20.0
    assert _symmetric_mm(turned, gt) == pytest.approx(0.0, abs=1e-9)
    _, choice = M.probe_symmetric_errors_mm(turned, gt)
    np.testing.assert_array_equal(choice, [1, 1, 1, 1])
    # only the identity in the group: the plain probe MPJPE
    assert _symmetric_mm(turned, gt, M.PROBE_SYMMETRIES["none"]) == pytest.approx(
        M.mpjpe_split_mm(turned, gt)["probe"], rel=1e-12)
    # a 3 mm shift of every corner along x: 3 mm under either labelling choice, the identity wins
    shifted = gt.copy()
    shifted[:, 21:, 0] += 0.003
    assert _symmetric_mm(shifted, gt) == pytest.approx(3.0)
    np.testing.assert_array_equal(M.probe_symmetric_errors_mm(shifted, gt)[1], 0)
    # mixed frames: frame 0 turned (0 mm), frame 1 shifted (3 mm): mean 1.5; never above the plain error
    mixed = np.concatenate([turned[:1], shifted[1:2]])
    assert _symmetric_mm(mixed, gt[:2]) == pytest.approx(1.5)
    pred, truth = _random_points(n=5)
    assert _symmetric_mm(pred, truth) <= M.mpjpe_split_mm(pred, truth)["probe"] + 1e-12


def test_symmetric_probe_error_torch_matches_numpy():
    pred, gt = _random_points(n=6, seed=3)
    errors, choice = M.probe_symmetric_errors_mm(pred, gt)
    errors_t, choice_t = M.probe_symmetric_errors_mm(torch.from_numpy(pred), torch.from_numpy(gt))
    np.testing.assert_allclose(errors_t.numpy(), errors, rtol=1e-12)
    np.testing.assert_array_equal(choice_t.numpy(), choice)


def test_symmetry_costs_and_permute_keypoints():
    gt, _ = _probe_frames(n=2)
    perms = M.PROBE_SYMMETRIES["half_turn"]
    costs = M.symmetry_costs(gt, gt, perms)
    assert costs.shape == (2, 2)
    np.testing.assert_allclose(costs[:, 0], 0.0, atol=1e-15)
    # the half turn moves every corner to the diagonally opposite corner of its z-face
    diagonal = np.hypot(0.072, 0.030)
    np.testing.assert_allclose(costs[:, 1], diagonal, rtol=1e-12)
    np.testing.assert_allclose(M.symmetry_costs(gt, gt, perms, squared=True)[:, 1], diagonal**2, rtol=1e-12)
    # relabelling by the half turn, twice, is the identity; the hand is untouched
    once = M.permute_keypoints(gt, perms, np.array([1, 0]))
    np.testing.assert_array_equal(once[0, 21:], gt[0, 21:][list(HALF_TURN_PERM)])
    np.testing.assert_array_equal(once[1], gt[1])
    np.testing.assert_array_equal(once[:, :21], gt[:, :21])
    np.testing.assert_array_equal(M.permute_keypoints(once, perms, np.array([1, 0])), gt)
    once_t = M.permute_keypoints(torch.from_numpy(gt), perms, torch.tensor([1, 0]))
    np.testing.assert_array_equal(once_t.numpy(), once)
    # works on 2D points too
    assert M.permute_keypoints(gt[..., :2], perms, np.array([1, 1])).shape == (2, 29, 2)


# ----------------------------------------------------------------------------- spread ratios


def test_spread_ratio_known_answers():
    _, gt = _random_points(n=20, seed=4)
    assert M.spread_ratios(gt, gt) == pytest.approx({"x": 1.0, "y": 1.0, "z": 1.0})
    # one layout for every image (the mean of the truth): 0 on every axis
    constant = np.broadcast_to(gt[0], gt.shape).copy()
    assert M.spread_ratios(constant, gt) == pytest.approx({"x": 0.0, "y": 0.0, "z": 0.0}, abs=1e-12)
    assert M.collapsed_axes(M.spread_ratios(constant, gt)) == ["x", "y", "z"]
    # a copy scaled about the per-keypoint mean by (0.3, 2, 1), and moved: ratios 0.3, 2, 1
    mean = gt.mean(axis=0)
    scaled = mean + (gt - mean) * [0.3, 2.0, 1.0] + [0.1, -0.2, 0.05]
    assert M.spread_ratios(scaled, gt) == pytest.approx({"x": 0.3, "y": 2.0, "z": 1.0}, rel=1e-12)
    assert M.collapsed_axes(M.spread_ratios(scaled, gt)) == ["x"]
    ratios_t = M.spread_ratios(torch.from_numpy(scaled).float(), torch.from_numpy(gt).float())
    assert all(type(v) is float for v in ratios_t.values())
    assert ratios_t == pytest.approx({"x": 0.3, "y": 2.0, "z": 1.0}, rel=1e-5)


def test_spread_ratio_hand_computed_and_undefined():
    # two frames, one keypoint: truth moves 2 cm along x only, prediction 1 cm along x and 1 cm along z
    gt = np.array([[[0.0, 0.0, 0.5]], [[0.02, 0.0, 0.5]]])
    pred = np.array([[[0.0, 0.0, 0.5]], [[0.01, 0.0, 0.51]]])
    # std over 2 frames = half the difference: x 5 mm / 10 mm; y, z: the truth does not move -> None
    assert M.spread_ratios(pred, gt) == {"x": 0.5, "y": None, "z": None}
    assert M.collapsed_axes({"x": 0.5, "y": None, "z": 0.49}) == ["z"]
    assert M.spread_ratios(pred[:1], gt[:1]) == {"x": None, "y": None, "z": None}   # one frame


def test_rotation_onto_recovers_a_turn_and_stays_proper():
    from hupbench.core.geometry import axis_angle_to_matrix, rotation_onto

    rng = np.random.default_rng(3)
    src = rng.normal(size=(4, 8, 3))
    turns = np.stack([axis_angle_to_matrix(v) for v in rng.normal(size=(4, 3))])
    dst = np.einsum("nij,nkj->nki", turns, src) + rng.normal(size=(4, 1, 3))   # turned and moved
    np.testing.assert_allclose(rotation_onto(src, dst), turns, atol=1e-10)
    mirrored = dst * np.array([1.0, 1.0, -1.0])                                  # no rotation can do this
    assert np.allclose(np.linalg.det(rotation_onto(src, mirrored)), 1.0)


# ----------------------------------------------------------------------------- object pose (BOP)


def _poses(n, seed=0):
    """(n, 4, 4) random T_cam_obj about 0.5 m in front of the camera."""
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        T[i, :3, :3] = _rotation(rng.normal(size=3), rng.uniform(0, np.pi))
        T[i, :3, 3] = [0.0, 0.0, 0.5] + rng.normal(0, 0.03, 3)
    return T


def _half_turn_symmetric_points(v=50, seed=0):
    """(2v, 3) object points, metres, mapped onto themselves by the half turn about z."""
    q = np.random.default_rng(seed).normal(0.0, 0.04, (v, 3))
    return np.concatenate([q, q @ PS.HALF_TURN_Z.T])


K_256 = np.array([[480.0, 0.0, 128.0], [0.0, 480.0, 128.0], [0.0, 0.0, 1.0]])


def test_fit_rigid_pose_recovers_the_pose_of_exact_points():
    from hupbench.core.geometry import fit_rigid_pose

    T = _poses(5)
    _, box = _probe_frames()
    observed = box @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]
    np.testing.assert_allclose(fit_rigid_pose(box, observed), T, atol=1e-12)
    # noise on the corners moves the fit less than the noise itself (least squares over 8 points)
    noisy = observed + np.random.default_rng(1).normal(0.0, 0.001, observed.shape)
    fitted = fit_rigid_pose(box, noisy)
    assert np.abs(fitted[:, :3, 3] - T[:, :3, 3]).max() < 0.002
    np.testing.assert_allclose(np.linalg.det(fitted[:, :3, :3]), 1.0)


def test_fit_rigid_pose_takes_one_point_set_per_frame():
    """(N, K, 3) object points, a different set in each frame (a prediction aligned onto the truth): each frame's
    own pose, and the same answer as fitting each frame alone."""
    from hupbench.core.geometry import fit_rigid_pose

    T = _poses(4)
    objects = np.random.default_rng(2).normal(0.0, 0.05, (4, 6, 3))
    observed = np.einsum("nij,nkj->nki", T[:, :3, :3], objects) + T[:, None, :3, 3]
    np.testing.assert_allclose(fit_rigid_pose(objects, observed), T, atol=1e-12)
    one_by_one = np.concatenate([fit_rigid_pose(objects[i], observed[i:i + 1]) for i in range(4)])
    np.testing.assert_allclose(fit_rigid_pose(objects, observed), one_by_one, atol=1e-12)


@pytest.mark.parametrize("n", [1, 70])   # 70 frames: more than one chunk
def test_identity_pose_scores_zero(n):
    T, pts = _poses(n), _half_turn_symmetric_points()
    K = np.broadcast_to(K_256, (n, 3, 3))
    for errors in (M.add_mm(T, T, pts), M.add_s_mm(T, T, pts), M.mssd_mm(T, T, pts), M.mspd_px(T, T, K, pts)):
        assert errors.shape == (n,)
        np.testing.assert_allclose(errors, 0.0, atol=1e-9)


def test_translation_known_answers():
    T_true, pts = _poses(4), _half_turn_symmetric_points()
    shift = np.array([0.003, -0.004, 0.012])                                     # 13 mm
    T_pred = T_true.copy()
    T_pred[:, :3, 3] += shift
    np.testing.assert_allclose(M.add_mm(T_pred, T_true, pts), 13.0)
    # every point moves by the same 13 mm: the max is the mean, and the half turn is further
    np.testing.assert_allclose(M.mssd_mm(T_pred, T_true, pts), 13.0)
    add_s = M.add_s_mm(T_pred, T_true, pts)
    assert np.all(add_s <= 13.0 + 1e-9) and np.all(add_s > 0.0)
    # ADD-S is the nearest-point distance: brute force over all pairs
    posed_true = pts @ T_true[0, :3, :3].T + T_true[0, :3, 3]
    posed_pred = posed_true + shift
    brute = np.linalg.norm(posed_true[:, None] - posed_pred[None], axis=-1).min(axis=1).mean() * 1000
    assert add_s[0] == pytest.approx(brute, rel=1e-9)


def test_half_turn_is_free_for_add_s_and_mssd_not_for_add():
    T_true, pts = _poses(3), _half_turn_symmetric_points()
    T_pred = T_true.copy()
    T_pred[:, :3, :3] = T_true[:, :3, :3] @ PS.HALF_TURN_Z                        # the object half-turned in place
    K = np.broadcast_to(K_256, (3, 3, 3))
    np.testing.assert_allclose(M.add_s_mm(T_pred, T_true, pts), 0.0, atol=1e-9)
    np.testing.assert_allclose(M.mssd_mm(T_pred, T_true, pts), 0.0, atol=1e-9)
    np.testing.assert_allclose(M.mspd_px(T_pred, T_true, K, pts), 0.0, atol=1e-6)
    # ADD: a point at distance r from the axis moves by 2 r under the half turn
    two_r = 2 * np.linalg.norm(pts[:, :2], axis=1) * 1000
    np.testing.assert_allclose(M.add_mm(T_pred, T_true, pts), two_r.mean())
    # without the symmetry MSSD is the largest of those moves
    none = M.PROBE_SYMMETRY_ROTATIONS["none"]
    np.testing.assert_allclose(M.mssd_mm(T_pred, T_true, pts, none), two_r.max())
    assert M.mspd_px(T_pred, T_true, K, pts, none).min() > 1.0


def test_mspd_matches_cv2_project_points():
    import cv2

    n = 6
    T_true, pts = _poses(n, seed=1), _half_turn_symmetric_points(seed=2)
    T_pred = _poses(n, seed=1)
    T_pred[:, :3, :3] = T_pred[:, :3, :3] @ _rotation([0.3, 1.0, 0.2], 0.2)      # turned by 0.2 rad
    T_pred[:, :3, 3] += [0.004, 0.0, -0.01]
    K = np.stack([K_256 * [[1.0 + 0.1 * i], [1.0], [1.0]] for i in range(n)])   # a different fx per frame
    K[:, 2, 2] = 1.0

    def project(T, k):
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        return cv2.projectPoints(pts, rvec, T[:3, 3], k, None)[0].reshape(-1, 2)

    expected = []
    for i in range(n):
        uv_pred = project(T_pred[i], K[i])
        per_symmetry = []
        for S in M.PROBE_SYMMETRY_ROTATIONS["half_turn"]:
            T_sym = T_true[i].copy()
            T_sym[:3, :3] = T_true[i, :3, :3] @ S
            per_symmetry.append(np.linalg.norm(uv_pred - project(T_sym, K[i]), axis=1).max())
        expected.append(min(per_symmetry))
    np.testing.assert_allclose(M.mspd_px(T_pred, T_true, K, pts), expected, rtol=1e-6)


def test_mspd_is_inf_behind_the_camera():
    T_true, pts = _poses(2), _half_turn_symmetric_points()
    T_pred = T_true.copy()
    T_pred[1, :3, 3] = [0.0, 0.0, -0.5]
    errors = M.mspd_px(T_pred, T_true, np.broadcast_to(K_256, (2, 3, 3)), pts)
    assert errors[0] == pytest.approx(0.0, abs=1e-9) and errors[1] == np.inf


def test_diameter_and_thresholds():
    _, box = _probe_frames()
    assert PS.object_diameter_m(box) == pytest.approx(math.sqrt(0.072 ** 2 + 0.030 ** 2 + 0.165 ** 2))
    cloud = np.random.default_rng(0).normal(size=(5000, 3))                    # the convex-hull path
    from scipy.spatial.distance import pdist
    assert PS.object_diameter_m(cloud) == pytest.approx(pdist(cloud).max())
    np.testing.assert_allclose(M.MSSD_THRESHOLDS_DIAMETER, [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5])
    np.testing.assert_allclose(M.mspd_thresholds_px(640), [5, 10, 15, 20, 25, 30, 35, 40, 45, 50])
    np.testing.assert_allclose(M.mspd_thresholds_px(256), [2, 4, 6, 8, 10, 12, 14, 16, 18, 20])


def test_recall_is_strict_and_averaged():
    np.testing.assert_allclose(M.recall([1.0, 2.0, 3.0], [2.0, 3.5]), [1 / 3, 1.0])   # 2.0 < 2.0 is not correct
    assert M.average_recall([1.0, 2.0, 3.0], [2.0, 3.5]) == pytest.approx(2 / 3)


def test_bop_scores_known_answers():
    scores = M.bop_scores(add=[5.0, 15.0], add_s=[5.0, 9.0], mssd=[0.0, 100.0], mspd=[3.0, 30.0],
                          diameter_mm=100.0, image_width_px=640)
    assert scores == pytest.approx({
        "add_mm": 10.0, "add_s_mm": 7.0, "mssd_mm": 50.0, "mspd_px": 16.5,
        "add_accuracy": 0.5, "add_s_accuracy": 1.0,                  # below 10 mm
        "ar_mssd": 0.5,                                               # 0 passes all of 5..50 mm, 100 none
        "ar_mspd": (10 + 4) / 20,                                     # 3 px passes all, 30 px 35..50 only
        "diameter_mm": 100.0, "image_width_px": 640})
    assert type(scores["image_width_px"]) is int and all(type(v) is float for k, v in scores.items()
                                                         if k != "image_width_px")
    behind = M.bop_scores([1.0], [1.0], [1.0], [np.inf], 100.0, 640)
    assert behind["mspd_px"] is None and behind["ar_mspd"] == 0.0


def test_the_probe_mesh_half_turned_costs_add_only():
    """The probe as built: its mesh maps onto itself under the half turn except for the marker."""
    from hupbench.datagen.assets.probe import build_probe

    probe = build_probe()
    pts = np.asarray(probe.mesh.vertices)
    T_true = _poses(2)
    T_pred = T_true.copy()
    T_pred[:, :3, :3] = T_true[:, :3, :3] @ PS.HALF_TURN_Z
    assert M.mssd_mm(T_pred, T_true, pts) == pytest.approx([0.0, 0.0], abs=1e-9)
    assert np.all(M.add_s_mm(T_pred, T_true, pts) < 0.2)                    # the marker and tessellation only
    assert np.all(M.add_mm(T_pred, T_true, pts) > 20.0)
    # the mesh's diameter is about its 165 mm length: the tapered probe does not reach its box's corners
    assert 0.165 <= PS.object_diameter_m(pts) < 0.166 < PS.object_diameter_m(probe.corners_probe)

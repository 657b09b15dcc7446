import numpy as np
import pytest
import torch

from hupbench.datagen.grasps.synthesis import GraspGenConfig, generate_candidates, select_grasps
from hupbench.datagen.grasps.refine import GraspBatch, GraspEnergy, RefineConfig, random_starts, refine
from hupbench.datagen.grasps.scores import SCORE_NAMES, score_grasps
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import joint_limits_rad
from hupbench.datagen.assets.probe import build_probe


@pytest.fixture(scope="module")
def models():
    return build_hand(), build_probe()


def _starts(models, n=4, seed=0):
    hand, _ = models
    return random_starts(n, np.random.default_rng(seed), hand.limits_rad)


def _assert_finite_and_scored(energy, grasps):
    for name in ("R_global", "trans", "angles", "energy"):
        assert np.all(np.isfinite(getattr(grasps, name))), name
    scores = score_grasps(energy, grasps)
    for name in SCORE_NAMES:
        values = scores[name].astype(float)
        assert np.all(np.isfinite(values) | (name == "min_contact_height_mm")), name
    return scores


def test_refinement_lowers_energy_and_penetration(models):
    hand, probe = models
    energy = GraspEnergy(hand, probe, RefineConfig(iterations=120))
    start = _starts(models, 6)
    before = score_grasps(energy, start)
    out = refine(energy, start)
    after = _assert_finite_and_scored(energy, out)
    assert np.median(after["max_penetration_mm"]) <= np.median(before["max_penetration_mm"])
    assert np.mean(after["pads_in_contact"]) > np.mean(before["pads_in_contact"])
    # the joint angles never leave their limits (sigmoid bounds)
    limits = joint_limits_rad()
    assert np.all(out.angles >= limits[..., 0] - 1e-9) and np.all(out.angles <= limits[..., 1] + 1e-9)


def test_stiff_penetration_weight_stays_finite(models):
    hand, probe = models
    energy = GraspEnergy(hand, probe, RefineConfig(iterations=60, w_penetration_start=1e4, w_penetration_end=1e4))
    _assert_finite_and_scored(energy, refine(energy, _starts(models, 3)))


def test_starts_far_away_and_deep_inside(models):
    hand, probe = models
    energy = GraspEnergy(hand, probe, RefineConfig(iterations=150))
    start = _starts(models, 2)
    far = GraspBatch(start.R_global, start.trans + [0.5, -0.4, 0.3], start.angles)
    inside = GraspBatch(start.R_global, np.array([[0.0, 0.0, 0.09], [0.0, 0.0, 0.03]]), start.angles)
    for batch in (far, inside):
        _assert_finite_and_scored(energy, refine(energy, batch))
    # starts inside the probe: each either gets pushed out, or stays stuck (a wrist at the handle's
    # core straddles it and the pushes cancel) and is then rejected by its scores
    before = score_grasps(energy, inside)["max_penetration_mm"]
    after = score_grasps(energy, refine(energy, inside))
    assert before.min() > 5.0
    recovered = after["max_penetration_mm"] <= 2.0
    assert recovered.any()
    assert not after["plausible"][~recovered].any()
    # the far start is pulled back towards the probe
    out = refine(energy, far)
    assert np.linalg.norm(out.trans - [0.0, 0.0, 0.09], axis=1).max() < np.linalg.norm(far.trans - [0, 0, 0.09], axis=1).min()


def test_same_seed_same_grasps_bitwise_and_other_seed_differs(models):
    torch.set_num_threads(1)
    cfg = dict(theta_vol_deg=((0, 0, 0), (0, 90, 0)), starts_per_theta=2)
    rc = RefineConfig(iterations=20)
    a = generate_candidates(GraspGenConfig(seed=3, **cfg), refine_config=rc, log=lambda *_: None)
    b = generate_candidates(GraspGenConfig(seed=3, **cfg), refine_config=rc, log=lambda *_: None)
    c = generate_candidates(GraspGenConfig(seed=4, **cfg), refine_config=rc, log=lambda *_: None)
    for name in ("R_global", "trans", "angles", "energy"):
        np.testing.assert_array_equal(getattr(a["grasps"], name), getattr(b["grasps"], name))
    assert not np.allclose(a["grasps"].trans, c["grasps"].trans)


@pytest.mark.parametrize("theta", [(0, 90, 0), (0, -90, 0), (0, 0, 0), (360, 360, 360), (90, 0, 0)])
def test_orientations_including_gimbal_lock(models, theta):
    out = generate_candidates(GraspGenConfig(theta_vol_deg=(theta,), starts_per_theta=2),
                              refine_config=RefineConfig(iterations=20), log=lambda *_: None)
    assert np.all(np.isfinite(out["grasps"].trans))


def test_selection_errors_name_the_problem(models):
    hand, _ = models
    out = generate_candidates(GraspGenConfig(starts_per_theta=2), refine_config=RefineConfig(iterations=5),
                              log=lambda *_: None)
    with pytest.raises(ValueError, match=r"cannot select 5 grasps: only \d+ of 2 candidates are plausible"):
        select_grasps(out, hand, 5, 0)
    np.testing.assert_array_equal(select_grasps(out, hand, 1, 0, pinned_ids=(1,)), [1])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(theta_vol_deg=((0, 0),)), "Theta_Vol"),
        (dict(theta_vol_deg=()), "Theta_Vol"),
        (dict(sampler="gan"), "sampler must be one of"),
        (dict(n_select=0), "n_select must be a whole number >= 1"),
        (dict(pinned_ids=("a",)), "pinned_ids must be a non-empty list of ints"),
        (dict(pinned_ids=(1, 1)), r"pinned_ids must be unique, got \[1, 1\]"),
        (dict(starts_per_theta=5000), r"starts_per_theta must be at most 4,096 .*, got 5,000"),
        (dict(short_refine_iterations=-1), "short_refine_iterations must be a whole number >= 0, got -1"),
        (dict(short_refine_iterations=10**6), "short_refine_iterations must be at most 100,000, got 1,000,000"),
        (dict(seed=-1), "seed must be a whole number from 0 to 4294967295, got -1"),
        (dict(theta_vol_deg=((0, 0, 1e9),)), r"Theta_Vol angles must be degrees in \[-360, 360\]"),
    ],
)
def test_bad_generation_config(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GraspGenConfig(**kwargs)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(iterations=True), "iterations must be a whole number >= 0, got True"),
        (dict(iterations=10**6), "iterations must be at most 100,000, got 1,000,000"),
        (dict(lr_joints=0.0), "lr_joints must be positive and finite, got 0.0"),
        (dict(clip_norm=float("nan")), "clip_norm must be positive and finite, got nan"),
        (dict(w_contact=-1.0), "w_contact must be finite and >= 0, got -1.0"),
        (dict(w_self="heavy"), "w_self must be finite and >= 0, got 'heavy'"),
        (dict(min_contact_z_m=float("nan")), "min_contact_z_m must be a finite height in metres or null, got nan"),
    ],
)
def test_bad_refine_config(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RefineConfig(**kwargs)

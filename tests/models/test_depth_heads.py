"""HUPNet's depth-reading heads: depth_anchor (each keypoint's depth from the measured surface) and
probe_head rigid (the probe box posed by a rotation), and the 6D rotation they use."""

import itertools

import numpy as np
import pytest
import torch

from hupbench.core import keypoints as kp
from hupbench.training.loop import probe_half_extents
from hupbench.models.build import build_model
from hupbench.models.heatmap import CORNER_SIGNS, HUPNet, HUPNetConfig, rotation_from_6d

K_64 = [[120.0, 0.0, 31.5], [0.0, 110.0, 30.0], [0.0, 0.0, 1.0]]
MEAN = [[0.01 * (k % 5), -0.01 * (k % 3), 0.5 + 0.005 * k] for k in range(29)]
EXTENTS = (0.036, 0.015, 0.0825)


def hupnet(**kw):
    return HUPNet(HUPNetConfig(**({"backbone": "resnet10", "K_input": K_64, "input_size": 64, "points3d_mean": MEAN,
                                   "points3d_scale": 0.01, "input_channels": 4, "depth_anchor": True} | kw)))


def rgbd(batch=2, depth_m=0.55, seed=0):
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(batch, 4, 64, 64, generator=g)
    images[:, 3] = 0.0
    images[:, 3, 16:48, 20:44] = depth_m       # a surface in the middle, nothing elsewhere
    return images


def test_corner_signs_follow_the_keypoint_order():
    assert CORNER_SIGNS == tuple(tuple(2.0 * b - 1.0 for b in bits) for bits in kp.CORNER_BITS)


def test_rotation_from_6d_is_a_proper_rotation_even_near_degenerate():
    six = torch.cat([torch.randn(64, 6, generator=torch.Generator().manual_seed(0)),
                     torch.tensor([[1.0, 0, 0, 1.0, 1e-9, 0], [1.0, 0, 0, -1.0, 0, 0], [0.0, 0, 0, 0, 0, 0]])])
    R = rotation_from_6d(six)
    assert torch.isfinite(R).all()
    ok = R[:-3]  # the last three are (anti)parallel or zero: finite is all that is asked
    torch.testing.assert_close(ok @ ok.transpose(1, 2), torch.eye(3).expand(len(ok), 3, 3), atol=1e-5, rtol=0)
    torch.testing.assert_close(torch.linalg.det(ok), torch.ones(len(ok)), atol=1e-5, rtol=0)
    torch.testing.assert_close(rotation_from_6d(torch.tensor([[1.0, 0, 0, 0, 1, 0]])), torch.eye(3)[None])


def test_depth_anchor_starts_at_the_seen_surface_and_stays_finite_without_one():
    model = hupnet().eval()
    with torch.no_grad():
        seen = model(rgbd(depth_m=0.55)).points3d
        empty = model(torch.cat([torch.rand(1, 3, 64, 64), torch.zeros(1, 1, 64, 64)], dim=1)).points3d
    torch.testing.assert_close(seen[..., 2], torch.full((2, 29), 0.55), atol=1e-3, rtol=0)  # zero heads: the mean
    assert torch.isfinite(empty).all()
    # the depth follows the measurement: the same image 10 cm further gives points 10 cm further
    with torch.no_grad():
        further = model(rgbd(depth_m=0.65)).points3d
    torch.testing.assert_close(further[..., 2] - seen[..., 2], torch.full((2, 29), 0.10), atol=2e-3, rtol=0)


def test_depth_anchor_needs_a_depth_input():
    with pytest.raises(ValueError, match="depth_anchor reads the depth channel: it needs data.reader.input_modalities"):
        hupnet(input_channels=3)


def test_the_rigid_probe_is_the_box_and_projects_onto_its_2d():
    model = hupnet(probe_head="rigid", probe_half_extents=EXTENTS).eval()
    with torch.no_grad():
        for p in model.probe_rotation.parameters():  # a turn away from the mean layout's
            p.normal_(0.0, 0.3)
        out = model(rgbd(batch=3))
    corners = out.points3d[:, -8:].double()
    box = torch.tensor(CORNER_SIGNS, dtype=torch.float64) * torch.tensor(EXTENTS, dtype=torch.float64)
    for a, b in itertools.combinations(range(8), 2):  # every pairwise distance of the box, in every frame
        torch.testing.assert_close((corners[:, a] - corners[:, b]).norm(dim=-1),
                                   (box[a] - box[b]).norm().expand(3), atol=1e-5, rtol=0)
    f = torch.tensor([K_64[0][0], K_64[1][1]], dtype=torch.float64)
    c = torch.tensor([K_64[0][2], K_64[1][2]], dtype=torch.float64)
    uv = corners[..., :2] / corners[..., 2:] * f + c                      # pixels, independent of the model's code
    torch.testing.assert_close(((out.points2d[:, -8:].double() + 1.0) * 64 - 1.0) / 2.0, uv, atol=1e-3, rtol=0)
    assert out.points2d_init.shape == (3, 29, 2)
    torch.testing.assert_close(out.points2d_init[:, :21], out.points2d[:, :21])  # the hand is unchanged


def test_rigid_probe_gradients_reach_the_rotation_head():
    model = hupnet(probe_head="rigid", probe_half_extents=EXTENTS).train()
    out = model(rgbd())
    out.points3d[:, -8:].square().sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.probe_rotation.parameters())


def test_rigid_probe_config_checks():
    with pytest.raises(ValueError, match="probe_head must be 'corners' or 'rigid', got 'box'"):
        HUPNetConfig(probe_head="box")
    with pytest.raises(ValueError, match="probe_half_extents must be 3 positive finite numbers"):
        HUPNetConfig(probe_half_extents=(0.1, -0.1, 0.1))
    with pytest.raises(ValueError, match="needs probe_half_extents"):
        hupnet(probe_head="rigid")
    model = hupnet(probe_head="rigid", probe_half_extents=EXTENTS)
    rebuilt = build_model(model.config.saved())
    assert rebuilt.config == model.config


def test_probe_half_extents_from_posed_boxes():
    rng = np.random.default_rng(0)
    box = np.array(CORNER_SIGNS) * np.array(EXTENTS)
    frames = []
    for _ in range(5):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.linalg.det(q))
        frames.append(box @ q.T + rng.normal(size=3))
    np.testing.assert_allclose(probe_half_extents(np.stack(frames)), EXTENTS, atol=1e-12)


def test_the_probe_crop_is_the_full_resolution_pixels_around_its_centre():
    """At a pixel-aligned centre the crop's bilinear samples are the input's pixels exactly; the backbone sees
    the input at half size and the canvas cells are 16 input pixels."""
    model = hupnet(input_size=128, K_input=[[240.0, 0.0, 63.5], [0.0, 240.0, 63.5], [0.0, 0.0, 1.0]],
                   backbone_size=64, probe_head="rigid", probe_half_extents=EXTENTS, probe_crop_px=32).eval()
    assert model.factor == 2 and model.stride == 16 and model.grid.shape == (8 + 2 * 2,)
    images = torch.rand(1, 4, 128, 128)
    where = torch.zeros(1, 1, 1, 2) + model.crop_offsets                  # centre (0, 0): pixels 48..79
    crop = torch.nn.functional.grid_sample(images, where, mode="bilinear", align_corners=False)
    torch.testing.assert_close(crop, images[..., 48:80, 48:80])
    with torch.no_grad():
        out = model(rgbd(batch=2).repeat_interleave(2, -1).repeat_interleave(2, -2))
    assert out.points3d.shape == (2, 29, 3) and torch.isfinite(out.points3d).all()


def test_backbone_size_and_crop_checks():
    K = [[240.0, 0.0, 63.5], [0.0, 240.0, 63.5], [0.0, 0.0, 1.0]]
    with pytest.raises(ValueError, match="backbone_size must divide input_size 128 and be a multiple of 8, got 48"):
        HUPNetConfig(K_input=K, input_size=128, backbone_size=48)
    with pytest.raises(ValueError, match="probe_crop_px feeds the rigid probe head"):
        HUPNetConfig(probe_crop_px=32)
    with pytest.raises(ValueError, match="probe_crop_px must be at most input_size 128"):
        HUPNetConfig(K_input=K, input_size=128, probe_head="rigid", probe_crop_px=256)

"""Lifting through the input camera: HOPE-Net's lift="camera", HUPNet, soft-argmax, unprojection."""

import numpy as np
import pytest
import torch

from hupbench.models.build import build_model
from hupbench.models.coords import normalized_to_pixels
from hupbench.models.heatmap import HUPNet, HUPNetConfig, soft_argmax
from hupbench.models.model_config import check_camera
from hupbench.models.hopenet import GraphLifter, HOPENet, HOPENetConfig, normalized_intrinsics, unproject_normalized

K_64 = [[120.0, 0.0, 31.5], [0.0, 110.0, 30.0], [0.0, 0.0, 1.0]]  # input camera of a 64 px model
MEAN = [[0.01 * (k % 5), -0.01 * (k % 3), 0.5 + 0.005 * k] for k in range(29)]


def project_px(points3d, K):
    """(B, N, 3) camera-frame points -> (B, N, 2) pixels, float64 (independent of the models' code)."""
    K = torch.as_tensor(K, dtype=torch.float64)
    uvw = points3d.double() @ K.T
    return uvw[..., :2] / uvw[..., 2:]


def test_normalized_intrinsics_match_pixel_projection():
    rng = np.random.default_rng(0)
    points = torch.from_numpy(rng.uniform([-0.2, -0.2, 0.3], [0.2, 0.2, 1.0], (1, 50, 3)))
    f_c = normalized_intrinsics(K_64, 64).double()
    norm = points[..., :2] / points[..., 2:] * f_c[:2] + f_c[2:]
    torch.testing.assert_close(normalized_to_pixels(norm, 64, 64), project_px(points, K_64))
    # unprojection inverts it
    torch.testing.assert_close(unproject_normalized(norm, points[..., 2], f_c), points)
    with pytest.raises(ValueError, match="K_input must be a finite"):
        check_camera([[0.0, 0, 1], [0, 1, 1], [0, 0, 1]], 64)
    with pytest.raises(ValueError, match="input_size must be a whole number >= 1, got 0"):
        check_camera(K_64, 0)


def test_soft_argmax_known_values():
    grid = torch.tensor([-1.0, 0.0, 1.0])
    logits = torch.full((1, 2, 3, 3), -1e4)
    logits[0, 0, 2, 0] = 0.0                       # all mass at x = -1, y = +1
    logits[0, 1, 0, 1] = logits[0, 1, 0, 2] = 0.0  # half at (0, -1), half at (1, -1)
    values = torch.arange(18.0).reshape(1, 2, 3, 3)
    xy, expected = soft_argmax(logits, grid, grid, values)
    torch.testing.assert_close(xy, torch.tensor([[[-1.0, 1.0], [0.5, -1.0]]]))
    torch.testing.assert_close(expected, torch.tensor([[6.0, (10.0 + 11.0) / 2]]))
    # uniform logits: the centre of the grid, the mean value
    xy, expected = soft_argmax(torch.zeros(1, 1, 3, 3), grid, grid, torch.ones(1, 1, 3, 3) * 2)
    torch.testing.assert_close(xy, torch.zeros(1, 1, 2)), torch.testing.assert_close(expected, torch.tensor([[2.0]]))


def test_camera_lift_points_project_onto_their_2d():
    """HOPE-Net with lift="camera": points3d projects exactly onto the corrected 2D points."""
    torch.manual_seed(0)
    model = HOPENet(HOPENetConfig(backbone="resnet10", lift="camera", K_input=K_64, input_size=64,
                                  points3d_mean=MEAN, points3d_scale=0.01)).eval()
    with torch.no_grad():
        out = model(torch.rand(3, 3, 64, 64))
        raw = model.unet(out.points2d)
    corrected = out.points2d + raw[..., :2] * 0.01
    torch.testing.assert_close(project_px(out.points3d, K_64).float(), normalized_to_pixels(corrected, 64, 64),
                               atol=1e-3, rtol=0)
    # moving the 2D input moves the 3D output as a pinhole camera does (here the U-Net is bypassed:
    # a lifter whose raw output is zero returns the prior depth at the 2D points)
    lifter = GraphLifter(lift="camera", points3d_mean=MEAN, points3d_scale=0.01, K_input=K_64, input_size=64)
    for p in lifter.unet.parameters():
        torch.nn.init.zeros_(p)
    points2d = torch.rand(2, 29, 2) * 2 - 1
    lifted = lifter(points2d)
    torch.testing.assert_close(lifted[..., 2], torch.tensor(MEAN)[:, 2].expand(2, -1))
    torch.testing.assert_close(project_px(lifted, K_64).float(), normalized_to_pixels(points2d, 64, 64), atol=1e-3, rtol=0)


def test_direct_lift_is_the_published_hopenet():
    model = HOPENet(HOPENetConfig(backbone="resnet10"))
    assert model.config.lift == "direct" and model.intrinsics is None
    camera = HOPENetConfig(backbone="resnet10", lift="camera", K_input=K_64, input_size=64)
    assert set(model.state_dict()) == set(HOPENet(camera).state_dict()) - {"intrinsics"}
    with pytest.raises(ValueError, match="lift='camera' needs K_input"):
        HOPENet(HOPENetConfig(lift="camera"))
    with pytest.raises(ValueError, match="lift must be 'direct' or 'camera', got 'mirror'"):
        HOPENetConfig(lift="mirror")


def hupnet(**kw):
    return HUPNet(HUPNetConfig(**({"backbone": "resnet10", "K_input": K_64, "input_size": 64, "points3d_mean": MEAN,
                                   "points3d_scale": 0.01} | kw)))


@pytest.mark.parametrize("batch, stride", [(1, 8), (3, 8), (2, 4)])
def test_hupnet_outputs_project_onto_their_2d(batch, stride):
    torch.manual_seed(1)
    model = hupnet(heatmap_stride=stride).eval()
    with torch.no_grad():
        out = model(torch.rand(batch, 3, 64, 64))
    assert out.points2d.shape == (batch, 29, 2) and out.points3d.shape == (batch, 29, 3)
    torch.testing.assert_close(project_px(out.points3d, K_64).float(), normalized_to_pixels(out.points2d, 64, 64),
                               atol=1e-3, rtol=0)
    # at initialisation: depths are the prior's, 2D near the canvas centre
    torch.testing.assert_close(out.points3d[..., 2], torch.tensor(MEAN)[:, 2].expand(batch, -1), atol=1e-3, rtol=0)


def test_hupnet_canvas_reaches_beyond_the_image():
    model = hupnet(canvas_margin=0.25)       # 64 px -> 8 cells, 2 more on each side
    assert model.margin_cells == 2 and model.grid.shape == (12,)
    torch.testing.assert_close(model.grid[[0, 2, -1]], torch.tensor([-1.375, -0.875, 1.375]))
    # a heatmap peaked on a margin cell puts the point outside the image
    with torch.no_grad():
        for p in (model.heatmap.weight, model.heatmap.bias):
            p.zero_()
    xy, _ = soft_argmax(torch.full((1, 1, 12, 12), -1e4).index_put_((torch.tensor([0]), torch.tensor([0]),
                                                                    torch.tensor([5]), torch.tensor([0])),
                                                                   torch.tensor(0.0)), model.grid, model.grid)
    assert float(xy[0, 0, 0]) == pytest.approx(-1.375) and float(xy[0, 0, 0]) < -1.0


def test_hupnet_stride_4_canvas_halves_the_cells_and_keeps_the_margin():
    model = hupnet(canvas_margin=0.25, heatmap_stride=4)   # 64 px -> 16 cells, 4 more on each side
    assert model.margin_cells == 4 and model.grid.shape == (24,) and model.stride == 4
    torch.testing.assert_close(model.grid[[0, 4, -1]], torch.tensor([-1.4375, -0.9375, 1.4375]))
    # the stride-8 canvas it is built from reaches as far: its outer edge is the same
    assert float(model.grid8[0] - 1 / 8) == pytest.approx(float(model.grid[0] - 1 / 16))
    with torch.no_grad():
        out = model(torch.rand(2, 3, 64, 64))
    assert torch.isfinite(out.points3d).all()
    with pytest.raises(ValueError, match="heatmap_stride must be 4 or 8"):
        hupnet(heatmap_stride=2)


@pytest.mark.parametrize("stride", [8, 4])
def test_hupnet_learns_a_point_and_its_depth(stride):
    """A few Adam steps on one image pull the 2D and 3D outputs onto a target (gradients reach both heads)."""
    torch.manual_seed(0)
    model = hupnet(backbone="resnet10", heatmap_stride=stride).train()
    images = torch.rand(4, 3, 64, 64)
    target2d = torch.full((4, 29, 2), 0.3)
    target_depth = torch.full((4, 29), 0.6)
    f_c = normalized_intrinsics(K_64, 64)
    target3d = unproject_normalized(target2d, target_depth, f_c)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    first = None
    for _ in range(60):
        out = model(images)
        loss = ((out.points3d - target3d) / 0.01).square().mean() + 100 * (out.points2d - target2d).square().mean()
        first = float(loss.detach()) if first is None else first
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert float(loss.detach()) < 0.05 * first


def test_hupnet_builds_from_its_config_and_checks_input():
    model = hupnet()
    rebuilt = build_model(model.config.saved())
    assert rebuilt.config == model.config
    with pytest.raises(ValueError, match=r"images must be \(B, 3, 64, 64\) \(the model's input size\), got \(1, 3, 32, 32\)"):
        model(torch.rand(1, 3, 32, 32))
    with pytest.raises(ValueError, match="HUPNet unprojects through the input camera"):
        HUPNet(HUPNetConfig())
    with pytest.raises(ValueError, match="input_size must be a positive multiple of 8, got 60"):
        hupnet(input_size=60)
    with pytest.raises(ValueError, match="canvas_margin must be a finite number in \\[0, 2\\]"):
        hupnet(canvas_margin=-0.1)


def test_hupnet_bf16_autocast_and_channels_last():
    torch.manual_seed(0)
    model = hupnet().eval()
    images = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        ref = model(images)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = model(images)
        cl = model.to(memory_format=torch.channels_last)(images.contiguous(memory_format=torch.channels_last))
    # soft-argmax runs in float32 under autocast: bf16 only enters through the features
    assert (low.points3d.float() - ref.points3d).abs().max() < 2e-3
    assert (cl.points3d - ref.points3d).abs().max() < 1e-5

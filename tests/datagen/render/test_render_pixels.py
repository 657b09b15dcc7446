"""The rendered pixels agree with the labels' pixel convention (pixel centres at integers).

Ground truth is independent of the renderer: per pixel, does the ray through the pixel's centre
(integer coordinates, through the inverse of K) hit the sphere? GL fills a pixel of a label mask
when its centre lies inside a triangle, so the rendered mask's centroid must match the centroid of
those pixel centres.
"""

import numpy as np
import pytest
import trimesh

from hupbench.core.camera import Intrinsics, project_points
from hupbench.datagen.render.renderer import SEG_LABELS, MeshPart, Renderer

#: the largest centroid disagreement allowed, pixels (a half-pixel convention error is ten times this)
CENTROID_TOL_PX = 0.05


def _ray_hit_centroid(intrinsics: Intrinsics, centre_cam: np.ndarray, radius_m: float, samples: int = 1) -> np.ndarray:
    """(2,) centroid of the pixels, weighted by the share of their ``samples`` x ``samples`` sub-pixel
    rays that meet the sphere (1: the pixel's centre alone), in pixel-centre coordinates."""
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64), np.arange(intrinsics.height, dtype=np.float64))
    coverage = np.zeros(u.shape)
    for du in (np.arange(samples) + 0.5) / samples - 0.5:
        for dv in (np.arange(samples) + 0.5) / samples - 0.5:
            rays = np.stack([(u + du - intrinsics.cx) / intrinsics.fx, (v + dv - intrinsics.cy) / intrinsics.fy,
                             np.ones(u.shape)], -1)
            rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
            along = rays @ centre_cam
            coverage += (centre_cam @ centre_cam - along ** 2 < radius_m ** 2) & (along > 0)
    return np.array([(u * coverage).sum(), (v * coverage).sum()]) / coverage.sum()


def _camera_at_origin() -> np.ndarray:
    return np.eye(4)  # the OpenCV camera frame is the world frame


@pytest.mark.parametrize("intrinsics", [
    Intrinsics(480.0, 480.0, 128.0, 128.0, 256, 256),
    Intrinsics(240.0, 240.0, 64.0, 64.0, 128, 128),
    Intrinsics(300.0, 310.0, 90.0, 70.0, 200, 150),  # not square, principal point off the middle
], ids=["256px", "128px", "200x150"])
@pytest.mark.parametrize("offset_px", [(0.0, 0.0), (37.3, -21.6), (-48.2, 30.9)], ids=["axis", "off1", "off2"])
def test_sphere_mask_centroid_matches_projection(intrinsics, offset_px):
    depth_m = 0.5
    radius_m = 12.0 / intrinsics.fx * depth_m  # about 12 px across the radius
    centre_cam = np.array([offset_px[0] * depth_m / intrinsics.fx, offset_px[1] * depth_m / intrinsics.fy, depth_m])
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=radius_m)
    sphere.apply_translation(centre_cam)
    with Renderer(intrinsics) as renderer:
        renderer.set_parts([MeshPart("ball", sphere, SEG_LABELS["probe"])])
        out = renderer.render(_camera_at_origin(), ("seg", "rgb"), alpha=True)
    rows, cols = np.nonzero(out["seg"] == SEG_LABELS["probe"])
    centroid = np.array([cols.mean(), rows.mean()])
    np.testing.assert_allclose(centroid, _ray_hit_centroid(intrinsics, centre_cam, radius_m), atol=CENTROID_TOL_PX)
    # the anti-aliased colour pass sits where the mask does: its alpha against the sub-pixel coverage
    alpha = out["rgb"][..., 3].astype(np.float64)
    v, u = np.mgrid[:intrinsics.height, :intrinsics.width]
    alpha_centroid = np.array([(u * alpha).sum(), (v * alpha).sum()]) / alpha.sum()
    np.testing.assert_allclose(alpha_centroid, _ray_hit_centroid(intrinsics, centre_cam, radius_m, samples=8),
                               atol=CENTROID_TOL_PX)
    if offset_px == (0.0, 0.0):  # on the axis the image of a sphere is a disc round the projected centre
        projected = project_points(centre_cam[None], intrinsics.K)[0]
        np.testing.assert_allclose(projected, [intrinsics.cx, intrinsics.cy])
        np.testing.assert_allclose(centroid, projected, atol=CENTROID_TOL_PX)
        np.testing.assert_allclose(alpha_centroid, projected, atol=CENTROID_TOL_PX)

"""Tests for the procedural ultrasound probe (datagen/assets/probe.py).

trimesh is the independent ground truth for the signed distance: the probe
computes its own exact point-to-triangle distances and signs, trimesh uses
its own closest-point search and ray tests (with the opposite sign).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from hupbench.core.keypoints import CORNER_BITS
from hupbench.datagen.assets.probe import Probe, ProbeSpec, build_probe
from hupbench.datagen.mesh_distance import FEATURE_EAB, FEATURE_FACE, FEATURE_VA, closest_points_on_triangles

MM = 1e-3


@pytest.fixture(scope="module")
def probe() -> Probe:
    return build_probe()


@pytest.fixture(scope="module")
def plain() -> Probe:
    """The probe without its orientation marker (coarse grid: only the mesh and exact distances are used)."""
    return build_probe(dataclasses.replace(ProbeSpec(), marker_height=0.0, sdf_spacing=0.004))


#: the half turn about the probe's long axis z: (x, y, z) -> (-x, -y, z)
HALF_TURN = np.diag([-1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def random_points(probe: Probe) -> np.ndarray:
    """(2000, 3) points uniform in the bounding box + 30 mm, probe frame."""
    lo, hi = probe.mesh.bounds
    return np.random.default_rng(0).uniform(lo - 0.03, hi + 0.03, size=(2000, 3))


@pytest.fixture(scope="module")
def trimesh_sdf(probe: Probe, random_points: np.ndarray) -> np.ndarray:
    # trimesh is positive inside: negate to our convention
    return -trimesh.proximity.signed_distance(probe.mesh, random_points)


@pytest.fixture(scope="module")
def surface_samples(probe: Probe) -> tuple[np.ndarray, np.ndarray]:
    points, face = trimesh.sample.sample_surface(probe.mesh, 2000, seed=1)
    return np.asarray(points), np.asarray(face)


def _extent_mm(vertices: np.ndarray, axis: int) -> float:
    return float(np.ptp(vertices[:, axis]) / MM)


# ---------------------------------------------------------------- mesh


def test_mesh_is_closed_outward_and_within_budget(probe: Probe) -> None:
    mesh = probe.mesh
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0
    # 11,360 faces for the sweep and about 1,650 more for the refined patch under the marker
    assert len(mesh.faces) <= 14_000
    # a probe about 165 x 72 x 28 mm holds roughly 100-200 cm^3
    assert 100e-6 < mesh.volume < 200e-6
    assert np.all(mesh.area_faces > 0)


def _mirrored(v: np.ndarray, flip) -> np.ndarray:
    """(V,) bool: which vertices have their mirror image ``v * flip`` among the vertices."""
    key = {tuple(row) for row in np.round(v, 12)}
    return np.array([tuple(row) in key for row in np.round(v * flip, 12)])


def test_mesh_is_mirror_symmetric_except_for_the_marker(probe: Probe, plain: Probe) -> None:
    # without the marker: symmetric about x = 0 and y = 0
    for flip in ([-1, 1, 1], [1, -1, 1]):
        assert _mirrored(plain.mesh.vertices, flip).all()
    # with it: still about y = 0 (the marker is centred on y = 0) ...
    v = probe.mesh.vertices
    assert _mirrored(v, [1, -1, 1]).all()
    # ... but not about x = 0: the refined patch on the +x end and the housing vertices facing it on the -x
    # end lose their mirror image, nothing else
    lost = ~_mirrored(v, [-1, 1, 1])
    assert lost.sum() > 100
    assert np.abs(v[lost, 0]).min() > 0.015 and np.abs(v[lost, 1]).max() < 0.013
    assert 0.02 < v[lost, 2].min() and v[lost, 2].max() < 0.045
    raised = plain.signed_distance_exact(v) > 1e-6
    assert raised.sum() > 50 and lost[raised].all()


def test_half_turned_mesh_differs_by_the_marker_height(probe: Probe, plain: Probe) -> None:
    # symmetric Hausdorff distance between the surface and its half-turned copy, sampled at the vertices:
    # the half turn is an involutive isometry, so max_v d(R v, S) covers both directions
    assert probe.spec.marker_height == pytest.approx(0.002)
    turned = probe.mesh.vertices @ HALF_TURN.T
    hausdorff = np.abs(probe.signed_distance_exact(turned)).max()
    assert hausdorff == pytest.approx(probe.spec.marker_height, abs=0.05 * MM)
    # the same through trimesh's own closest points
    _, dist, _ = trimesh.proximity.closest_point(probe.mesh, turned)
    assert dist.max() == pytest.approx(hausdorff, abs=1e-6)
    # without the marker the half turn maps the mesh onto itself
    plain_turned = plain.mesh.vertices @ HALF_TURN.T
    assert np.abs(plain.signed_distance_exact(plain_turned)).max() < 1e-12
    assert _mirrored(plain.mesh.vertices, [-1, -1, 1]).all()


def test_marker_is_on_the_plus_x_end_of_the_head(probe: Probe, plain: Probe) -> None:
    spec, mesh = probe.spec, probe.mesh
    marker = probe.marker_face_mask
    assert marker.dtype == bool and marker.shape == (len(mesh.faces),)
    assert not (marker & probe.lens_face_mask).any()
    v = mesh.vertices[np.unique(mesh.faces[marker])]
    # documented side: +x, centred on y = 0, on the head's shoulder around marker_z
    assert v[:, 0].min() > 0.02
    np.testing.assert_allclose(v[:, 1].max(), -v[:, 1].min(), atol=1e-12)
    # the width is measured around the rounded end, so the marker reaches a little less far in y
    assert 0.8 * spec.marker_width / 2 < v[:, 1].max() < spec.marker_width / 2
    assert v[:, 2].min() > probe.region_z.lens[1] and v[:, 2].max() < probe.region_z.head[1]
    assert v[:, 2].min() < spec.marker_z < v[:, 2].max()
    # its area is about that of the flat 14 x 20 mm stadium, plus what the slopes of the rounded pad add
    rim = min(spec.marker_length, spec.marker_width) / 2
    stadium = spec.marker_length * spec.marker_width - (4 - np.pi) * rim**2
    assert stadium < mesh.area_faces[marker].sum() < 1.3 * stadium
    # the pad stands marker_height proud of the housing it was moulded into (up to the sweep's chords)
    assert plain.signed_distance_exact(v).max() == pytest.approx(spec.marker_height, abs=0.05 * MM)
    # nothing changed on the -x end
    far = mesh.vertices[:, 0] < 0
    assert np.abs(plain.signed_distance_exact(mesh.vertices[far])).max() < 1e-12


def test_marker_keeps_box_lens_and_regions(probe: Probe, plain: Probe) -> None:
    np.testing.assert_array_equal(probe.corners_probe, plain.corners_probe)
    np.testing.assert_array_equal(probe.mesh.bounds, plain.mesh.bounds)
    assert probe.region_z == plain.region_z
    lens = probe.mesh.triangles[probe.lens_face_mask]
    plain_lens = plain.mesh.triangles[plain.lens_face_mask]
    np.testing.assert_array_equal(np.sort(lens.reshape(-1, 9), axis=0), np.sort(plain_lens.reshape(-1, 9), axis=0))


def test_signed_distance_sign_at_the_marker(probe: Probe, plain: Probe) -> None:
    mesh = probe.mesh
    top = np.unique(mesh.faces[probe.marker_face_mask])
    height = plain.signed_distance_exact(mesh.vertices[top])
    top = top[height > 0.9 * probe.spec.marker_height]  # the pad's flat top
    assert len(top) > 10
    normal = mesh.vertex_normals[top]
    inside = mesh.vertices[top] - 1 * MM * normal  # inside the pad, 1 mm above the housing
    outside = mesh.vertices[top] + 1 * MM * normal
    for points, sign in ((inside, -1.0), (outside, 1.0)):
        exact = probe.signed_distance_exact(points)
        # 1 mm along the vertex normal is 1 mm from the surface up to the pad's curvature
        np.testing.assert_allclose(exact, sign * 1 * MM, atol=0.1 * MM)
        np.testing.assert_allclose(probe.signed_distance(points), exact, atol=0.3 * MM)
        torch_d = probe.signed_distance_torch(torch.tensor(points)).numpy()
        np.testing.assert_allclose(torch_d, probe.signed_distance(points), atol=1e-12)
        # trimesh (positive inside) agrees on the side
        assert np.all(np.sign(-trimesh.proximity.signed_distance(mesh, points)) == sign)
    # without the marker the same inside points are outside the housing; on the -x end they are outside too
    assert np.all(plain.signed_distance_exact(inside) > 0.5 * MM)
    assert np.all(probe.signed_distance(inside @ HALF_TURN.T) > 0.5 * MM)


def test_vertex_normals_are_smooth(probe: Probe) -> None:
    # no creases: every face normal is close to its corners' vertex normals
    mesh = probe.mesh
    cos = np.einsum("fi,fki->fk", mesh.face_normals, mesh.vertex_normals[mesh.faces])
    assert np.quantile(cos, 0.99) > 0.99
    assert cos.min() > 0.9


def test_overall_dimensions(probe: Probe) -> None:
    v = probe.mesh.vertices
    lo, hi = probe.mesh.bounds
    assert lo[2] == pytest.approx(0.0, abs=1e-12)  # the lens apex is the lowest point
    assert hi[2] == pytest.approx(0.165, abs=0.5 * MM)
    assert _extent_mm(v, 0) == pytest.approx(72.0, abs=0.5)  # head width is the widest part
    near_lens = v[v[:, 2] < 8 * MM]
    assert _extent_mm(near_lens, 1) == pytest.approx(22.0, abs=0.5)
    grip = v[(v[:, 2] > 90 * MM) & (v[:, 2] < 110 * MM)]
    assert _extent_mm(grip, 0) == pytest.approx(38.0, abs=1.0)
    assert _extent_mm(grip, 1) == pytest.approx(28.0, abs=1.0)


def test_shape_tapers_from_head_through_neck_to_handle(probe: Probe) -> None:
    v = probe.mesh.vertices

    def width_mm(z_lo: float, z_hi: float) -> float:
        return _extent_mm(v[(v[:, 2] >= z_lo) & (v[:, 2] <= z_hi)], 0)

    head, neck, handle = probe.region_z.head, probe.region_z.neck, probe.region_z.handle
    head_w = width_mm(15 * MM, 22 * MM)
    neck_w = width_mm(*neck)
    handle_w = width_mm(handle[0] + 20 * MM, handle[1] - 20 * MM)
    relief_w = width_mm(*probe.region_z.strain_relief)
    assert head_w > 65 and neck_w < handle_w < head_w
    assert 30 < neck_w < 38 and relief_w < 40
    # the head is a fan: wider at the bottom than at its top
    assert width_mm(head[1] - 4 * MM, head[1]) < 0.6 * head_w


def test_lens_is_the_convex_bottom_cap(probe: Probe) -> None:
    spec, mesh = probe.spec, probe.mesh
    lens = probe.lens_face_mask
    assert lens.dtype == bool and lens.shape == (len(mesh.faces),)
    assert 0 < lens.sum() < len(lens) / 4
    # every lens vertex lies on the cylinder of radius 55 mm through the apex
    v = mesh.vertices[np.unique(mesh.faces[lens])]
    sag = spec.lens_radius - np.sqrt(spec.lens_radius**2 - v[:, 0] ** 2)
    np.testing.assert_allclose(v[:, 2], sag, atol=1e-12)
    # its sagitta matches the 55 mm radius over its half-width
    half_width = np.abs(v[:, 0]).max()
    expected = spec.lens_radius - np.sqrt(spec.lens_radius**2 - half_width**2)
    assert v[:, 2].max() == pytest.approx(expected, abs=1e-9)
    assert probe.region_z.lens[1] == pytest.approx(expected, abs=1e-9)
    assert 10 * MM < expected < 12 * MM
    # the lens faces face down and away from the probe, and the apex is on it
    assert np.all(mesh.face_normals[lens][:, 2] < 0)
    assert np.any(np.all(v == 0.0, axis=1))


def test_regions_are_contiguous_and_ordered(probe: Probe) -> None:
    r = probe.region_z
    assert r.head[0] == 0.0 and r.strain_relief[1] == pytest.approx(probe.spec.length)
    assert r.head[1] == r.neck[0] and r.neck[1] == r.handle[0] and r.handle[1] == r.strain_relief[0]
    for z0, z1 in r:
        assert z0 < z1
    assert r.lens[1] < r.head[1]
    assert set(r._asdict()) == {"lens", "head", "neck", "handle", "strain_relief"}


# ---------------------------------------------------------------- corners


def test_corners_match_trimesh_oriented_box(probe: Probe) -> None:
    corners = probe.corners_probe
    assert corners.shape == (8, 3) and corners.dtype == np.float64
    obb = np.asarray(probe.mesh.bounding_box_oriented.vertices)
    # trimesh orders its corners differently: match as sets
    dist = np.linalg.norm(corners[:, None] - obb[None], axis=-1)
    assert dist.min(axis=1).max() < 0.5 * MM
    assert dist.min(axis=0).max() < 0.5 * MM


def test_corners_follow_documented_order(probe: Probe) -> None:
    lo, hi = probe.mesh.bounds
    for k, bits in enumerate(CORNER_BITS):
        expected = [(lo, hi)[b][axis] for axis, b in enumerate(bits)]
        np.testing.assert_array_equal(probe.corners_probe[k], expected)
    # corner 0 is (-x, -y, z = 0) at the lens end, corner 7 (+x, +y, cable end)
    assert probe.corners_probe[0][2] == 0.0 and probe.corners_probe[7][2] == pytest.approx(0.165, abs=0.5 * MM)


# ---------------------------------------------------------------- signed distance


def test_closest_point_kernel_known_answers() -> None:
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    points = np.array([[0.2, 0.2, 2.0], [-1.0, -1.0, 0.0], [0.5, -2.0, 0.0]])
    sq, bary, feature = closest_points_on_triangles(points, a, b, c)
    np.testing.assert_allclose(sq, [4.0, 2.0, 4.0])
    np.testing.assert_allclose(bary, [[0.6, 0.2, 0.2], [1, 0, 0], [0.5, 0.5, 0]])
    assert list(feature) == [FEATURE_FACE, FEATURE_VA, FEATURE_EAB]


def test_grid_nodes_are_exact(probe: Probe) -> None:
    rng = np.random.default_rng(2)
    idx = rng.integers(0, probe.sdf_grid.shape, size=(120, 3))
    # nodes near the surface and inside are where culling mistakes would show
    near = np.argwhere(np.abs(probe.sdf_grid) < 3 * MM)
    idx = np.concatenate([idx, near[rng.choice(len(near), 60, replace=False)]])
    nodes = probe.sdf_origin + probe.sdf_spacing * idx
    stored = probe.sdf_grid[idx[:, 0], idx[:, 1], idx[:, 2]]
    # interpolating at a node returns the node value
    np.testing.assert_allclose(probe.signed_distance(nodes), stored, atol=1e-12)
    # brute force over every triangle, no culling
    a, b, c = (probe.mesh.triangles[None, :, k] for k in range(3))
    brute = np.concatenate(
        [closest_points_on_triangles(chunk[:, None], a, b, c)[0].min(axis=1) for chunk in np.array_split(nodes, 12)]
    )
    np.testing.assert_allclose(np.abs(stored), np.sqrt(brute), atol=1e-12)
    # and trimesh, which agrees to its own closest-point accuracy
    reference = -trimesh.proximity.signed_distance(probe.mesh, nodes)
    np.testing.assert_allclose(stored, reference, atol=1e-4)


def test_signed_distance_matches_trimesh(probe: Probe, random_points: np.ndarray, trimesh_sdf: np.ndarray) -> None:
    d = probe.signed_distance(random_points)
    assert d.shape == (2000,) and d.dtype == np.float64
    err = np.abs(d - trimesh_sdf)
    assert err.max() < 1 * MM
    assert np.median(err) < 0.05 * MM
    clear = np.abs(trimesh_sdf) > 1 * MM
    assert clear.sum() > 1500
    np.testing.assert_array_equal(np.sign(d[clear]), np.sign(trimesh_sdf[clear]))
    assert np.sum(trimesh_sdf < -1 * MM) > 20  # the test really covers the inside


def test_exact_signed_distance_matches_trimesh(probe: Probe, random_points: np.ndarray,
                                                trimesh_sdf: np.ndarray) -> None:
    d = probe.signed_distance_exact(random_points[:300])
    np.testing.assert_allclose(d, trimesh_sdf[:300], atol=1e-4)


def test_surface_points_lens_apex_and_far_points(probe: Probe, surface_samples) -> None:
    points, _ = surface_samples
    assert np.abs(probe.signed_distance(points)).max() < 1 * MM
    assert abs(float(probe.signed_distance(np.zeros(3)))) < 1e-9
    # just below the apex is outside, just above is inside
    assert probe.signed_distance([0.0, 0.0, -2 * MM]) == pytest.approx(2 * MM, abs=1e-9)
    assert probe.signed_distance([0.0, 0.0, 2 * MM]) < -1 * MM
    # beyond the grid the result is positive and an upper bound of the true distance
    far = np.array([[0.5, 0.0, 0.08], [0.0, -0.4, 0.1], [0.0, 0.0, 1.0], [0.3, 0.3, -0.3]])
    d_far = probe.signed_distance(far)
    true_far = probe.signed_distance_exact(far)
    assert np.all(d_far > 0)
    assert np.all(d_far >= true_far - 1e-9)
    np.testing.assert_allclose(d_far[:3], true_far[:3], rtol=0.05)


@pytest.mark.parametrize("shape", [(3,), (5, 3), (2, 4, 3)])
def test_signed_distance_broadcasts_leading_dims(probe: Probe, random_points: np.ndarray, shape) -> None:
    n = int(np.prod(shape[:-1]))
    pts = random_points[:n].reshape(shape)
    d = probe.signed_distance(pts)
    assert d.shape == shape[:-1]
    np.testing.assert_array_equal(d.reshape(-1), probe.signed_distance(random_points[:n]))


# ---------------------------------------------------------------- torch and normals


@pytest.mark.parametrize("dtype, atol", [(torch.float64, 1e-12), (torch.float32, 1e-6)])
def test_torch_matches_numpy(probe: Probe, random_points: np.ndarray, dtype, atol) -> None:
    far = np.array([[0.5, 0.0, 0.08], [0.0, 0.0, -0.2]])
    pts = np.concatenate([random_points, far])
    out = probe.signed_distance_torch(torch.tensor(pts, dtype=dtype))
    assert out.dtype == dtype and out.shape == (len(pts),)
    np.testing.assert_allclose(out.numpy(), probe.signed_distance(pts), atol=atol)


def test_torch_gradient_points_outward_at_surface(probe: Probe, surface_samples) -> None:
    points, face = surface_samples
    pts = torch.tensor(points, requires_grad=True)
    probe.signed_distance_torch(pts).sum().backward()
    grad = pts.grad.numpy()
    assert np.all(np.isfinite(grad))
    unit = grad / np.linalg.norm(grad, axis=1, keepdims=True)
    dots = np.einsum("ni,ni->n", unit, probe.mesh.face_normals[face])
    assert np.mean(dots > 0.9) > 0.95
    # the numpy normal field is the same gradient, normalised
    np.testing.assert_allclose(probe.surface_normal(points), unit, atol=1e-9)


def test_torch_gradient_is_finite_outside_grid_and_matches_numpy(probe: Probe) -> None:
    pts_np = np.array([[0.5, 0.0, 0.08], [0.01, 0.002, 0.1], [0.0, 0.0, -0.2]])
    pts = torch.tensor(pts_np, requires_grad=True)
    probe.signed_distance_torch(pts).sum().backward()
    assert torch.isfinite(pts.grad).all()
    np.testing.assert_allclose(pts.grad.numpy(), probe.signed_distance_gradient(pts_np), atol=1e-9)
    # far along +x the field grows like the distance along +x; the small
    # remainder is the interpolant's slope along the grid's +x face
    grad_far = pts.grad.numpy()[0]
    assert grad_far[0] == pytest.approx(1.0, abs=1e-9)
    assert np.abs(grad_far[1:]).max() < 0.05


def test_numpy_gradient_matches_finite_differences(probe: Probe) -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(probe.mesh.bounds[0], probe.mesh.bounds[1], size=(50, 3))
    eps = 1e-7  # far below the 1.5 mm cell, so (almost surely) in the same cell
    fd = np.stack(
        [(probe.signed_distance(pts + eps * e) - probe.signed_distance(pts - eps * e)) / (2 * eps) for e in np.eye(3)],
        axis=-1,
    )
    np.testing.assert_allclose(probe.signed_distance_gradient(pts), fd, atol=1e-5)
    n = probe.surface_normal(pts)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)


# ---------------------------------------------------------------- caching and bad specs


def test_build_is_cached(probe: Probe) -> None:
    assert build_probe() is probe
    assert build_probe(ProbeSpec()) is probe
    assert not probe.sdf_grid.flags.writeable


@pytest.mark.parametrize(
    "change, match",
    [
        ({"lens_radius": -0.055}, "lens_radius must be a finite number > 0, got -0.055"),
        ({"head_width": float("nan")}, "head_width must be a finite number > 0, got nan"),
        ({"length": float("inf")}, "length must be a finite number > 0, got inf"),
        ({"sdf_spacing": 0.0}, "sdf_spacing must be a finite number > 0"),
        ({"sdf_margin": -0.01}, "sdf_margin must be a finite number >= 0"),
        ({"n_around": 42}, "n_around must be a multiple of 4"),
        ({"n_around": 80.0}, "n_around must be a whole number"),
        ({"head_width": "wide"}, "head_width must be a finite number > 0, got 'wide'"),
        ({"lens_radius": 0.03}, "lens_radius .* must exceed half the head width"),
        ({"lens_edge_radius": 0.012}, "lens_edge_radius .* must be less than the head.s corner radius"),
        ({"neck_width": 0.05}, "neck_width .* must not exceed"),
        ({"length": 0.09}, "leaves no handle"),
        ({"head_height": 0.008}, "head_height .* too small"),
        ({"n_body_rings": 3}, "ring counts too small"),
        ({"marker_height": -0.001}, "marker_height must be a finite number >= 0"),
        ({"handle_flare": -0.001}, r"ProbeSpec.handle_flare must be a finite number >= 0, got -0.001"),
        ({"marker_subdivisions": 2.5}, "marker_subdivisions must be a whole number"),
        ({"marker_width": 0.005}, "marker_length and marker_width > 2 \\* marker_edge"),
        ({"marker_length": 0.006}, "marker_length and marker_width > 2 \\* marker_edge"),
    ],
)
def test_bad_spec_raises(change, match) -> None:
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(ProbeSpec(), **change)


@pytest.mark.parametrize(
    "change, match",
    [
        ({"marker_z": 0.005}, "must lie on the head's housing|must lie on the housing"),
        ({"marker_z": 0.12}, "must lie on the head's housing"),
        ({"marker_height": 0.01}, "sticks out of the probe's bounding box"),
        ({"marker_length": 0.05}, "must lie on the head's housing"),
        ({"marker_width": 0.03, "marker_length": 0.03}, "sticks out of the probe's bounding box"),
        ({"marker_width": 0.08}, "wider than the head's end"),
    ],
)
def test_misplaced_marker_is_refused(change, match) -> None:
    spec = dataclasses.replace(ProbeSpec(), sdf_spacing=0.004, **change)
    with pytest.raises(ValueError, match=match):
        build_probe(spec)

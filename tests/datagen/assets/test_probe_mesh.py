"""Your own probe: the mesh loader's checks and repairs, the principal-axes alignment and what a mesh probe derives."""

import numpy as np
import pytest
import trimesh

from hupbench.datagen.assets.probe import probe_of
from hupbench.datagen.assets.probe_mesh import (
    REGION_FRACTIONS,
    ProbeMeshSpec,
    ProbeSource,
    align_principal_axes,
    linear_probe_mesh,
    load_probe_mesh,
)
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.keypoints import CORNER_BITS


@pytest.fixture(scope="module")
def linear_stl(tmp_path_factory):
    path = tmp_path_factory.mktemp("probe") / "linear.stl"
    linear_probe_mesh().export(path)
    return path


@pytest.fixture(scope="module")
def linear(linear_stl):
    return probe_of(ProbeSource(str(linear_stl)))


def _spec(path, **kw) -> ProbeMeshSpec:
    return ProbeMeshSpec(str(path), **kw)


def test_linear_probe_derived_geometry(linear):
    # the box: the head's 56 mm width, the handle's 26 mm thickness, 155 mm long, in CORNER_BITS order
    lo, hi = np.array([-0.028, -0.013, 0.0]), np.array([0.028, 0.013, 0.155])
    expected = np.array([[(lo, hi)[b][axis] for axis, b in enumerate(bits)] for bits in CORNER_BITS])
    np.testing.assert_allclose(linear.corners_probe, expected, atol=1e-6)
    # regions by fractions of the length; the lens is the flat bottom face (4 triangles at z = 0)
    assert linear.region_z.neck == pytest.approx((REGION_FRACTIONS["neck"][0] * 0.155,
                                                  REGION_FRACTIONS["neck"][1] * 0.155), abs=1e-6)
    assert linear.lens_face_mask.sum() == 4 and linear.region_z.lens == pytest.approx((0.0, 0.0), abs=1e-6)
    assert np.allclose(linear.mesh.triangles_center[linear.lens_face_mask][:, 2], 0.0, atol=1e-7)
    # the marker patch lies on the head's +x face (x = 28 mm), around z = 0.2 L, just outside the surface
    patch = linear.marker_patch
    assert patch is not None and np.allclose(patch.vertices[:, 0], 0.028 + 0.0005, atol=1e-6)
    assert patch.vertices[:, 2].mean() == pytest.approx(0.2 * 0.155, abs=1e-4)
    assert (patch.face_normals[:, 0] > 0.99).all()
    assert linear.record["kind"] == "mesh" and len(linear.record["sha256"]) == 64


def test_linear_probe_signed_distance_matches_exact(linear):
    rng = np.random.default_rng(0)
    points = rng.uniform(linear.mesh.bounds[0] - 0.01, linear.mesh.bounds[1] + 0.01, (3000, 3))
    exact = -trimesh.proximity.signed_distance(linear.mesh, points)  # trimesh: positive inside
    np.testing.assert_allclose(linear.signed_distance_exact(points), exact, atol=1e-5)  # trimesh errs by microns
    grid = linear.signed_distance(points)
    near = np.abs(exact) < 0.003
    # trilinear interpolation of exact nodes near the surface; farther the sampled distance (half a step)
    assert np.abs(grid - exact)[near].max() < 0.5e-3 and np.abs(grid - exact).max() < 1.0e-3
    assert (np.sign(grid) == np.sign(exact))[np.abs(exact) > 0.002].all()


def test_units_mm_refused_then_accepted(tmp_path):
    path = tmp_path / "linear_mm.stl"
    linear_probe_mesh().apply_scale(1000.0).export(path)
    with pytest.raises(BadValueError, match=r"is 155 m long in m .*probe.mesh_unit=mm"):
        load_probe_mesh(_spec(path))
    mesh = load_probe_mesh(_spec(path, unit="mm"))
    np.testing.assert_allclose(mesh.extents, [0.056, 0.026, 0.155], atol=1e-6)


def test_align_principal_axes_recovers_the_frame(tmp_path):
    mesh = linear_probe_mesh()
    # the handle along y, turned a little more about two other axes
    R = trimesh.transformations.rotation_matrix(np.pi / 2, [1.0, 0.0, 0.0]) \
        @ trimesh.transformations.rotation_matrix(0.3, [0.2, 0.1, 1.0])
    R[:3, 3] = [0.2, -0.1, 0.05]
    turned = mesh.copy()
    turned.apply_transform(R)
    aligned, T = align_principal_axes(turned)
    np.testing.assert_allclose(aligned.extents, mesh.extents, atol=1e-9)
    assert aligned.bounds[0, 2] == pytest.approx(0.0, abs=1e-12)
    # the head (wider) is at the bottom: the face's centre is back at the origin, up to the half turn about z
    np.testing.assert_allclose(np.abs(aligned.bounds), np.abs(mesh.bounds), atol=1e-9)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    path = tmp_path / "turned.ply"
    turned.export(path)
    with pytest.raises(BadValueError, match=r"\+z must run along the handle.*probe.align=true"):
        load_probe_mesh(_spec(path))
    np.testing.assert_allclose(load_probe_mesh(_spec(path, align=True)).extents, mesh.extents, atol=1e-6)


def test_holes_are_filled_and_winding_fixed(tmp_path):
    mesh = linear_probe_mesh()
    faces = mesh.faces.copy()
    faces[5] = faces[5, ::-1]  # one face wound inwards
    holed = trimesh.Trimesh(mesh.vertices, np.delete(faces, 0, axis=0), process=False)  # one bottom triangle gone
    path = tmp_path / "holed.obj"
    holed.export(path)
    repaired = load_probe_mesh(_spec(path))
    assert repaired.is_watertight and repaired.is_winding_consistent
    assert repaired.volume == pytest.approx(mesh.volume, rel=1e-9)


@pytest.mark.parametrize("case, error, message", [
    ("missing", MissingFileError, r"probe.mesh .*nothing.stl not found"),
    ("wrong_suffix", BadValueError, r"must be an .stl, .obj or .ply file, got a .txt file"),
    ("not_a_mesh", BadValueError, r"cannot be read as PLY|holds no triangles"),
    ("empty", BadValueError, r"holds no triangles"),
    ("non_manifold", BadValueError, r"is non-manifold: 1 edge\(s\) are shared by more than two triangles"),
    ("open", BadValueError, r"is not closed"),
    ("tiny", BadValueError, r"too small for a hand to hold.*check probe.mesh_unit"),
])
def test_bad_meshes_one_line(tmp_path, case, error, message):
    mesh = linear_probe_mesh()
    path = tmp_path / {"missing": "nothing.stl", "wrong_suffix": "probe.txt", "not_a_mesh": "probe.ply",
                       "empty": "empty.stl"}.get(case, f"{case}.stl")
    if case == "wrong_suffix":
        path.write_text("solid probe\n")
    elif case == "not_a_mesh":
        path.write_bytes(b"this is not a PLY file\n" * 4)
    elif case == "empty":
        path.write_bytes(b"\0" * 80 + b"\0\0\0\0")  # a binary STL with zero triangles
    elif case == "non_manifold":
        # a fin: a third triangle on an edge of the closed mesh
        a, b = mesh.faces[0, 0], mesh.faces[0, 1]
        vertices = np.vstack([mesh.vertices, [[0.0, -0.05, 0.0]]])
        trimesh.Trimesh(vertices, np.vstack([mesh.faces, [[a, b, len(vertices) - 1]]]), process=False).export(path)
    elif case == "open":
        # the top cut off: a hole of 8 edges, more than trimesh fills
        fine = mesh.subdivide()
        keep = fine.triangles_center[:, 2] < 0.1
        trimesh.Trimesh(fine.vertices, fine.faces[keep], process=False).export(path)
    elif case == "tiny":
        mesh.apply_scale(0.1).export(path)
    with pytest.raises(error, match=message) as caught:
        if case in ("missing", "wrong_suffix"):
            ProbeSource(str(path))
        else:
            load_probe_mesh(_spec(path))
    assert "\n" not in str(caught.value)


def test_probe_source_options_checked():
    with pytest.raises(BadValueError, match="probe.mesh_unit must be one of m, cm, mm, got 'inch'"):
        ProbeSource(None, mesh_unit="inch")
    with pytest.raises(BadValueError, match="probe.align must be true or false, got 'yes'"):
        ProbeSource(None, align="yes")
    assert ProbeSource().spec is None


def test_a_mesh_over_the_face_budget_is_refused_with_a_simplification_that_works(tmp_path, monkeypatch):
    """The refusal names the count and the budget, and the command it suggests makes a mesh the loader takes."""
    import re
    import subprocess
    import sys

    import hupbench.datagen.assets.probe_mesh as probe_mesh

    monkeypatch.setattr(probe_mesh, "MAX_FACES", 5_000)  # a small budget keeps the test quick
    mesh = trimesh.creation.icosphere(subdivisions=5)  # 20,480 triangles
    mesh.apply_scale([0.03, 0.02, 0.08])
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    path = tmp_path / "dense.stl"
    mesh.export(path)
    with pytest.raises(BadValueError, match=r"has 20,480 triangles, more than the 5,000 a probe may have") as caught:
        load_probe_mesh(_spec(path))
    command = re.search(r'python -c "(.*)"$', str(caught.value)).group(1)
    subprocess.run([sys.executable, "-c", command], check=True, cwd=tmp_path)
    simplified = load_probe_mesh(_spec(tmp_path / "dense_5k.stl"))
    assert len(simplified.faces) <= 5_000 and simplified.is_watertight

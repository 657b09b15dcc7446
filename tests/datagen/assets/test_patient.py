"""The patient: its config's checks, its signed distance against its mesh, the abdomen's curvature, the
placement under the default grasps' probe, the grasps-file round trip and the skin tones."""

import io

import numpy as np
import pytest
import trimesh
from omegaconf import OmegaConf

from hupbench.core.errors import BadValueError
from hupbench.datagen.assets import patient as pt
from hupbench.datagen.dataset.grasps_file import DEFAULT_GRASPS, GraspSet
from hupbench.datagen.render.scene import Grasp, scene_parts

#: default grasps placed in the placement tests (each builds its hand and arm meshes)
GRASPS = (0, 3, 6, 9)


def _placement(radius_m: float, T_world_body=np.eye(4)) -> pt.PatientPlacement:
    return pt.PatientPlacement(np.asarray(T_world_body, dtype=np.float64), radius_m, np.array([0.0, 0.0, 1.0]),
                               np.array([0.0, 0.0, 1.0]), 0.0, 0.0)


@pytest.fixture(scope="module")
def grasps():
    return GraspSet(DEFAULT_GRASPS)


@pytest.fixture(scope="module")
def placed(grasps):
    """(grasp index, hand vertices, arm vertices, placement) for each of GRASPS, seeded by the grasp."""
    out = []
    for g in GRASPS:
        parts = {p.name: p.mesh for p in scene_parts(Grasp(grasps.hand_pose[g], grasps.hand_trans[g]),
                                                       probe=grasps.probe)}
        hand, arm = np.asarray(parts["hand"].vertices), np.asarray(parts["arm"].vertices)
        out.append((g, hand, arm, pt.place_patient(pt.PatientSpec(), grasps.probe, hand, arm,
                                                   np.random.default_rng(g))))
    return out


# --------------------------------------------------------------------------- the config


def test_a_radius_of_zero_is_refused_in_one_line_naming_the_key():
    with pytest.raises(BadValueError) as info:
        pt.PatientSpec(radius_m=[0, 0.2])
    assert str(info.value) == ("radius_m must be two numbers [low, high], low <= high, "
                               "from 0.1 to 0.5 m, got [0, 0.2]")


@pytest.mark.parametrize("change, key", [
    (dict(radius_m=[0.3, 0.2]), "radius_m"), (dict(radius_m=[0.2]), "radius_m"), (dict(radius_m="0.2"), "radius_m"),
    (dict(radius_m=[0.2, float("nan")]), "radius_m"), (dict(max_tilt_deg=-1.0), "max_tilt_deg"),
    (dict(press_m=0.003), "press_m"), (dict(max_penetration_m=float("inf")), "max_penetration_m"),
    (dict(attempts=0), "attempts")])
def test_bad_patient_values_are_refused_naming_their_key(change, key):
    with pytest.raises(BadValueError, match=rf"^{key} must be .*, got "):
        pt.PatientSpec(**change)


def test_a_radius_range_from_a_composed_config_is_read_as_floats():
    spec = pt.PatientSpec(radius_m=OmegaConf.create({"r": [0.15, 0.2]}).r)
    assert spec.radius_m == (0.15, 0.2) and isinstance(spec.radius_m[0], float)


# --------------------------------------------------------------------------- the body


@pytest.mark.parametrize("radius_m", [0.1, 0.15, 0.25, 0.5])
def test_the_mesh_is_closed_and_lies_on_the_zero_level(radius_m):
    T = trimesh.transformations.rotation_matrix(0.7, [1.0, -2.0, 0.5], [0.1, 0.2, -0.3])
    placement = _placement(radius_m, T)
    mesh = pt.body_mesh(placement)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert len(mesh.faces) <= 6000
    assert np.abs(pt.body_sdf(placement, mesh.vertices)).max() < 5e-4
    # the flat triangles cut under the skin by their sagitta: under 1 mm above the bed, the cap included
    centres_body = trimesh.transform_points(mesh.triangles_center, np.linalg.inv(T))
    sag = pt.body_sdf_local(radius_m, centres_body)
    from_centre = centres_body - [0.0, 0.0, pt.APEX_HEIGHT_M - radius_m]
    cap = from_centre[:, 2] > np.cos(np.radians(pt.CONTACT_MAX_POLAR_DEG)) * np.linalg.norm(from_centre, axis=1)
    assert cap.sum() > 50 and sag[cap].min() > -1e-3 and sag[centres_body[:, 2] > 0].min() > -1e-3


@pytest.mark.parametrize("radius_m", [0.15, 0.25])
def test_the_signed_distance_agrees_with_the_mesh(radius_m):
    placement = _placement(radius_m, trimesh.transformations.translation_matrix([0.0, 0.1, -0.2]))
    mesh = pt.body_mesh(placement)
    rng = np.random.default_rng(0)
    surface, face = trimesh.sample.sample_surface(mesh, 600, seed=1)
    points = surface + mesh.face_normals[face] * rng.uniform(-0.01, 0.01, (600, 1))
    points = points[points[:, 2] > -0.2]  # above the bed: what a camera sees
    reference = -trimesh.proximity.signed_distance(mesh, points)  # trimesh: positive inside
    sdf = pt.body_sdf(placement, points)
    assert (np.sign(sdf) == np.sign(reference))[np.abs(reference) > 2e-3].all()
    # the mesh's facets (under 1 mm) and, off the cap, the smooth union's approximate distance
    assert np.abs(sdf - reference).max() < 1.5e-3
    # known values: 0.5 m above the abdomen's apex (0.30 m above the bed) on its axis, exactly; the core inside
    assert pt.body_sdf(placement, np.array([[0.0, 0.1, 0.6]]))[0] == pytest.approx(0.5, abs=1e-12)
    assert pt.body_sdf(placement, np.array([[-0.02, 0.1, -0.06]]))[0] < -0.05  # the core is deep inside


def _principal_radii(placement: pt.PatientPlacement, point: np.ndarray, step: float = 2e-3) -> np.ndarray:
    """(2,) the skin's principal radii of curvature at ``point`` from the signed distance's Hessian."""
    hessian = np.zeros((3, 3))
    eye = np.eye(3) * step
    for i in range(3):
        for j in range(3):
            corners = np.array([point + eye[i] + eye[j], point + eye[i] - eye[j], point - eye[i] + eye[j],
                                point - eye[i] - eye[j]])
            f = pt.body_sdf(placement, corners)
            hessian[i, j] = (f[0] - f[1] - f[2] + f[3]) / (4 * step ** 2)
    curvatures = np.sort(np.linalg.eigvalsh(hessian))[1:]  # the normal direction's eigenvalue is 0
    return 1.0 / curvatures


def test_the_skin_at_the_contact_curves_with_the_drawn_radius(placed):
    spec = pt.PatientSpec()
    for _, _, _, placement in placed:
        # the skin point under the lens apex, along the contact normal
        contact = -pt.body_sdf(placement, np.zeros((1, 3)))[0] * placement.normal_world
        radii = _principal_radii(placement, contact)
        assert radii == pytest.approx([placement.radius_m] * 2, rel=1e-3)
        assert spec.radius_m[0] <= radii.min() and radii.max() <= spec.radius_m[1]


# --------------------------------------------------------------------------- the placement


def test_the_lens_rests_on_the_skin_and_the_hand_stays_out(grasps, placed):
    spec = pt.PatientSpec()
    probe_vertices = np.asarray(grasps.probe.mesh.vertices)
    lens = probe_vertices[np.unique(grasps.probe.mesh.faces[grasps.probe.lens_face_mask])]
    for _, hand, arm, placement in placed:
        assert placement is not None
        lens_skin = pt.body_sdf(placement, lens).min()
        assert lens_skin == pytest.approx(-spec.press_m, abs=1e-6) == placement.lens_skin_m
        assert -2e-3 <= lens_skin <= 1e-3
        assert pt.body_sdf(placement, probe_vertices).min() >= -pt.PROBE_MAX_DEPTH_M
        assert pt.body_sdf(placement, np.concatenate([hand, arm])).min() >= -spec.max_penetration_m
        assert placement.penetration_m <= spec.max_penetration_m
        # the skin normal is the probe's +z tilted by at most the allowed tilt, the room's up near it
        tilt = np.degrees(np.arccos(placement.normal_world[2]))
        assert tilt <= spec.max_tilt_deg + 1e-9
        assert np.degrees(np.arccos(placement.normal_world @ placement.vertical_world)) <= 50.0
        assert placement.radius_m == pytest.approx(np.mean(spec.radius_m), abs=0.05 + 1e-12)
        T = placement.T_world_body
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
        np.testing.assert_allclose(T[:3, 2], placement.vertical_world, atol=1e-15)


def test_a_hand_inside_the_body_is_rejected_until_the_attempts_run_out(grasps):
    # a forearm vertex 10 cm under the lens is inside the body whatever the draw
    deep = np.array([[0.0, 0.0, -0.10]])
    spec = pt.PatientSpec(attempts=5)
    assert pt.place_patient(spec, grasps.probe, deep, np.zeros((0, 3)), np.random.default_rng(0)) is None
    # the same draws with the vertex above the probe succeed at the first attempt
    kept = pt.place_patient(spec, grasps.probe, -deep, np.zeros((0, 3)), np.random.default_rng(0))
    assert kept is not None and kept.penetration_m == 0.0


def test_placements_are_seeded():
    from hupbench.datagen.assets.probe import build_probe

    probe = build_probe()
    none = np.zeros((0, 3))
    a, b = (pt.place_patient(pt.PatientSpec(), probe, none, none, np.random.default_rng(7)) for _ in range(2))
    np.testing.assert_array_equal(a.T_world_body, b.T_world_body)
    c = pt.place_patient(pt.PatientSpec(), probe, none, none, np.random.default_rng(8))
    assert not np.allclose(a.T_world_body, c.T_world_body)


def test_placements_round_trip_through_a_grasps_file(placed):
    placements = [p for *_, p in placed]
    arrays = pt.placement_arrays(placements)
    assert arrays["patient_T_world_body"].shape == (len(placed), 4, 4)
    assert arrays["patient_radius_m"].shape == (len(placed),) and arrays["patient_vertical_world"].shape[1] == 3
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    with np.load(buffer) as read:
        for i, placement in enumerate(placements):
            back = pt.placement_from_arrays(dict(read), i)
            for name in pt.PLACEMENT_FIELDS.values():
                np.testing.assert_array_equal(getattr(back, name), getattr(placement, name))


# --------------------------------------------------------------------------- the skin


def test_skin_tones_span_the_monk_scale_from_light_to_dark():
    assert len(pt.SKIN_RGB) >= 6 and len(set(pt.SKIN_RGB)) == len(pt.SKIN_RGB)
    assert pt.SKIN_RGB[0] == pytest.approx((246 / 255, 237 / 255, 228 / 255))  # MST 1, #f6ede4
    luminance = [0.2126 * r + 0.7152 * g + 0.0722 * b for r, g, b in pt.SKIN_RGB]
    assert luminance[0] > 0.9 and luminance[-1] < 0.15 and luminance[3] > luminance[6]
    assert pt.skin_rgb(3) == pt.SKIN_RGB[3] == pt.skin_rgb(3 + len(pt.SKIN_RGB))

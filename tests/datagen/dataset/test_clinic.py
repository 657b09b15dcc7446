"""The clinic track's world (hupbench.datagen.dataset.clinic) on the shipped clinic grasps: depth behind the hand, the
lens on the skin, no hand or forearm in the body, cameras that do not repeat the palm across grasps, and a killed
generation that resumes to the frames of an unbroken one."""

from __future__ import annotations

import os
import textwrap

import cv2
import numpy as np
import pytest

from helpers import REPO
from helpers.datasets import CLINIC_SPLITS as SPLITS, annotations, generate_clinic as run, kill_after_first_chunk
from hupbench.core import keypoints as kp
from hupbench.core.contract import CLINIC_SEG_LABELS, SEG_LABELS
from hupbench.core.geometry import transform_points
from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, GraspSet

#: the palm's six joints: the wrist, the thumb's CMC and the four fingers' MCPs (OpenPose order)
PALM = [0, 1, 5, 9, 13, 17]
#: the bounds the clinic track promises, metres: the lens within 1 mm of the skin and at most 2 mm into it, no hand
#: or forearm vertex more than 3 mm inside the body
LENS_GAP_M, LENS_DEPTH_M, BODY_DEPTH_M = 0.001, 0.002, 0.003
ALL_SPLITS = ("train", "val", "test")


def test_the_abdomen_and_the_room_have_depth_in_every_frame(tiny_clinic):
    """depth > 0 everywhere (the room encloses the scene) and over more than the hand, probe and arm; the patient's
    label covers part of every frame's depth."""
    root, _ = tiny_clinic
    objects = [SEG_LABELS[name] for name in ("hand", "arm", "probe")]
    frames = 0
    for split, ann in annotations(root, ALL_SPLITS).items():
        for frame_id in ann["frame_id"]:
            depth = cv2.imread(str(root / split / "depth" / f"{frame_id:06d}.png"), cv2.IMREAD_UNCHANGED)
            seg = cv2.imread(str(root / split / "seg" / f"{frame_id:06d}.png"), cv2.IMREAD_UNCHANGED)
            assert (depth > 0).all(), (split, frame_id)
            assert (depth > 0).sum() > np.isin(seg, objects).sum(), (split, frame_id)
            frames += 1
    assert frames == sum(SPLITS.values()) * 3 * 2


def test_the_patient_and_subjects_are_recorded(tiny_clinic):
    root, grasps = tiny_clinic
    import json

    manifest = json.loads((root / "manifest.json").read_text())
    assert manifest["seg_labels"] == CLINIC_SEG_LABELS and manifest["protocol"]["track"] == "clinic"
    subjects = GraspSet(grasps).subjects
    for ann in annotations(root, ALL_SPLITS).values():
        g = ann["grasp_index"]
        np.testing.assert_array_equal(ann["hand_length_mm"], subjects["hand_length_mm"][g])
        np.testing.assert_array_equal(ann["hand_breadth_mm"], subjects["hand_breadth_mm"][g])
        assert ((ann["z_ego"] >= 0.35) & (ann["z_ego"] <= 0.8)).all()
        assert (np.abs(ann["roll_deg"]) <= 15.0).all()
        assert (np.abs(ann["aim_px"] - 24.0) <= 0.15 * 48 + 1e-9).all()
        np.testing.assert_allclose(ann["keypoints_2d"][:, kp.KEYPOINT_NAMES.index("middle_mcp")], ann["aim_px"],
                                   atol=1e-3)


@pytest.fixture(scope="module")
def shipped():
    return GraspSet(CLINIC_GRASPS)


def _lens_and_body(grasps: GraspSet, g: int) -> tuple[float, float, float]:
    """(deepest lens point's signed distance to the skin, deepest probe vertex's, deepest hand/forearm vertex's),
    metres (negative inside), grasp ``g`` as rendered."""
    from hupbench.datagen.assets.patient import body_sdf
    from hupbench.datagen.render.scene import Grasp, models_of, scene_parts

    probe, placement = grasps.probe, grasps.placements[g]
    parts = {p.name: p.mesh for p in scene_parts(Grasp(grasps.hand_pose[g], grasps.hand_trans[g]),
                                                  models_of(grasps.hand_spec(g)), probe=probe)}
    vertices = np.asarray(probe.mesh.vertices)
    lens = vertices[np.unique(probe.mesh.faces[probe.lens_face_mask])]
    body = np.concatenate([np.asarray(parts["hand"].vertices), np.asarray(parts["arm"].vertices)])
    return (float(body_sdf(placement, lens).min()), float(body_sdf(placement, vertices).min()),
            float(body_sdf(placement, body).min()))


@pytest.mark.parametrize("g", [0, 1, 2, 3])
def test_the_lens_rests_on_the_skin_and_the_hand_stays_out(shipped, g):
    lens, probe, body = _lens_and_body(shipped, g)
    assert -LENS_DEPTH_M <= lens <= LENS_GAP_M, lens
    assert probe >= -LENS_DEPTH_M, probe
    assert body >= -BODY_DEPTH_M, body


@pytest.mark.slow
def test_every_shipped_grasp_rests_on_the_skin_with_the_hand_out(shipped):
    for g in range(len(shipped)):
        lens, probe, body = _lens_and_body(shipped, g)
        assert -LENS_DEPTH_M <= lens <= LENS_GAP_M and probe >= -LENS_DEPTH_M and body >= -BODY_DEPTH_M, (g, lens,
                                                                                                         probe, body)


def test_the_palm_does_not_repeat_across_grasps_of_a_view(shipped):
    """For every camera index, the palm's six joints in the camera frame spread by more than 5 mm over the grasps
    (on the paper protocol they coincide to 0.00 mm: the camera is built in the wrist's frame)."""
    from hupbench.config import compose
    from hydra.utils import instantiate

    from hupbench.datagen.dataset.clinic import ClinicWorld

    dataset = instantiate(compose("generate", ["+track=clinic"]).dataset)
    world = ClinicWorld(dataset, shipped)
    palm = np.stack([[transform_points(world.cameras(g)["T_cam_world"][v], shipped.keypoints_world[g, PALM])
                      for v in range(dataset.head.views_per_grasp)] for g in range(len(shipped))])  # (G, V, 6, 3)
    spread_mm = 1000 * np.linalg.norm(palm.std(axis=0), axis=-1)  # (V, 6)
    assert spread_mm.min() > 5.0, spread_mm.min()


@pytest.mark.slow  # 10 s; test_generate's SIGKILL-then-resume keeps the resume in the default set (CI under 20 min)
def test_a_killed_clinic_generation_resumes_to_the_same_frames(tiny_clinic, tmp_path):
    root, grasps = tiny_clinic
    out = tmp_path / "killed"
    code = textwrap.dedent(f"""
        import sys
        sys.path[:0] = [{os.path.dirname(__file__)!r}, {str(REPO / "tests")!r}]
        from helpers.datasets import generate_clinic as run
        run({str(out)!r}, {str(grasps)!r})
    """)
    kill_after_first_chunk(code, out, 300)
    assert not (out / "manifest.json").exists()
    result = run(out, grasps)
    assert result["complete"] and 0 < result["frames_rendered"] < 24
    a, b = annotations(out, ALL_SPLITS), annotations(root, ALL_SPLITS)
    for split in a:
        for key in a[split]:
            np.testing.assert_array_equal(a[split][key], b[split][key], err_msg=key)
    for path in root.glob("*/*/*.*"):
        assert path.read_bytes() == (out / path.relative_to(root)).read_bytes(), path


#: sha256 of datagen/dataset/clinic_grasps.npz: `hupbench grasps +subjects=clinic` with the committed config on a 2-core
#: AMD EPYC (the selection depends on the CPU's floating point, so generate renders this file, not a new synthesis)
CLINIC_GRASPS_SHA256 = "8b82677ad1a084ebd980343bbb6d5b1445db025983759833add184465b9932f2"


def test_the_shipped_clinic_grasps_are_pinned_package_data_of_sixty_subjects(shipped):
    import fnmatch
    import hashlib
    import tomllib

    assert hashlib.sha256(CLINIC_GRASPS.read_bytes()).hexdigest() == CLINIC_GRASPS_SHA256
    package_data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert any(fnmatch.fnmatch(CLINIC_GRASPS.name, pattern) for pattern in package_data["hupbench.datagen.dataset"])
    assert len(shipped) == 60 and len(set(shipped.grasp_id.tolist())) == 60
    assert sorted(np.bincount(shipped.subjects["subject_sex"]).tolist()) == [30, 30]
    assert shipped.placements is not None and len(shipped.placements) == 60

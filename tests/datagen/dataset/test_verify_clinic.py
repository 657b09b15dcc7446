"""hupbench.datagen.dataset.verify on the clinic track: a tiny clinic dataset passes, and each check of what the
track promises (the lens on the skin, the camera outside the patient, the subject's hand size, the patient's
pixels on the body, depth in every pixel, the head's aim, each grasp's own hand) fires on a doctored copy."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from helpers.datasets import TINY_SPEC, write_grasps
from hupbench.core.contract import CLINIC_SEG_LABELS, SEG_LABELS, read_annotations, read_manifest
from hupbench.core.io import save_npz
from hupbench.datagen.dataset import verify_clinic as VC
from hupbench.datagen.dataset.verify import report_lines, verify
from hupbench.datagen.dataset.verify_annotations import check_geometry
from hupbench.datagen.dataset.verify_images import image_format_problem

#: two subjects' hands, neither the tables' hand, so that a check on the default hand would fail
SCALES = (0.92, 1.08)


def quiet(*_):
    pass


def clinic_grasps(path):
    """The hand-set grasp (two turns about the probe axis) on two subjects' hands, with a patient under each."""
    from hupbench.datagen.assets.hand import build_hand
    from hupbench.datagen.assets.hand_anatomy import HandSpec
    from hupbench.datagen.assets.patient import PatientSpec, place_patient, placement_arrays
    from hupbench.datagen.assets.probe import build_probe
    from hupbench.datagen.render.scene import Grasp, SceneModels, scene_parts

    with np.load(write_grasps(path, n=len(SCALES))) as data:
        arrays = {k: data[k] for k in data.files}
    specs = [HandSpec(scale=s) for s in SCALES]
    probe, rng, placements = build_probe(), np.random.default_rng(0), []
    for g, spec in enumerate(specs):
        parts = {p.name: p.mesh for p in scene_parts(Grasp(arrays["hand_pose"][g], arrays["hand_trans"][g]),
                                                      SceneModels(hand=spec), probe=probe)}
        placements.append(place_patient(PatientSpec(), probe, np.asarray(parts["hand"].vertices),
                                        np.asarray(parts["arm"].vertices), rng))
    assert all(p is not None for p in placements)
    hands = [build_hand(s) for s in specs]
    arrays |= {"subject_sex": np.array([0, 1]),
               "subject_hand": np.array([[s.scale, s.palm, s.fingers, s.breadth, s.thickness] for s in specs]),
               "hand_length_mm": np.array([h.length_mm for h in hands]),
               "hand_breadth_mm": np.array([h.breadth_mm for h in hands])}
    return save_npz(path, arrays | placement_arrays(placements))


@pytest.fixture(scope="module")
def clinic_dataset(tmp_path_factory):
    """A finished 48 x 48 clinic dataset: 2 grasps (train, test), 2 head cameras each, 1 room, 1 glove. Read only."""
    from hupbench.datagen.dataset.head import HeadSpec
    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    grasps = clinic_grasps(tmp_path_factory.mktemp("clinic_grasps") / "grasps.npz")
    spec = DatasetSpec(**{k: v for k, v in TINY_SPEC.items() if k != "sphere"} | dict(
        track="clinic", splits={"train": 1, "val": 0, "test": 1}, head=HeadSpec(views_per_grasp=2), n_backgrounds=1,
        n_gloves=1, width=48, height=48, fx=60.0, fy=60.0, cx=24.0, cy=24.0))
    root = tmp_path_factory.mktemp("clinic") / "dataset"
    generate(GenerateRun(spec, root, grasps, progress=False), {"test": "clinic_dataset"}, log=quiet)
    return root


def _copy(root, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(root, out)
    return out


def _kinds(result) -> set[str]:
    return {p["kind"] for p in result["problems"]}


def _world_and_test_split(root):
    world, why = VC.read_clinic_grasps(root)
    assert why is None
    return world, read_annotations(root, "test", manifest=read_manifest(root))


def test_clinic_dataset_passes_and_prints_its_floor(clinic_dataset):
    lines = []
    result = verify(clinic_dataset, workers=1, log=lines.append)
    assert result["ok"], result["problems"]
    assert result["frames"] == 4
    # the checks that do not apply say so; those of the world ran (the grasps carry subjects and patients)
    assert any("room covers the backdrop" in line for line in lines)
    assert not any("lens_skin" in line for line in lines)
    floor = report_lines(result, 10)
    assert any(line.startswith("  floor of test: nearest training frame") for line in floor)
    assert floor[-1] == "hupbench verify: OK, 4 frames checked"


def test_the_lens_and_the_hand_are_measured_against_the_patient(clinic_dataset):
    world, ann = _world_and_test_split(clinic_dataset)
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset

    probe = probe_of_dataset(clinic_dataset)
    assert VC.check_lens_skin(ann, "test", world, probe) == []
    lens_m, probe_m, hand_m = world.contact[int(ann["grasp_index"][0])]
    # the placement pressed the lens 0.5 mm in (PatientSpec.press_m); the hand stays clear
    assert lens_m == pytest.approx(-0.0005, abs=1e-6) and probe_m >= -0.002 and hand_m <= VC.BODY_PENETRATION_M


def test_a_moved_patient_is_lens_skin(clinic_dataset, tmp_path):
    root = _copy(clinic_dataset, tmp_path)
    with np.load(root / "grasps.npz") as data:
        arrays = {k: data[k] for k in data.files}
    # the body 5 mm away from the probe along the skin's normal: the lens floats 4.5 mm above the skin
    arrays["patient_T_world_body"][:, :3, 3] -= 0.005 * arrays["patient_normal_world"]
    save_npz(root / "grasps.npz", arrays)
    result = verify(root, workers=1, log=quiet)
    lens = [p for p in result["problems"] if p["kind"] == "lens_skin"]
    assert len(lens) == 2  # one per grasp, naming its frames
    assert "grasp index 1 (2 frames" in " ".join(p["detail"] for p in lens) and "floats 4.50 mm" in lens[0]["detail"]


def test_a_camera_inside_the_body_is_camera_in_patient(clinic_dataset):
    world, ann = _world_and_test_split(clinic_dataset)
    assert VC.check_cameras(ann, "test", world) == []
    placement = world.placements[int(ann["grasp_index"][1])]
    inside = placement.T_world_body[:3, :3] @ np.array([0.0, 0.0, 0.1]) + placement.T_world_body[:3, 3]
    ann["T_cam_world"][1, :3, 3] = -ann["T_cam_world"][1, :3, :3] @ inside  # centre 10 cm above the bed, in the torso
    found = VC.check_cameras(ann, "test", world)
    assert [(p["kind"], p["frame_id"]) for p in found] == [("camera_in_patient", int(ann["frame_id"][1]))]
    assert "inside the body" in found[0]["detail"]


def test_a_wrong_hand_length_is_hand_size(clinic_dataset):
    world, ann = _world_and_test_split(clinic_dataset)
    assert VC.check_hand_size(ann, "test", world) == []
    ann["hand_length_mm"][1] += 5.0
    found = VC.check_hand_size(ann, "test", world)
    assert [(p["kind"], p["frame_id"]) for p in found] == [("hand_size", int(ann["frame_id"][1]))]
    assert "(5.000 mm off)" in found[0]["detail"]


def test_the_aim_pixel_is_checked_not_the_optical_axis(clinic_dataset):
    _, ann = _world_and_test_split(clinic_dataset)
    assert VC.check_aim(ann, "test", "middle_mcp") == []
    # the head turned keypoint 9 off the axis: it is not at (0, 0, z_ego)
    assert np.abs(ann["keypoints_3d_cam"][:, 9, :2]).max() > 1e-3
    ann["aim_px"][0] += [0.5, 0.0]
    ann["z_ego"][1] += 0.001
    found = VC.check_aim(ann, "test", "middle_mcp")
    assert [p["frame_id"] for p in found] == [int(ann["frame_id"][0]), int(ann["frame_id"][1])]
    assert {p["kind"] for p in found} == {"look_at"}


def test_each_grasp_is_rebuilt_on_its_own_hand(clinic_dataset):
    world, ann = _world_and_test_split(clinic_dataset)
    assert [p for p in check_geometry(ann, "test", hand_spec=VC.hand_spec_of(world))
            if p["kind"] == "pose_mismatch"] == []
    # the default hand is not this subject's: every frame would be off
    assert len([p for p in check_geometry(ann, "test") if p["kind"] == "pose_mismatch"]) == len(ann["frame_id"])


def test_patient_painted_on_the_room_is_patient_depth(clinic_dataset, tmp_path):
    root = _copy(clinic_dataset, tmp_path)
    path = root / "test" / "seg" / f"{int(read_annotations(root, 'test', keys=('frame_id',))['frame_id'][0]):06d}.png"
    seg = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert (seg == 0).sum() > 0.2 * seg.size  # the room shows
    seg[seg == 0] = CLINIC_SEG_LABELS["patient"]
    assert cv2.imwrite(str(path), seg)
    result = verify(root, workers=1, log=quiet)
    assert [p["kind"] for p in result["problems"]] == ["patient_depth"]
    assert "patient pixels off the body's surface" in result["problems"][0]["detail"]


def test_pixels_without_depth_are_mask_depth(clinic_dataset, tmp_path):
    root = _copy(clinic_dataset, tmp_path)
    path = next((root / "test" / "depth").glob("*.png"))
    depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert depth.min() > 0  # the room and the patient have depth in every pixel
    depth[:4] = 0
    assert cv2.imwrite(str(path), depth)
    result = verify(root, workers=1, log=quiet)
    assert _kinds(result) == {"mask_depth"}
    assert result["problems"][0]["detail"].startswith(f"{4 * depth.shape[1]} pixels without depth")


def test_the_patient_label_is_the_clinic_tracks():
    seg = np.zeros((8, 8), np.uint8)
    seg[2, 2] = CLINIC_SEG_LABELS["patient"]
    assert image_format_problem(seg, "seg", (8, 8), CLINIC_SEG_LABELS) is None
    assert image_format_problem(seg, "seg", (8, 8)) == f"labels [4] outside {SEG_LABELS}"


def test_grasps_without_patients_skip_the_world_checks(clinic_dataset, tmp_path):
    root = _copy(clinic_dataset, tmp_path)
    with np.load(root / "grasps.npz") as data:
        arrays = {k: data[k] for k in data.files if not k.startswith("patient_")}
    save_npz(root / "grasps.npz", arrays)
    lines = []
    result = verify(root, workers=1, log=lines.append)
    assert any(line.startswith("not checked: pose_mismatch, lens_skin") and "patient placements" in line
               for line in lines)
    assert _kinds(result) == {"grasps_file"}  # the file changed under the manifest's sha256

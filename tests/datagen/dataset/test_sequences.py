"""A dataset of clips (``hupbench generate +track=clinic_sequences``): it generates and verifies, each clip whole and in
time with its kinematics recorded, every frame rendered at its own camera and patient pose; verify finds a label
jump, a clock that skips, a lost contact and a clip without a record."""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import pytest
from hydra.utils import instantiate

from helpers.datasets import CLINIC_SPLITS, CLIP_FPS, CLIP_FRAMES, CLIPS_PER_GRASP, clinic_spec, sequence_spec
from hupbench.config import compose
from hupbench.core.contract import SEQUENCE, SEQUENCE_ANNOTATION_FIELDS, read_annotations, read_manifest
from hupbench.core.errors import BadValueError
from hupbench.core.io import save_npz
from hupbench.datagen.dataset.head_motion import HeadMotionSpec
from hupbench.datagen.dataset.scan_motion import ScanMotionSpec
from hupbench.datagen.dataset.spec import DatasetSpec
from hupbench.datagen.dataset.verify import verify
from hupbench.datagen.dataset.verify_sequence import check_clips

FPS, FRAMES = CLIP_FPS, CLIP_FRAMES


@pytest.fixture(scope="module")
def clips_dataset(tiny_clips):
    return tiny_clips


def test_the_track_composes_and_refuses_half_a_sequence():
    spec = instantiate(compose("generate", ["+track=clinic_sequences"]).dataset)
    assert spec.sequence and spec.track == "clinic" and spec.frames_per_clip == 151 and spec.n_views == 2
    assert not instantiate(compose("generate", ["+track=clinic"]).dataset).sequence
    with pytest.raises(BadValueError, match="dataset.scan and dataset.head_motion"):
        clinic_spec(scan=ScanMotionSpec(duration_s=(1.0, 1.0)))
    with pytest.raises(BadValueError, match="dataset.scan.duration_s must be one clip length"):
        clinic_spec(scan=ScanMotionSpec(duration_s=(1.0, 2.0)), head_motion=HeadMotionSpec())
    with pytest.raises(BadValueError, match="on the unseen_grasps track"):
        DatasetSpec(scan=ScanMotionSpec(duration_s=(1.0, 1.0)), head_motion=HeadMotionSpec())


def test_a_dataset_of_clips_verifies(clips_dataset):
    result = verify(clips_dataset, workers=1, progress=False, log=lambda *_: None)
    assert result["ok"], result["problems"][:5]
    assert result["frames"] == sum(CLINIC_SPLITS.values()) * CLIPS_PER_GRASP * FRAMES


def test_each_clip_is_whole_in_order_and_recorded(clips_dataset):
    manifest = read_manifest(clips_dataset)
    record = manifest[SEQUENCE]
    assert record["fps"] == FPS and record["frames_per_clip"] == FRAMES and record["clips_per_grasp"] == CLIPS_PER_GRASP
    assert [c["clip_id"] for c in record["clips"]] == list(range(sum(CLINIC_SPLITS.values()) * CLIPS_PER_GRASP))
    for split in ("train", "val", "test"):
        ann = read_annotations(clips_dataset, split)
        assert set(SEQUENCE_ANNOTATION_FIELDS) <= set(ann)
        for clip in np.unique(ann["clip_id"]):
            rows = np.flatnonzero(ann["clip_id"] == clip)
            c = record["clips"][int(clip)]
            assert c["split"] == split and c["grasp_index"] == int(ann["grasp_index"][rows[0]])
            np.testing.assert_array_equal(ann["frame_in_clip"][rows], np.arange(FRAMES))
            np.testing.assert_allclose(ann["time_s"][rows], np.arange(FRAMES) / FPS, atol=1e-12)
            assert len(np.unique(ann["background_id"][rows])) == 1 == len(np.unique(ann["glove_id"][rows]))
            # the clip's measured kinematics are its drawn ones (scan_motion's calibration), below its bounds
            for key, value in c["kinematics"].items():
                assert value == pytest.approx(c["target"][key], rel=2e-3)
                assert value < c["bounds"][key]
            # the patient moves under the probe: its pose differs from frame to frame
            steps = np.abs(np.diff(ann["T_world_body"][rows][:, :3, 3], axis=0)).max(axis=1)
            assert (steps > 0).all()


def test_a_clips_first_frame_is_its_grasps_drawn_camera(clips_dataset):
    """The first frame of clip c of a grasp is the grasp's head camera c: the same pose, angles, distance and aim
    as the clinic track draws them; later frames' angles are measured on their own camera."""
    from hupbench.datagen.dataset.clinic import ClinicWorld
    from hupbench.datagen.dataset.grasps_file import GraspSet

    world = ClinicWorld(sequence_spec(), GraspSet(clips_dataset / "grasps.npz"))
    ann = read_annotations(clips_dataset, "train")
    for row in np.flatnonzero(ann["frame_in_clip"] == 0):
        g, view = int(ann["grasp_index"][row]), int(ann["view_id"][row])
        cams = world.cameras(g)
        np.testing.assert_allclose(ann["T_cam_world"][row], cams["T_cam_world"][view], atol=1e-12)
        assert np.degrees(ann["theta"][row]) == pytest.approx(90.0 - cams["elevation_deg"][view], abs=1e-6)
        assert np.degrees(ann["phi"][row]) == pytest.approx(cams["azimuth_deg"][view], abs=1e-6)
        assert ann["z_ego"][row] == pytest.approx(cams["distance_m"][view], abs=1e-6)
        np.testing.assert_allclose(ann["aim_px"][row], cams["aim_px"][view], atol=1e-3)
    # the head moves: a clip's cameras are not all its first
    rows = np.flatnonzero(ann["clip_id"] == ann["clip_id"][0])
    assert np.abs(ann["T_cam_world"][rows] - ann["T_cam_world"][rows[0]]).max() > 1e-3


def _copy(clips_dataset, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(clips_dataset, out)
    return out


def test_a_label_jump_is_clip_continuity(clips_dataset):
    """One frame's patient moved 10 mm under the probe is a jump of the probe's centre beyond the clip's speed
    bound; the same frame's camera moved 3 cm, its labels re-expressed in it (every per-frame check holds), is a
    jump of the head beyond its bound."""
    manifest = read_manifest(clips_dataset)
    ann = read_annotations(clips_dataset, "train")
    assert check_clips(ann, "train", manifest) == []
    row = 5
    bound = manifest[SEQUENCE]["clips"][int(ann["clip_id"][row])]["bounds"]["speed_mm_per_s"]
    assert 10.0 > bound / FPS  # 10 mm in a frame is beyond the clip's top speed
    # the body (and room) 10 mm along the world's x: the probe's centre moves 10 mm in the body frame
    moved = copy.deepcopy(ann)
    moved["T_world_body"][row, 0, 3] += 0.010
    problems = check_clips(moved, "train", manifest)
    assert len(problems) == 1 and problems[0]["kind"] == "clip_continuity"
    assert "probe's centre's speed" in problems[0]["detail"] and problems[0]["frame_id"] == ann["frame_id"][row]
    # the camera 3 cm along its x, the labels re-expressed in it: the probe stays, the head jumps
    moved = copy.deepcopy(ann)
    shift = np.eye(4)
    shift[0, 3] = -0.03
    moved["T_cam_world"][row] = shift @ ann["T_cam_world"][row]
    moved["keypoints_3d_cam"][row] = ann["keypoints_3d_cam"][row] + np.float32([-0.03, 0.0, 0.0])
    problems = check_clips(moved, "train", manifest)
    assert len(problems) == 1 and "head's speed" in problems[0]["detail"], problems


def test_a_broken_clock_or_order_or_record_is_clip_continuity(clips_dataset):
    manifest = read_manifest(clips_dataset)
    ann = read_annotations(clips_dataset, "train")
    late = copy.deepcopy(ann)
    late["time_s"][3] += 0.01
    assert "time_s" in check_clips(late, "train", manifest)[0]["detail"]
    swapped = copy.deepcopy(ann)
    swapped["frame_in_clip"][[3, 4]] = swapped["frame_in_clip"][[4, 3]]
    assert "not consecutive" in check_clips(swapped, "train", manifest)[0]["detail"]
    short = {k: v[1:] for k, v in ann.items()}
    assert "1 frames" not in check_clips(short, "train", manifest)[0]["detail"]
    assert f"{FRAMES - 1} frames" in check_clips(short, "train", manifest)[0]["detail"]
    unrecorded = copy.deepcopy(manifest)
    unrecorded[SEQUENCE]["clips"] = unrecorded[SEQUENCE]["clips"][1:]
    problems = check_clips(ann, "train", unrecorded)
    assert len(problems) == 1 and "has no record" in problems[0]["detail"] and problems[0]["file"] == "manifest.json"
    no_bounds = copy.deepcopy(manifest)
    del no_bounds[SEQUENCE]["clips"][0]["head_bounds"]
    assert "has no head_bounds" in check_clips(ann, "train", no_bounds)[0]["detail"]


def test_verify_reads_each_frames_patient_pose(clips_dataset, tmp_path):
    """Every frame's patient pixels lie on the body at the frame's pose (verify passes); with every frame given its
    clip's first pose verify finds the patient off its pixels (and the head moving against the room beyond its
    bounds)."""
    out = _copy(clips_dataset, tmp_path)
    ann = read_annotations(out, "train")
    first = {int(c): ann["T_world_body"][np.flatnonzero(ann["clip_id"] == c)[0]] for c in np.unique(ann["clip_id"])}
    ann["T_world_body"] = np.stack([first[int(c)] for c in ann["clip_id"]])
    save_npz(out / "train" / "annotations.npz", ann)
    result = verify(out, workers=1, progress=False, log=lambda *_: None)
    kinds = result["by_kind"]
    assert kinds["patient_depth"] > 0 and kinds["clip_continuity"] > 0, kinds
    assert {p["split"] for p in result["problems"]} == {"train"}


def test_a_frame_that_loses_the_contact_is_lens_skin(clips_dataset):
    """The lens rests on the skin in every frame at the frame's pose; one frame's patient lowered 3 mm along the
    skin's normal leaves the lens floating in that frame: one problem for its clip, naming that frame."""
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset
    from hupbench.datagen.dataset.verify_clinic import check_lens_skin, frame_placement, read_clinic_grasps

    manifest = read_manifest(clips_dataset)
    world, why = read_clinic_grasps(clips_dataset)
    assert why is None
    probe = probe_of_dataset(clips_dataset, manifest)
    ann = read_annotations(clips_dataset, "val")
    assert check_lens_skin(ann, "val", world, probe) == []
    row = 7
    normal = frame_placement(world, int(ann["grasp_index"][row]), ann["T_world_body"][row]).normal_world
    lowered = copy.deepcopy(ann)
    lowered["T_world_body"][row, :3, 3] -= 0.003 * normal
    problems = check_lens_skin(lowered, "val", world, probe)
    assert len(problems) == 1 and problems[0]["frame_id"] == ann["frame_id"][row], problems
    assert "1 of its 11 frames lose the contact" in problems[0]["detail"] and "floats" in problems[0]["detail"]


def test_a_malformed_sequence_record_is_refused(clips_dataset, tmp_path):
    out = _copy(clips_dataset, tmp_path)
    manifest = json.loads((out / "manifest.json").read_text())
    manifest[SEQUENCE]["fps"] = 0
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BadValueError, match="sequence must be a clinic dataset's record"):
        verify(out, workers=1, progress=False, log=lambda *_: None)


def test_the_fingers_adjust_within_a_clip_and_verify_holds_each_frame_to_its_record(clips_dataset):
    """The tiny clips' fingers move (frames whose hand pose is not their grasp's, hand keypoints that move
    relative to the probe); each frame's pose is its grasp's with its clip's recorded adjustments, and a frame
    given another pose is a grasps_file problem."""
    from hupbench.datagen.dataset.grasps_file import read_grasps
    from hupbench.datagen.dataset.verify_annotations import check_grasps_file

    manifest = read_manifest(clips_dataset)
    assert manifest[SEQUENCE]["fingers"]["rate_hz"] > 0
    grasps = read_grasps(clips_dataset / "grasps.npz")
    annotations = {split: read_annotations(clips_dataset, split) for split in ("train", "val", "test")}
    moved = {split: (ann["hand_pose"] != grasps["hand_pose"][ann["grasp_index"]]).any(axis=1)
             for split, ann in annotations.items()}
    assert sum(m.sum() for m in moved.values()) > 10
    ann = annotations["train"]
    first = ann["frame_in_clip"] == 0  # a clip starts at its grasp's pose
    assert not moved["train"][first].any()
    assert check_grasps_file(clips_dataset, annotations, manifest) == []
    row = int(np.flatnonzero(moved["train"])[0])
    other = copy.deepcopy(annotations)
    other["train"]["hand_pose"][row, 5] += 0.01
    problems = check_grasps_file(clips_dataset, other, manifest)
    assert len(problems) == 1 and problems[0]["frame_id"] == ann["frame_id"][row], problems
    assert "1 train frames' grasp (id, hand pose, translation) differ" in problems[0]["detail"]


def test_a_finger_label_jump_or_a_malformed_adjustment_is_clip_continuity(clips_dataset):
    """A fingertip label moved 50 mm in one frame (beyond the clip's fingers' bound) is a jump; a record whose
    adjustment names the thumb is not an adjustment."""
    from hupbench.core import keypoints as kp

    manifest = read_manifest(clips_dataset)
    ann = read_annotations(clips_dataset, "train")
    row = 4
    bound = manifest[SEQUENCE]["clips"][int(ann["clip_id"][row])]["fingers"]["keypoint_speed_mm_per_s"]
    assert 50.0 > bound / FPS
    jumped = copy.deepcopy(ann)
    jumped["keypoints_3d_cam"][row, kp.KEYPOINT_NAMES.index("index_tip")] += np.float32([0.05, 0.0, 0.0])
    problems = check_clips(jumped, "train", manifest)
    assert len(problems) == 1 and "hand keypoint moves" in problems[0]["detail"], problems
    assert problems[0]["frame_id"] == ann["frame_id"][row]
    thumb = copy.deepcopy(manifest)
    clip = int(ann["clip_id"][0])
    thumb[SEQUENCE]["clips"][clip]["fingers"]["adjustments"] = [
        {"fingers": ["thumb"], "start_s": 0.1, "move_s": 0.1, "hold_s": 0.0, "open_deg": [[5.0, 5.0, 5.0]]}]
    problems = check_clips(ann, "train", thumb)
    assert len(problems) == 1 and "fingers are not" in problems[0]["detail"], problems


def test_generate_renders_a_missing_clip_frame_of_a_finished_dataset_of_clips_again(clips_dataset, tmp_path):
    """The frames whose fingers moved hold their clip's poses, not their grasp's: generate on the finished dataset
    still knows it was rendered from its grasps and renders the missing frame's clip again, byte for byte."""
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    out = _copy(clips_dataset, tmp_path)
    frame = next((out / "val" / "rgb").glob("*.*"))
    before = frame.read_bytes()
    frame.unlink()
    result = generate(GenerateRun(sequence_spec(), str(out), str(out / "grasps.npz"), progress=False),
                      {"test": "tiny_clips"}, log=lambda *_: None)
    assert result["complete"] and result["frames_rendered"] == FRAMES  # the one clip
    assert frame.read_bytes() == before

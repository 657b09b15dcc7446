"""``hupbench grasps +subjects=clinic``: one grasp per subject, on the subject's own hand, with a patient under it;
the grasps file's reader reads and checks the subject fields."""

import numpy as np
import pytest

from hupbench.config import compose
from hupbench.core.errors import BadValueError
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import HandSpec
from hupbench.datagen.assets.patient import PLACEMENT_FIELDS
from hupbench.datagen.assets.subjects import SubjectSpec, draw_subjects
from hupbench.datagen.dataset.grasps_file import DEFAULT_GRASPS, GraspSet, read_grasps
from hupbench.verbs.grasps import run_grasps

TINY = ["+subjects=clinic", "subjects.count=2", "generate.starts_per_theta=8", "sheet.tile_px=32", "threads=1"]


@pytest.fixture(scope="module")
def clinic(tmp_path_factory):
    out = tmp_path_factory.mktemp("clinic_grasps")
    result = run_grasps(compose("grasps", [f"out_dir={out}", *TINY]), log=lambda *_: None)
    return out, result


def test_each_grasp_is_made_on_its_subjects_hand(clinic):
    out, result = clinic
    assert result["selected"] == 2
    data = dict(np.load(out / "grasps.npz"))
    subjects = draw_subjects(SubjectSpec(count=2))
    assert data["grasp_id"].tolist() == [0, 1]
    assert data["subject_sex"].dtype == np.int8 and data["subject_sex"].tolist() == [s.sex for s in subjects]
    assert data["subject_hand"].shape == (2, 5) and data["subject_hand"].dtype == np.float64
    assert set(PLACEMENT_FIELDS) <= set(data)
    assert data["score_plausible"].all()
    for g, subject in enumerate(subjects):
        hand = build_hand(HandSpec(*data["subject_hand"][g]))
        assert data["hand_length_mm"][g] == hand.length_mm == pytest.approx(subject.length_mm, abs=1.0)
        assert data["hand_breadth_mm"][g] == hand.breadth_mm == pytest.approx(subject.breadth_mm, abs=1.0)
        own = hand.keypoints(data["hand_pose"][g], data["hand_trans"][g], clamp=False)
        # the same hand's joints to the last bits (the grasp search computes them batched: an ulp apart on some CPUs)
        np.testing.assert_allclose(data["keypoints_probe"][g], own, rtol=0, atol=1e-12)
        # the tables' hand in the same pose puts its fingertips elsewhere
        default = build_hand().keypoints(data["hand_pose"][g], data["hand_trans"][g], clamp=False)
        assert np.abs(default - own).max() > 0.002
    assert (out / "contact_sheet.png").stat().st_size > 1000


def test_grasp_set_reads_subjects_and_builds_each_grasps_hand(clinic):
    out, _ = clinic
    grasps, data = GraspSet(out / "grasps.npz"), np.load(out / "grasps.npz")
    assert grasps.subjects["subject_sex"].tolist() == data["subject_sex"].tolist()
    for g in range(2):
        assert grasps.hand_spec(g) == HandSpec(*data["subject_hand"][g])
    np.testing.assert_allclose(grasps.keypoints_world[:, :21], data["keypoints_probe"], rtol=0, atol=1e-12)
    default = GraspSet(DEFAULT_GRASPS)
    assert default.subjects is None and default.hand_spec(0) == HandSpec()


@pytest.mark.parametrize("change, message", [
    (lambda d: d.pop("hand_breadth_mm"), r"but not \['hand_breadth_mm'\]; expected all of them or none"),
    (lambda d: d.update(subject_sex=np.array([0, 2], np.int8)), r"subject_sex must be 0 \(woman\) or 1 \(man\); rows \[1\]"),
    (lambda d: d.update(subject_hand=d["subject_hand"][:, :4]), r"subject_hand has shape \(2, 4\), expected \(G, 5\)"),
    (lambda d: d.update(hand_length_mm=np.array([180.0, 20.0])), r"hand_length_mm must be within 130..230"),
])
def test_bad_subject_fields_are_refused(clinic, tmp_path, change, message):
    out, _ = clinic
    data = dict(np.load(out / "grasps.npz"))
    change(data)
    np.savez(tmp_path / "grasps.npz", **data)
    with pytest.raises(BadValueError, match=message):
        read_grasps(tmp_path / "grasps.npz")


def test_a_subjects_grasp_does_not_depend_on_the_worker_count(clinic):
    from hupbench.config import build
    from hupbench.datagen.grasps.subject_grasps import subject_grasps

    out, _ = clinic
    run = build(compose("grasps", [f"out_dir={out}_again", *TINY]))
    made = subject_grasps(draw_subjects(run.subjects), run.generate, run.refine, run.probe, run.patient, workers=2,
                          log=lambda *_: None)["arrays"]
    written = np.load(out / "grasps.npz")  # made by one worker (threads=1)
    for key in ("hand_pose", "hand_trans", "subject_hand", "hand_length_mm", "patient_T_world_body"):
        np.testing.assert_array_equal(made[key], written[key])

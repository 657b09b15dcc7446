"""Subjects: adult women's and men's hands drawn from Pheasant and Haslegrave's tables, each built to its
measures."""

import numpy as np
import pytest

from hupbench.core.errors import BadValueError
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.subjects import SubjectSpec, draw_subjects

# Pheasant and Haslegrave, Bodyspace, 3rd ed. (2006), mm, written out here: women's 5th and men's 95th
WOMEN_5TH_LENGTH, MEN_95TH_LENGTH = 159.0, 205.0
WOMEN_5TH_BREADTH, MEN_95TH_BREADTH = 69.0, 95.0


@pytest.fixture(scope="module")
def subjects():
    return draw_subjects(SubjectSpec(count=200, seed=0))


def test_draw_spans_both_sexes_5th_to_95th_percentiles(subjects):
    length = np.array([s.length_mm for s in subjects])
    breadth = np.array([s.breadth_mm for s in subjects])
    assert length.min() < WOMEN_5TH_LENGTH and length.max() > MEN_95TH_LENGTH
    assert breadth.min() < WOMEN_5TH_BREADTH and breadth.max() > MEN_95TH_BREADTH
    sex = np.array([s.sex for s in subjects])
    assert sex.sum() == 100  # women_fraction 0.5
    # men's hands are longer on average, by about the tables' 15 mm
    assert 10.0 < length[sex == 1].mean() - length[sex == 0].mean() < 20.0
    assert np.corrcoef(length[sex == 1], breadth[sex == 1])[0, 1] > 0.3


def test_draw_is_seeded(subjects):
    assert draw_subjects(SubjectSpec(count=200, seed=0)) == subjects
    assert draw_subjects(SubjectSpec(count=200, seed=1)) != subjects


def test_built_hands_measure_their_targets(subjects):
    by_length = sorted(subjects, key=lambda s: s.length_mm)
    for subject in (by_length[0], by_length[100], by_length[-1]):
        hand = build_hand(subject.hand_spec(voxel_m=0.002))
        assert hand.length_mm == pytest.approx(subject.length_mm, abs=1.0)
        assert hand.breadth_mm == pytest.approx(subject.breadth_mm, abs=1.0)


@pytest.mark.parametrize("change, message", [
    (dict(count=0), "count must be a whole number from 1 to"),
    (dict(women_fraction=1.5), r"women_fraction must be a finite number in \[0, 1\]"),
    (dict(hand_length_mm=[100, 200]), r"hand_length_mm must be \[low, high\] with 130 <= low < high <= 230"),
    (dict(hand_length_mm=[200, 180]), r"hand_length_mm must be \[low, high\] with 130"),
    (dict(hand_length_mm=[150]), r"hand_length_mm must be \[low, high\]"),
    (dict(hand_breadth_mm=[60, 300]), r"hand_breadth_mm must be \[low, high\] with 55 <= low < high <= 115"),
    (dict(hand_length_mm=[130, 140], hand_breadth_mm=[100, 115]), "admit no hand: breadth / length"),
])
def test_bad_subject_spec_refused_with_its_line(change, message):
    with pytest.raises(BadValueError, match=message) as info:
        SubjectSpec(**change)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("override, message", [
    ("subjects.count=0", "subjects: count must be a whole number from 1 to"),
    ("subjects.hand_length_mm=[120,240]", r"subjects: hand_length_mm must be \[low, high\] with 130"),
    ("subjects.women_fraction=-0.1", r"subjects: women_fraction must be a finite number in \[0, 1\]"),
])
def test_bad_clinic_subjects_refused_before_any_grasp(tmp_path, override, message):
    from hupbench.config import build, compose

    with pytest.raises(BadValueError, match=message):
        build(compose("grasps", [f"out_dir={tmp_path}", "+subjects=clinic", override]))
    assert not any(tmp_path.iterdir())


def test_without_subjects_the_grasps_run_is_the_single_hand_one(tmp_path):
    from hupbench.config import build, compose

    assert build(compose("grasps", [f"out_dir={tmp_path}"])).subjects is None
    assert build(compose("grasps", [f"out_dir={tmp_path}", "+subjects=clinic"])).subjects == SubjectSpec()

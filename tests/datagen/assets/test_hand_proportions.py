"""The hand's proportions: HandSpec() is the tables' hand, each factor moves joints along unchanged bone
directions, and the measured length and breadth follow."""

import numpy as np
import pytest

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import HandSpec, child_of_joint, rest_skeleton

#: HandSpec()'s rest keypoints 0 (wrist), 4 (thumb tip), 8, 12, 16, 20 (finger tips), metres, hand frame, printed
#: before the proportions were added: the default hand must not move
REFERENCE_REST = np.array([
    [0.0, 0.0, 0.0],
    [0.09275734081449218, -0.03363974092978114, -0.07583139139442335],
    [0.1723192665374728, 0.0, -0.03035445062069216],
    [0.1858510584310061, 0.0, -0.005],
    [0.17269417696374317, -0.002, 0.01880955220061083],
    [0.14185457180291747, -0.005, 0.03918430319011506]])
COARSE = 0.002


def test_default_hand_is_unchanged():
    np.testing.assert_array_equal(build_hand().keypoints_rest[[0, 4, 8, 12, 16, 20]], REFERENCE_REST)
    assert build_hand().length_mm == pytest.approx(185.918, abs=1e-3)


def _bone_directions(spec):
    joints, tips = rest_skeleton(spec)
    bones = child_of_joint(joints, tips)[1:] - joints[1:]
    return bones / np.linalg.norm(bones, axis=1, keepdims=True), np.linalg.norm(bones, axis=1)


@pytest.mark.parametrize("factor", ["palm", "fingers", "breadth", "thickness"])
def test_proportions_keep_bone_directions(factor):
    directions, lengths = _bone_directions(HandSpec())
    changed, changed_lengths = _bone_directions(HandSpec(**{factor: 1.2}))
    np.testing.assert_allclose(changed, directions, atol=1e-12)
    if factor == "fingers":  # every phalanx 20 % longer
        np.testing.assert_allclose(changed_lengths, 1.2 * lengths, rtol=1e-12)


def test_breadth_spreads_the_mcps_and_fingers_lengthen_the_hand():
    joints, tips = rest_skeleton(HandSpec())
    wide = rest_skeleton(HandSpec(breadth=1.2))[0]
    mcps = [1 + 3 * i for i, f in enumerate(kp.MANO_FINGER_ORDER) if f != "thumb"]
    np.testing.assert_allclose(wide[mcps, 2], 1.2 * joints[mcps, 2], rtol=1e-12)
    np.testing.assert_allclose(wide[mcps, 0], joints[mcps, 0], rtol=1e-12)
    long = build_hand(HandSpec(fingers=1.1, voxel_m=COARSE))
    middle = kp.MANO_FINGER_ORDER.index("middle")
    phalanges = np.linalg.norm(tips[middle] - joints[1 + 3 * middle]) * 1e3
    assert long.length_mm - build_hand().length_mm == pytest.approx(0.1 * phalanges, abs=0.05)


def test_measured_breadth_grows_with_breadth_and_thickness():
    base = build_hand(HandSpec(voxel_m=COARSE)).breadth_mm
    assert 65.0 < base < 85.0  # the tables' hand, across the knuckles
    assert build_hand(HandSpec(breadth=1.2, voxel_m=COARSE)).breadth_mm > base + 8.0
    assert build_hand(HandSpec(thickness=1.2, voxel_m=COARSE)).breadth_mm > base + 2.0
    assert build_hand(HandSpec(scale=1.2, voxel_m=COARSE)).breadth_mm == pytest.approx(1.2 * base, abs=1.0)

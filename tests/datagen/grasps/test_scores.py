import numpy as np
import pytest

from hupbench.datagen.grasps.refine import GraspBatch, GraspEnergy
from hupbench.datagen.grasps.scores import farthest_point_selection, force_closure_residual, score_grasps
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import pose_to_anatomical
from hupbench.core.geometry import axis_angle_to_matrix
from hupbench.datagen.render.preview import handset_grasp
from hupbench.datagen.assets.probe import build_probe


def test_force_closure_known_values():
    # two opposing contacts on one line balance exactly
    assert force_closure_residual(np.array([[0.01, 0, 0], [-0.01, 0, 0]]), np.array([[-1.0, 0, 0], [1, 0, 0]])) < 1e-9
    # one contact cannot balance anything: the best unit force left is the cone's axis component
    single = force_closure_residual(np.array([[0.01, 0, 0]]), np.array([[-1.0, 0, 0]]))
    # (the unit-sum constraint is a weighted row of the NNLS, so it holds to about 1e-4)
    assert single == pytest.approx(1.0 / np.sqrt(1.0 + 0.5**2), rel=1e-3)
    assert force_closure_residual(np.zeros((0, 3)), np.zeros((0, 3))) == 1.0


def test_farthest_point_selection_spreads_out():
    line = np.linspace(0.0, 1.0, 11)[:, None]
    picked = farthest_point_selection(line, 3, np.random.default_rng(0))
    assert line[picked[1], 0] in (0.0, 1.0) and len(set(picked.tolist())) == 3
    again = farthest_point_selection(line, 3, np.random.default_rng(0))
    np.testing.assert_array_equal(picked, again)


def test_scores_of_the_handset_grasp():
    hand, probe = build_hand(), build_probe()
    g = handset_grasp()
    batch = GraspBatch(axis_angle_to_matrix(g.hand_pose[:3])[None], g.hand_trans[None],
                       pose_to_anatomical(g.hand_pose)[None])
    s = score_grasps(GraspEnergy(hand, probe), batch)
    assert s["max_penetration_mm"][0] < 0.5
    assert s["joint_limit_violation_deg"][0] < 1e-6
    assert s["lens_coverage"][0] == 0.0
    # the hand-set grip touches nothing below the top of the lens
    assert s["min_contact_height_mm"][0] > 1000.0 * probe.region_z.lens[1]
    assert s["pads_in_contact"][0] >= 3
    # pushing the hand 5 cm through the handle is caught
    deep = GraspBatch(batch.R_global, batch.trans + [0.0, 0.05, 0.0], batch.angles)
    s_deep = score_grasps(GraspEnergy(hand, probe), deep)
    assert s_deep["max_penetration_mm"][0] > 4.0 and not s_deep["plausible"][0]

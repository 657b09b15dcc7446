"""The grasps contact sheet: a header explaining views and scores, then three titled views per grasp."""

import numpy as np
from helpers.datasets import write_grasps

from hupbench.core.geometry import axis_angle_to_matrix
from hupbench.datagen.grasps.sheet import VIEW_DISTANCE_M, contact_sheet, grasp_views

WHITE = 255


def _arrays(tmp_path, n=2):
    with np.load(write_grasps(tmp_path / "grasps.npz", n=n)) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["grasp_id"] = np.array([7, 9])[:n]
    arrays["score_max_penetration_mm"] = np.array([0.25, 1.5])[:n]
    arrays["score_pads_in_contact"] = np.array([5, 3])[:n]
    arrays["score_force_closure_residual"] = np.array([0.01, 0.04])[:n]
    return arrays


def test_grasp_views_stand_at_the_distance_two_above_one_below(tmp_path):
    pose = _arrays(tmp_path, 1)["hand_pose"][0]
    centre = np.array([0.0, 0.0, 0.085])
    eyes = [np.linalg.inv(T)[:3, 3] for T in grasp_views(pose)]
    np.testing.assert_allclose([np.linalg.norm(e - centre) for e in eyes], VIEW_DISTANCE_M, atol=1e-9)
    np.testing.assert_allclose([np.arcsin((e - centre)[2] / VIEW_DISTANCE_M) for e in eyes],
                               np.deg2rad([20.0, 20.0, -40.0]), atol=1e-9)
    # the lower camera faces the side away from the forearm (the hand's -x axis points up the forearm)
    forearm = -axis_angle_to_matrix(pose[:3])[:, 0]
    assert np.dot((eyes[2] - centre)[:2], forearm[:2]) < 0


def test_contact_sheet_layout_titles_and_header(tmp_path):
    sheet = contact_sheet(_arrays(tmp_path), size=64, split_of={7: "train"})
    title, gap, width = 22 + 16, 6, 3 * (64 + 6) + 6
    grid_h = 2 * (64 + title) + 3 * gap
    assert sheet.shape[1] == width
    header_h = sheet.shape[0] - grid_h - gap
    assert header_h > 60 and (sheet[:header_h] < 128).any()
    grid = sheet[header_h + gap :]
    tiles = []
    for row in range(2):
        for col in range(3):
            y, x = gap + row * (64 + title + gap), gap + col * (64 + gap)
            bar, tile = grid[y : y + title, x : x + 64], grid[y + title : y + title + 64, x : x + 64]
            assert (bar[:22] < 128).any() and (bar[22:] < 128).any(), (row, col)  # two title lines
            assert np.all(bar[:, -2:] == WHITE), (row, col)  # titles fit the tile
            assert (tile < 200).any(), (row, col)  # something rendered
            tiles.append(tile.astype(int))
    for a in range(6):
        for b in range(a + 1, 6):
            assert np.abs(tiles[a] - tiles[b]).mean() > 1.0, (a, b)  # six different pictures

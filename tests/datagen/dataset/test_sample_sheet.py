"""The dataset pictures: the per-background sample sheet and the overview (views, distances, grasps, legends)."""

import json
import shutil

import cv2
import numpy as np
import pytest
from helpers.datasets import TINY_SPEC, write_grasps

from hupbench.datagen.dataset.sample_sheet import (
    legends,
    overview,
    overview_plan,
    sample_sheet,
    sphere_map,
    spread_views,
)
from hupbench.core.draw import (
    FINGER_RGB,
    PROBE_RGB,
    SEG_RGB,
    colorize_depth,
    depth_color_bar,
    titled,
)

WHITE = 255


@pytest.fixture(scope="module")
def two_distances(tmp_path_factory):
    """One grasp at two camera distances (0.5 and 0.8 m), one background, one glove, 48 px frames, train only."""
    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    folder = tmp_path_factory.mktemp("two_distances")
    grasps, root = write_grasps(folder / "grasps.npz", n=1), folder / "dataset"
    spec = DatasetSpec(**(TINY_SPEC | {"splits": {"train": 1, "val": 0, "test": 0}, "z_ego_m": (0.5, 0.8),
                                       "n_backgrounds": 1, "width": 48, "height": 48, "fx": 90.0, "fy": 90.0,
                                       "cx": 24.0, "cy": 24.0}))
    generate(GenerateRun(spec, root, grasps, progress=False), {"test": "two_distances"}, log=lambda *_: None)
    return root


def _has_colour(image, rgb) -> bool:
    return bool(np.all(image == np.asarray(rgb, dtype=np.uint8), axis=-1).any())


def _blobs(image, rgb, min_area) -> int:
    """Connected regions of exactly ``rgb`` with at least ``min_area`` pixels."""
    mask = np.all(image == np.asarray(rgb, dtype=np.uint8), axis=-1).astype(np.uint8)
    _, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    return int((stats[1:, cv2.CC_STAT_AREA] >= min_area).sum())


def test_sample_sheet_tiles_then_legends(tiny_dataset):
    """Two backgrounds x one glove: two rows of four tiles, then a footer holding every legend colour."""
    sheet = sample_sheet(tiny_dataset, view=3, tile_px=32)
    grid_w, grid_h = 4 * 32 + 5 * 6, 2 * (32 + 22) + 3 * 6
    assert sheet.shape[1] == 900  # the footer's minimum width, wider than the grid
    assert np.all(sheet[:grid_h, grid_w:] == WHITE)  # nothing right of the four columns
    for row in range(2):
        for col in range(4):
            y, x = 6 + row * (32 + 22 + 6) + 22, 6 + col * (32 + 6)
            assert not np.all(sheet[y : y + 32, x : x + 32] == WHITE), (row, col)
    footer = sheet[grid_h + 6 :]
    assert footer.shape[0] > 40
    for rgb in [*SEG_RGB[1:4], *FINGER_RGB.values(), PROBE_RGB]:  # the paper protocol's labels: no patient
        assert _has_colour(footer, rgb), rgb


def test_colorize_depth_on_a_fixed_range_clips_and_keeps_its_default():
    depth_m = np.array([[0.3, 0.4, 0.65, 0.9, 1.0, 0.0]])
    fixed = colorize_depth(depth_m, 0.4, 0.9)
    assert np.array_equal(fixed[0, 0], fixed[0, 1]) and np.array_equal(fixed[0, 4], fixed[0, 3])
    assert not np.array_equal(fixed[0, 1], fixed[0, 3]) and np.all(fixed[0, 5] == 0)
    assert np.array_equal(colorize_depth(depth_m), colorize_depth(depth_m, 0.3, 1.0))


def test_depth_color_bar_ends_and_ticks():
    """The bar is colorize_depth's own ramp (near at the left) with 1-2-5 ticks: 0.4, 0.6, 0.8 on 0.4-0.9 m."""
    bar = depth_color_bar(0.4, 0.9, width=300, height=16)
    top, margin, length = 22, 24, 300 - 48
    assert np.array_equal(bar[top + 8, margin], colorize_depth(np.array([[0.4]]), 0.4, 0.9)[0, 0])
    assert np.array_equal(bar[top + 8, margin + length - 1], colorize_depth(np.array([[0.9]]), 0.4, 0.9)[0, 0])
    tick_row = bar[top + 16 + 2, :, 0]
    assert list(np.flatnonzero(tick_row < 100)) == [margin + round(k * (length - 1) / 2.5) for k in range(3)]


def test_titles_fit_their_tile():
    """A title wider than its tile is drawn smaller, never past the right edge; lines stack in a taller bar."""
    image = np.zeros((40, 96, 3), dtype=np.uint8)
    long = titled(image, "consultation_room / glove 1")
    assert long.shape == (62, 96, 3)
    assert np.all(long[:22, -3:] == WHITE) and (long[:22] < 128).any()
    two = titled(image, "grasp 108 (train)\nplain_white / glove 0")
    assert two.shape == (40 + 22 + 16, 96, 3) and (two[:22] < 128).any() and (two[22:38] < 128).any()
    assert np.array_equal(titled(image, "depth")[22:], image)


def test_spread_views_are_distinct_and_start_from_the_given_view():
    theta = np.deg2rad([0.0, 20, 20, 20, 90, 90, 90, 90, 160])
    phi = np.deg2rad([0.0, 0, 120, 240, 0, 90, 180, 270, 0])
    views = spread_views(theta, phi, 4, first=4)
    assert len(set(views)) == 4 and 4 in views
    assert spread_views(theta, phi, 2, first=4) == [4, 6]  # the antipode comes first
    top, bottom = spread_views(theta, phi, 2, first=8)  # from near the bottom: a view of the top ring
    assert bottom == 8 and theta[top] <= np.deg2rad(20)
    assert spread_views(theta, phi, 20, first=0) == list(range(9))


def test_overview_plan_spans_views_distances_and_grasps(tiny_dataset, two_distances):
    plan = overview_plan(tiny_dataset, n_views=6)
    train = plan["annotations"]["train"]
    view_ids = [int(train["view_id"][r]) for _, r in plan["views"]]
    assert len(view_ids) == 6 and len(set(view_ids)) == 6
    assert {int(train["grasp_index"][r]) for _, r in plan["views"]} == {int(train["grasp_index"].min())}
    assert [s for s, _ in plan["grasps"]] == ["train", "val", "test"]
    grasp_ids = [int(plan["annotations"][s]["grasp_id"][r]) for s, r in plan["grasps"]]
    assert len(set(grasp_ids)) == 3
    # backgrounds in turn
    assert [int(plan["annotations"][s]["background_id"][r]) for s, r in plan["grasps"]] == [0, 1, 0]
    assert len(plan["sphere"]) == len(np.unique(train["view_id"]))

    plan = overview_plan(two_distances)
    train = plan["annotations"]["train"]
    rows = [r for _, r in plan["distances"]]
    assert [float(train["z_ego"][r]) for r in rows] == [0.5, 0.8]
    assert len({int(train["view_id"][r]) for r in rows}) == 1
    assert int(train["view_id"][rows[0]]) == plan["first_view"]


def test_sphere_map_numbers_the_chosen_views():
    sphere = np.array([[v, t, p] for v, (t, p) in enumerate([(0.3, 0.0), (0.3, 2.0), (1.5, 1.0), (1.5, 4.0),
                                                             (2.8, 3.0)])], dtype=np.float64)
    image = sphere_map(sphere, [1, 3], 400, 240)
    assert _blobs(image, (40, 90, 220), 100) == 2  # chosen: large blue dots (the digits are smaller)
    assert _blobs(image, (150, 150, 150), 20) == 3  # the others: grey dots


def test_overview_draws_distinct_views_and_legends(two_distances):
    image = overview(two_distances, tile_px=48, columns=4, n_views=5)
    plan = overview_plan(two_distances, n_views=5)
    assert image.shape[1] == 4 * (48 + 6) + 6
    assert _blobs(image, (40, 90, 220), 100) == 5  # the map numbers five views
    assert _blobs(image, (150, 150, 150), 20) == len(plan["sphere"]) - 5
    bottom = image[-legends(plan["manifest"], (0.4, 0.9), image.shape[1]).shape[0] :]
    for rgb in [SEG_RGB[1], SEG_RGB[3], PROBE_RGB, FINGER_RGB["thumb"]]:
        assert _has_colour(bottom, rgb), rgb


def test_pictures_need_every_modality(tiny_dataset, tmp_path):
    broken = tmp_path / "copy"
    shutil.copytree(tiny_dataset, broken)
    manifest = json.loads((broken / "manifest.json").read_text())
    manifest["modalities"] = ["rgb", "depth"]
    (broken / "manifest.json").write_text(json.dumps(manifest))
    shutil.rmtree(broken / "train" / "seg")
    for draw in (overview, sample_sheet):
        with pytest.raises(ValueError, match=r"a sample sheet needs rgb, depth and seg; the dataset lacks \['seg'\]"):
            draw(broken)

import numpy as np
import pytest

from hupbench.datagen.dataset.spec import DatasetSpec, Layout, lamp, protocol, split_of_grasps, view_directions_arm
from hupbench.datagen.dataset.writer import parse_shard
from hupbench.datagen.dataset.sphere import SphereSpec, viewpoints


def test_bijection_covers_every_frame_once():
    layout = Layout(11, 2, 8, 2, 90)
    assert layout.size == 31680 and layout.chunk_size == 180 and layout.n_chunks == 176
    seen = set()
    for i in range(0, layout.size, 7):
        t = layout.tuple(i)
        assert layout.index(*t) == i
        seen.add(t)
    assert len(seen) == len(range(0, layout.size, 7))
    # viewpoints run fastest, grasps slowest, as documented
    assert layout.tuple(0) == (0, 0, 0, 0, 0) and layout.tuple(1) == (0, 0, 0, 0, 1)
    assert layout.tuple(90) == (0, 0, 0, 1, 0) and layout.tuple(180) == (0, 0, 1, 0, 0)
    assert layout.tuple(31679) == (10, 1, 7, 1, 89)
    # a chunk is one (grasp, z, background) block
    frames = list(layout.chunk_frames(5))
    assert len({layout.tuple(i)[:3] for i in frames}) == 1


def test_default_split_matches_hup3d():
    spec = DatasetSpec()
    splits = split_of_grasps(spec, 11)
    assert [len(splits[s]) for s in ("train", "val", "test")] == [7, 2, 2]
    frames_per_grasp = 2 * 8 * 2 * 90
    assert 7 * frames_per_grasp == 20160 and 2 * frames_per_grasp == 5760
    with pytest.raises(ValueError, match="add up to 11 grasps but the grasps file holds 12"):
        split_of_grasps(spec, 12)


def test_lamp_is_a_pure_function_of_seed_and_index():
    spec = DatasetSpec()
    a, b, c = lamp(spec, 17), lamp(spec, 17), lamp(DatasetSpec(seed=1), 17)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert not np.allclose(a["position_cam"], c["position_cam"])
    many = np.array([lamp(spec, i)["position_cam"] for i in range(300)])
    assert np.all(many[:, 0] >= -0.6) and np.all(many[:, 0] <= 0.6)
    assert np.all(-many[:, 1] >= 0.1) and np.all(-many[:, 1] <= 0.4)  # above the optical axis
    np.testing.assert_allclose(many[:, 2], -0.5)  # behind the camera, as in the published renderer
    colors = np.array([lamp(spec, i)["color"] for i in range(300)])
    np.testing.assert_array_equal(colors[:, 0], colors[:, 1])
    assert colors.min() >= 0.6 and colors.max() <= 1.0
    energy = np.array([lamp(spec, i)["energy_w"] for i in range(300)])
    assert energy.min() >= 50 and energy.max() <= 300


@pytest.mark.parametrize("kwargs, message", [
    (dict(z_ego_m=(0.5, 0.0)), "z_ego_m must be a non-empty list of camera distances from 0.1 to 10.0 m"),
    (dict(z_ego_m=(-0.5,)), "z_ego_m must be a non-empty list of camera distances from 0.1 to 10.0 m"),
    (dict(modalities=("rgb", "normals")), "unknown modality 'normals'"),
    (dict(splits={"train": 7, "dev": 4}), "splits must map"),
    (dict(width=0), "dataset.width must be a whole number from 16 to 8192"),
    (dict(rgb_format="bmp"), "rgb_format"),
    (dict(look_at="centre"), "look_at must be 'box_centre' or a keypoint name .* got 'centre'"),
])
def test_bad_dataset_spec(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DatasetSpec(**kwargs)


def test_parse_shard():
    assert parse_shard(None) == (0, 1) and parse_shard("2/4") == (2, 4)
    for bad in ("4/4", "a/b", "1", "-1/3"):
        with pytest.raises(ValueError, match="shard"):
            parse_shard(bad)


def test_default_protocol_is_the_papers_and_the_earlier_one_is_named():
    paper = protocol(DatasetSpec())
    assert paper["name"] == "paper" and paper["sphere_axis"] == "body" and paper["look_at"] == "middle_mcp"
    assert paper["excluded_view_ids"] == [34, 50] and paper["look_at_index"] == 9
    earlier = protocol(DatasetSpec(sphere=SphereSpec(axis="forearm", exclude=("poles",)), look_at="box_centre"))
    assert earlier["name"] == "forearm_box_centre" and earlier["excluded_view_ids"] == [0, 91]
    assert earlier["look_at_index"] is None
    assert protocol(DatasetSpec(look_at="wrist"))["name"] == "custom"


@pytest.mark.parametrize("axis", ["body", "forearm"])
def test_view_directions_in_the_arm_frame(axis):
    """(elbow, dorsal, thumb side) components: the published sphere has 16 views exactly perpendicular to
    the forearm and its north pole on the back of the hand; the forearm sphere has none perpendicular."""
    sphere = SphereSpec(axis=axis, exclude=())
    ids, angles = viewpoints(sphere)
    d = view_directions_arm(sphere, angles)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    perpendicular = int(np.sum(np.abs(d[:, 0]) < 1e-9))
    if axis == "body":
        assert perpendicular == 16
        np.testing.assert_allclose(d[0], [0.0, 1.0, 0.0], atol=1e-12)  # north: dorsal
        np.testing.assert_allclose(d[34], [np.cos(np.radians(10)), np.sin(np.radians(10)), 0.0], atol=1e-12)
    else:
        assert perpendicular == 0
        np.testing.assert_allclose(d[0], [1.0, 0.0, 0.0], atol=1e-12)  # north: elbow

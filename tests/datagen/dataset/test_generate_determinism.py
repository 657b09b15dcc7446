"""A dataset is a function of its config: the same bytes with any number of workers, in any process.

The cause of the earlier variation (measured): where the hand and the forearm meet at the wrist, a
pixel can hold both at exactly the same depth; OpenGL's GL_LESS keeps the mesh drawn first, and
pyrender drew meshes in the iteration order of a set of nodes (their memory addresses), which
differs between processes. Parts are now drawn in the order given to ``Renderer.set_parts``.
"""

import numpy as np
import pytest

from hupbench.datagen.render import gl
from hupbench.datagen.dataset.chunks import frame_camera
from hupbench.datagen.dataset.grasps_file import GraspSet
from hupbench.datagen.dataset.spec import DatasetSpec, Layout
from hupbench.datagen.dataset.writer import GenerateRun, generate
from hupbench.datagen.render.renderer import Renderer
from hupbench.datagen.render.scene import Grasp, scene_parts
from hupbench.datagen.dataset.sphere import viewpoints

from helpers.datasets import TINY_SPEC as TINY, write_grasps  # noqa: E402  (tests/ is on sys.path)

#: the tiny sphere at 256 px (fx 480, principal point 127.5): frame 1 (grasp 0, view 1) and frame 11 (grasp 1,
#: view 1) each hold one pixel where the hand and the forearm are at the same depth
TIES_256 = TINY | dict(width=256, height=256, fx=480.0, fy=480.0, cx=127.5, cy=127.5, n_backgrounds=1)
TIE_FRAME = 1


def _files(root):
    """{relative path: bytes} of every file under ``root``."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def tie_scene(tmp_path_factory):
    """A renderer holding grasp 0 and the camera of a frame with a hand/arm depth tie."""
    grasps_path = write_grasps(tmp_path_factory.mktemp("ties") / "grasps.npz", n=2)
    spec = DatasetSpec(**TIES_256)
    grasps = GraspSet(grasps_path)
    layout = Layout(len(grasps), len(spec.z_ego_m), spec.n_backgrounds, spec.n_gloves, len(viewpoints(spec.sphere)[0]))
    cam = frame_camera(spec, grasps, layout, TIE_FRAME)
    renderer = Renderer(spec.intrinsics)
    renderer.set_parts(scene_parts(Grasp(grasps.hand_pose[cam["grasp"]], grasps.hand_trans[cam["grasp"]])))
    yield renderer, cam["T_cam_world"]
    renderer.close()


class _OrderedNodes(list):
    """Stands in for pyrender's ``Scene._mesh_nodes`` set with a chosen iteration order."""

    def add(self, node):
        self.append(node)


def _render_with_node_order(renderer, T_cam_world, reverse):
    scene = renderer._scene
    before = scene._mesh_nodes
    nodes = sorted(before, key=lambda n: getattr(n, gl.DRAW_RANK), reverse=reverse)
    scene._mesh_nodes = _OrderedNodes(nodes)
    try:
        return renderer.render(T_cam_world, ("rgb", "depth", "seg"))
    finally:
        scene._mesh_nodes = before


def test_a_depth_tie_is_decided_by_the_part_order_not_by_the_node_set_order(tie_scene):
    renderer, T_cam_world = tie_scene
    forward = _render_with_node_order(renderer, T_cam_world, reverse=False)
    backward = _render_with_node_order(renderer, T_cam_world, reverse=True)
    for key in forward:
        np.testing.assert_array_equal(forward[key], backward[key], err_msg=key)
    # the frame does hold a tie: ranking the arm first hands its pixel(s) to the arm
    nodes = {n.name: n for n in renderer._scene.mesh_nodes}
    ranks = {name: getattr(node, gl.DRAW_RANK) for name, node in nodes.items()}
    try:
        setattr(nodes["arm"], gl.DRAW_RANK, -1)
        arm_first = renderer.render(T_cam_world, ("rgb", "depth", "seg"))
    finally:
        for name, rank in ranks.items():
            setattr(nodes[name], gl.DRAW_RANK, rank)
    changed = forward["seg"] != arm_first["seg"]
    assert 1 <= changed.sum() <= 5, changed.sum()
    assert set(forward["seg"][changed]) == {1} and set(arm_first["seg"][changed]) == {2}  # hand (first) wins
    np.testing.assert_array_equal(forward["depth"], arm_first["depth"])  # an exact tie: the depth is the same


def test_parts_are_drawn_in_the_order_given(tie_scene):
    renderer, _ = tie_scene
    inner = renderer._renderer._renderer  # pyrender's Renderer behind the OffscreenRenderer
    for reverse in (False, True):
        before = renderer._scene._mesh_nodes
        renderer._scene._mesh_nodes = _OrderedNodes(sorted(before, key=lambda n: n.name, reverse=reverse))
        try:
            order = [n.name for n in inner._sorted_mesh_nodes(renderer._scene)]
        finally:
            renderer._scene._mesh_nodes = before
        assert order == ["hand", "arm", "probe_body", "probe_lens", "probe_marker"]


@pytest.mark.parametrize("spec, frames", [
    # 20 frames at 256 px, two of them with a hand/arm depth tie
    pytest.param(TIES_256, 20, id="ties-256px"),
    pytest.param(TINY, 40, id="tiny-64px", marks=pytest.mark.slow),
])
def test_one_and_two_workers_write_the_same_bytes(tmp_path, spec, frames):
    """Every file compared, the manifest too."""
    grasps = write_grasps(tmp_path / "grasps.npz", n=2)
    spec = DatasetSpec(**spec)
    for workers in (1, 2):
        result = generate(GenerateRun(spec, tmp_path / f"w{workers}", grasps, progress=False, workers=workers),
                          {"test": "determinism"}, log=lambda *_: None)
        assert result["complete"] and result["frames_rendered"] == frames
    one, two = _files(tmp_path / "w1"), _files(tmp_path / "w2")
    assert sorted(one) == sorted(two)
    assert len([name for name in one if name.endswith((".jpg", ".png"))]) == 3 * frames
    different = [name for name in one if one[name] != two[name]]
    assert not different, different

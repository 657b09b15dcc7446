"""The probe's fit to the depth input (hupbench.fits.probe_fit) on scenes ray-cast by trimesh, an independent
renderer: the probe mesh in a known pose, its marker in the marker's colour, a finger-sized cylinder against its
handle. The fit must find the pose the depth shows from a network's pose turned away from it, read the half turn
from the marker's colour (or its absence), fall back to the network's turn where neither site is in view, and
leave the network's corners where no surface is measured."""

import dataclasses

import numpy as np
import pytest
import trimesh

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.probe import build_probe
from hupbench.fits.known_probe import FitProbe, default_fit_probe
from hupbench.datagen.render.scene import PROBE_BODY_RGB, PROBE_MARKER_RGB
from hupbench.fits import probe_fit as F

S = 128
K = np.array([[240.0, 0.0, 63.75], [0.0, 240.0, 63.75], [0.0, 0.0, 1.0]])


def turn_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(x_towards, z_along, origin):
    """Probe-to-camera rotation with the probe's +x as near ``x_towards`` as its +z = ``z_along`` allows."""
    z = np.asarray(z_along, float) / np.linalg.norm(z_along)
    x = np.asarray(x_towards, float) - np.dot(x_towards, z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z]), np.asarray(origin, float)


#: the marker (+x side) towards the camera; and the head's broad face towards it, both sites edge-on
MARKER_IN_VIEW = pose((0.3, 0.2, -1.0), (1.0, 0.1, 0.3), (-0.06, 0.0, 0.6))
SITES_EDGE_ON = pose((1.0, 0.05, 0.0), (0.1, 1.0, 0.25), (0.0, -0.07, 0.6))


def render(R, t, marker_coloured=True, finger=True):
    """(4, S, S) float32 model image of the probe posed by (R, t), ray-cast with trimesh."""
    probe = build_probe()
    meshes = [trimesh.Trimesh(probe.mesh.vertices @ R.T + t, probe.mesh.faces, process=False)]
    colours = [np.where(probe.marker_face_mask[:, None] & marker_coloured, PROBE_MARKER_RGB, PROBE_BODY_RGB)]
    if finger:  # across the handle, touching its -y side
        cylinder = trimesh.creation.cylinder(radius=0.009, height=0.09, sections=24)
        along_x = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # the cylinder's z onto x
        local = cylinder.vertices @ along_x.T + [0.0, -0.026, 0.12]
        meshes.append(trimesh.Trimesh(local @ R.T + t, cylinder.faces, process=False))
        colours.append(np.tile([0.76, 0.57, 0.45], (len(cylinder.faces), 1)))
    scene = trimesh.util.concatenate(meshes)
    face_rgb = np.concatenate(colours)
    v, u = np.mgrid[0:S, 0:S]
    rays = np.stack([(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1], np.ones(S * S)], 1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    hits, ray, tri = scene.ray.intersects_location(np.zeros_like(rays), rays, multiple_hits=False)
    image = np.zeros((4, S * S), np.float32)
    image[:3] = 0.5  # a grey background, no depth
    image[:3, ray] = face_rgb[tri].T
    image[3, ray] = hits[:, 2]
    return image.reshape(4, S, S)


def occlude(image, point):
    """A finger-coloured patch of 9 x 9 pixels 3 cm in front of ``point`` (camera frame) in ``image``; its (v, u)."""
    u, v = np.round(point[:2] / point[2] * [K[0, 0], K[1, 1]] + K[:2, 2]).astype(int)
    image[:3, v - 4:v + 5, u - 4:u + 5] = np.asarray([0.76, 0.57, 0.45], np.float32)[:, None, None]
    image[3, v - 4:v + 5, u - 4:u + 5] = point[2] - 0.03
    return v, u


def corners(R, t):
    return build_probe().corners_probe @ R.T + t


def network_output(R, t, turn=0.0, shift=(0.0, 0.0, 0.0)):
    """(1, 29, 2), (1, 29, 3): a network's output whose probe is (R, t) turned about its long axis and shifted."""
    points3d = np.zeros((1, kp.NUM_KEYPOINTS, 3))
    points3d[0, :kp.NUM_HAND] = t + [0.0, 0.05, 0.0]
    points3d[0, kp.CORNER_SLICE] = corners(R @ turn_z(turn), t + np.asarray(shift))
    return np.zeros((1, kp.NUM_KEYPOINTS, 2)), points3d


def fit(image, points2d, points3d):
    out2d, out3d, report = F.fit_probe(points2d, points3d, image[None], K)
    return out2d[0], out3d[0], F.DECISIONS[report.decision[0]]


def error_mm(points, R, t):
    return float(np.linalg.norm(points[kp.CORNER_SLICE] - corners(R, t), axis=1).mean() * 1000)


def test_signed_distance_and_gradient_match_the_probe():
    """The fits' probe (its grid as float32) against the generator's numpy signed distance and gradient, inside
    and outside the grid's box."""
    probe = build_probe()
    q = np.random.default_rng(0).uniform([-0.1, -0.07, -0.05], [0.1, 0.07, 0.25], (4000, 3))
    d, g = default_fit_probe().signed_distance_and_gradient(q)
    np.testing.assert_allclose(d, probe.signed_distance(q), atol=2e-6)
    # the gradient inside the grid's box (outside it the fit leaves the points out: they are far from the surface)
    upper = probe.sdf_origin + probe.sdf_spacing * (np.array(probe.sdf_grid.shape) - 1)
    inside = ((q > probe.sdf_origin) & (q < upper)).all(axis=1)
    assert inside.mean() > 0.25
    np.testing.assert_allclose(g[inside], probe.signed_distance_gradient(q[inside]), atol=1e-3)
    outside = ~((q >= probe.sdf_origin) & (q <= upper)).all(axis=1)
    assert outside.mean() > 0.2
    np.testing.assert_allclose(np.linalg.norm(g[outside], axis=1), 1.0, atol=1e-9)   # away from the box


@pytest.mark.parametrize("turn", [np.pi / 2, -np.pi / 3, np.pi])
def test_the_fit_finds_the_pose_the_depth_shows(turn):
    R, t = MARKER_IN_VIEW
    points2d, points3d = network_output(R, t, turn, shift=(0.006, -0.004, 0.005))
    assert error_mm(points3d[0], R, t) > 15
    out2d, out3d, decision = fit(render(R, t), points2d, points3d)
    assert decision == "marker"
    assert error_mm(out3d, R, t) < 2.0
    # an exact box, its 2D the projection; the hand as it was
    box = corners(np.eye(3), np.zeros(3))
    got = out3d[kp.CORNER_SLICE]
    np.testing.assert_allclose(np.linalg.norm(got[:, None] - got[None], axis=-1),
                               np.linalg.norm(box[:, None] - box[None], axis=-1), atol=1e-5)
    uv = got[:, :2] / got[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
    np.testing.assert_allclose(out2d[kp.CORNER_SLICE], (2 * uv + 1) / S - 1, atol=1e-6)
    np.testing.assert_array_equal(out3d[:kp.NUM_HAND], points3d[0, :kp.NUM_HAND])
    np.testing.assert_array_equal(out2d[:kp.NUM_HAND], points2d[0, :kp.NUM_HAND])


def test_where_the_sensor_sees_no_depth_on_the_marker_the_segmentation_shows_it():
    """A time-of-flight camera returns no depth from much of the probe's dark plastic: here three pixels in four of
    the probe, and the marker with 2 pixels around it, have none. The marker's window then has no depth to show the
    site, and the network's (wrong) half turn decides; given the probe's pixels (a segmentation), those without
    depth show the probe, and the marker's colour decides the half turn. Without them the fitted surface's pixels
    show no marker either, but the window of the site facing the camera has no depth: the marker may be there, so
    the turn turned away from the camera does not win ("marker hidden" needs depth in that window)."""
    R, t = MARKER_IN_VIEW
    image = render(R, t, finger=False)
    probe_pixels = image[3] > 0
    marker = (np.abs(image[:3] - np.asarray(PROBE_MARKER_RGB, np.float32)[:, None, None]).max(0) < 1e-3) & probe_pixels
    assert marker.sum() > 4
    v, u = np.mgrid[0:S, 0:S]
    near_marker = np.zeros_like(marker)
    for dv in range(-2, 3):
        for du in range(-2, 3):
            near_marker |= np.roll(marker, (dv, du), axis=(0, 1))
    image[3][((u % 2 == 1) | (v % 2 == 1)) | near_marker] = 0.0
    assert 30 < (image[3] > 0).sum() < 0.3 * probe_pixels.sum()
    points2d, points3d = network_output(R, t, np.pi, shift=(0.004, -0.003, 0.004))
    blind = F.fit_probe(points2d, points3d, image[None], K)
    seen = F.fit_probe(points2d, points3d, image[None], K, pixels=probe_pixels[None])
    assert F.DECISIONS[blind[2].decision[0]] == "network" and error_mm(blind[1][0], R, t) > 50
    assert F.DECISIONS[seen[2].decision[0]] == "marker" and error_mm(seen[1][0], R, t) < 3.0


def test_a_marker_site_in_view_without_the_colour_means_the_other_turn():
    R, t = MARKER_IN_VIEW
    points2d, points3d = network_output(R, t)        # the network right, the marker painted over
    _, out3d, decision = fit(render(R, t, marker_coloured=False), points2d, points3d)
    assert decision == "no marker"
    assert error_mm(out3d, R @ turn_z(np.pi), t) < 2.0


@pytest.mark.parametrize("turn, expected", [(np.pi / 3, 0.0), (np.pi * 5 / 6, np.pi)])
def test_with_both_sites_out_of_view_the_network_picks_the_half_turn(turn, expected):
    """Both sites edge-on (neither faces the camera), and no pixel of the marker's colour: its 2 mm stand out of
    the silhouette is painted over, so that nothing in the image tells the half turn."""
    R, t = SITES_EDGE_ON
    points2d, points3d = network_output(R, t, turn)
    _, out3d, decision = fit(render(R, t, marker_coloured=False), points2d, points3d)
    assert decision == "network"
    assert error_mm(out3d, R @ turn_z(expected), t) < 2.0


def test_without_a_measured_surface_the_network_stays(monkeypatch):
    def no_search(*_):
        raise AssertionError("a frame with fewer points than min_inliers was refined")

    monkeypatch.setattr(F, "_refine", no_search)
    R, t = MARKER_IN_VIEW
    points2d, points3d = network_output(R, t, np.pi / 2)
    image = render(R, t)
    image[3] = 0.0
    out2d, out3d, decision = fit(image, points2d, points3d)
    assert decision == "kept"
    assert np.isnan(F.fit_probe(points2d, points3d, image[None], K)[2].pose).all()   # no start for the next frame
    np.testing.assert_array_equal(out3d, points3d[0])
    np.testing.assert_array_equal(out2d, points2d[0])


def test_a_batch_is_fitted_frame_by_frame():
    (R1, t1), (R2, t2) = MARKER_IN_VIEW, SITES_EDGE_ON
    a, b = network_output(R1, t1, np.pi / 2), network_output(R2, t2, np.pi / 3)
    images = np.stack([render(R1, t1), render(R2, t2, marker_coloured=False)])
    out2d, out3d, report = F.fit_probe(np.concatenate([a[0], b[0]]), np.concatenate([a[1], b[1]]), images, K)
    assert [F.DECISIONS[d] for d in report.decision] == ["marker", "network"]
    assert error_mm(out3d[0], R1, t1) < 2.0 and error_mm(out3d[1], R2, t2) < 2.0
    assert (report.inliers > F.ProbeFitSettings().min_inliers).all()


def test_a_setting_changes_what_the_probe_fit_does():
    """The same frame with min_inliers beyond any frame's points: the network's corners are kept."""
    R, t = MARKER_IN_VIEW
    image = render(R, t)[None]
    points2d, points3d = network_output(R, t, turn=0.5)
    _, fitted, report = F.fit_probe(points2d, points3d, image, K)
    _, kept, strict = F.fit_probe(points2d, points3d, image, K, F.ProbeFitSettings(min_inliers=10 ** 6))
    assert F.DECISIONS[report.decision[0]] == "marker" and F.DECISIONS[strict.decision[0]] == "kept"
    assert not np.allclose(fitted, points3d) and np.array_equal(kept, points3d)


def test_the_probe_read_back_from_its_json_fits_the_same_and_damage_is_refused():
    """A model file's probe (FitProbe.to_json) reads back equal; a changed grid byte or layout is one clear error."""
    from hupbench.core.errors import BadValueError
    import json

    probe = default_fit_probe()
    back = FitProbe.from_json(probe.to_json(), "model.onnx")
    assert back.record == probe.record == {"kind": "procedural"} and np.array_equal(back.grid, probe.grid)
    R, t = MARKER_IN_VIEW
    image = render(R, t)[None]
    points2d, points3d = network_output(R, t, turn=0.5)
    np.testing.assert_array_equal(F.fit_probe(points2d, points3d, image, K, probe=back)[1],
                                  F.fit_probe(points2d, points3d, image, K)[1])
    doc = json.loads(probe.to_json())
    for key, value, message in (("grid_sha256", "0" * 64, "distance grid is damaged"),
                                ("schema", 99, "probe layout 99"), ("corners", [[0.0] * 3] * 7, "corners")):
        with pytest.raises(BadValueError, match=message):
            FitProbe.from_json(json.dumps(doc | {key: value}), "model.onnx")
    with pytest.raises(BadValueError, match="model.onnx: not a probe of the fits"):
        FitProbe.from_json("{}", "model.onnx")


def test_tracking_starts_at_the_frame_before_and_keeps_its_half_turn(monkeypatch):
    """Nothing in the image tells the half turn (both sites edge-on, no marker colour) and the network's turn is the
    wrong one, which the frame alone keeps; started at the frame before's pose (3 mm and 4 degrees off), the fit
    keeps that half turn ("previous") without searching the turns, and returns its pose for the next frame."""
    R, t = SITES_EDGE_ON
    image = render(R, t, marker_coloured=False)
    points2d, points3d = network_output(R, t, np.pi * 5 / 6)
    _, alone, report = F.fit_probe(points2d, points3d, image[None], K)
    assert F.DECISIONS[report.decision[0]] == "network" and error_mm(alone[0], R @ turn_z(np.pi), t) < 2.0
    before = np.eye(4)
    before[:3, :3], before[:3, 3] = R @ turn_z(np.radians(4.0)), t + [0.003, 0.0, -0.001]

    def no_search(*_):
        raise AssertionError("a frame with a start searched the turns")

    monkeypatch.setattr(F, "_search", no_search)
    out2d, out3d, report = F.fit_probe(points2d, points3d, image[None], K, start=before[None])
    assert F.DECISIONS[report.decision[0]] == "previous"
    assert error_mm(out3d[0], R, t) < 2.0
    pose = report.pose[0]
    np.testing.assert_allclose(pose[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(corners(pose[:3, :3], pose[:3, 3]), out3d[0, kp.CORNER_SLICE], atol=1e-9)


def test_in_a_batch_a_frame_without_a_start_is_fitted_alone():
    (R1, t1), (R2, t2) = MARKER_IN_VIEW, SITES_EDGE_ON
    a, b = network_output(R1, t1, np.pi / 2), network_output(R2, t2, np.pi * 5 / 6)
    images = np.stack([render(R1, t1), render(R2, t2, marker_coloured=False)])
    start = np.full((2, 4, 4), np.nan)
    start[1] = np.eye(4)
    start[1, :3, :3], start[1, :3, 3] = R2, t2
    out2d, out3d, report = F.fit_probe(np.concatenate([a[0], b[0]]), np.concatenate([a[1], b[1]]), images, K,
                                       start=start)
    alone2d, alone3d, alone = F.fit_probe(*a, images[:1], K)
    np.testing.assert_array_equal(out3d[0], alone3d[0])
    np.testing.assert_array_equal(out2d[0], alone2d[0])
    assert [F.DECISIONS[d] for d in report.decision] == ["marker", "previous"]
    assert error_mm(out3d[1], R2, t2) < 2.0
    np.testing.assert_array_equal(report.pose[0], alone.pose[0])


@pytest.mark.parametrize("turn", [np.pi / 3, np.pi * 5 / 6])
def test_the_markers_pixels_read_the_half_turn_where_its_site_does_not(turn):
    """Both sites edge-on, the marker's 2 mm stand out of the silhouette in its colour, and the sites' windows told
    to see no colour (``marker_chroma`` 2): given the probe's pixels (a segmentation's), or without them those on
    the fitted surface, the centre of those with the marker's colour lies nearer the true turn's site, whichever
    turn the network gave; reading neither (``marker_surface_m`` 0, no segmentation) the network's turn decides."""
    R, t = SITES_EDGE_ON
    image = render(R, t)
    points2d, points3d = network_output(R, t, turn)
    windows_blind = dataclasses.replace(F.ProbeFitSettings(), marker_chroma=2.0)
    blind = F.fit_probe(points2d, points3d, image[None], K, dataclasses.replace(windows_blind, marker_surface_m=0.0))
    for pixels in ((image[3] > 0)[None], None):
        seen = F.fit_probe(points2d, points3d, image[None], K, windows_blind, pixels=pixels)
        assert F.DECISIONS[seen[2].decision[0]] == "marker pixels"
        assert error_mm(seen[1][0], R, t) < 2.0
    assert F.DECISIONS[blind[2].decision[0]] == "network"


@pytest.mark.parametrize("network_turn", [0.0, np.pi])
def test_a_marker_on_no_pixel_of_the_fitted_surface_is_on_the_side_turned_away(network_turn):
    """The marker's side turned away from the camera, and something 3 cm in front of the site that faces it (so
    that its window neither shows the marker nor says it is absent): without a segmentation, the fitted surface's
    pixels show no marker colour, so the turn whose site faces away wins, whichever turn the network gave; not
    reading them (``marker_surface_m`` 0), the network's turn decides."""
    R, t = MARKER_IN_VIEW
    R = R @ turn_z(np.pi)                                          # the marker's side away from the camera
    image = render(R, t, finger=False)
    probe = default_fit_probe()
    occlude(image, R @ turn_z(np.pi) @ probe.marker + t)           # the site facing the camera (no marker)
    points2d, points3d = network_output(R, t, network_turn)
    _, out3d, report = F.fit_probe(points2d, points3d, image[None], K)
    assert F.DECISIONS[report.decision[0]] == "marker hidden"
    assert error_mm(out3d[0], R, t) < 2.0
    unread = dataclasses.replace(F.ProbeFitSettings(), marker_surface_m=0.0)
    _, network3d, network = F.fit_probe(points2d, points3d, image[None], K, unread)
    assert F.DECISIONS[network.decision[0]] == "network"
    assert error_mm(network3d[0], R @ turn_z(network_turn), t) < 2.0


@pytest.mark.parametrize("turn", [np.pi, np.pi / 2, -np.pi / 3, -2.5])
def test_a_kept_frame_whose_marker_shows_takes_the_networks_box_in_the_roll_it_reads(turn):
    """No depth at all (the probe kept), the network's box turned about its long axis by any roll and 5 mm off across
    the view: given the probe's pixels the marker's colour turns it to the roll whose site projects on the marker's
    pixels and moves it there (within 6 mm: the rolls tried are 10 degrees apart), and the frame gives no start to
    the next; read as a half turn only (``marker_roll_deg`` 180) a quarter turn stays wrong; without the pixels the
    network's corners stay."""
    R, t = MARKER_IN_VIEW
    image = render(R, t)
    pixels = (image[3] > 0)[None]
    image[3] = 0.0
    points2d, points3d = network_output(R, t, turn, shift=(0.004, -0.003, 0.0))
    out2d, out3d, report = F.fit_probe(points2d, points3d, image[None], K, pixels=pixels)
    assert F.DECISIONS[report.decision[0]] == "kept, marker pixels" and np.isnan(report.pose).all()
    assert error_mm(out3d[0], R, t) < 6.0 < 30 < error_mm(points3d[0], R, t)
    np.testing.assert_array_equal(out3d[0, :kp.NUM_HAND], points3d[0, :kp.NUM_HAND])
    uv = out3d[0, kp.CORNER_SLICE, :2] / out3d[0, kp.CORNER_SLICE, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
    np.testing.assert_allclose(out2d[0, kp.CORNER_SLICE], (2 * uv + 1) / S - 1, atol=1e-6)
    half_turns = dataclasses.replace(F.ProbeFitSettings(), marker_roll_deg=180.0)
    _, halved, _ = F.fit_probe(points2d, points3d, image[None], K, half_turns, pixels=pixels)
    if abs(np.sin(turn)) > 0.8:  # a roll near a quarter turn: neither half turn of it is near the truth
        assert error_mm(halved[0], R, t) > 30
    _, kept3d, kept = F.fit_probe(points2d, points3d, image[None], K)
    assert F.DECISIONS[kept.decision[0]] == "kept"
    np.testing.assert_array_equal(kept3d, points3d)


@pytest.mark.parametrize("network_turn", [0.0, np.pi])
def test_a_marker_under_the_fingers_is_read_at_the_site_facing_the_camera(network_turn):
    """The marker's side towards the camera, a finger 3 cm in front of its site hiding it (no pixel of its colour,
    the finger's pixels not the probe's in the segmentation), the other site turned away: neither window nor pixel
    decides. With ``marker_under_hand`` the turn whose site faces the camera wins, whichever turn the network gave;
    without it (the default) the network's turn decides."""
    R, t = MARKER_IN_VIEW
    image = render(R, t, marker_coloured=False, finger=False)
    v, u = occlude(image, R @ default_fit_probe().marker + t)
    pixels = image[3] > 0
    pixels[v - 4:v + 5, u - 4:u + 5] = False
    points2d, points3d = network_output(R, t, network_turn)
    under = dataclasses.replace(F.ProbeFitSettings(), marker_under_hand=True)
    _, out3d, report = F.fit_probe(points2d, points3d, image[None], K, under, pixels=pixels[None])
    assert F.DECISIONS[report.decision[0]] == "marker under hand"
    assert error_mm(out3d[0], R, t) < 2.0
    _, network3d, network = F.fit_probe(points2d, points3d, image[None], K, pixels=pixels[None])
    assert F.DECISIONS[network.decision[0]] == "network"
    assert error_mm(network3d[0], R @ turn_z(network_turn), t) < 2.0
    _, _, unsegmented = F.fit_probe(points2d, points3d, image[None], K, under)
    assert F.DECISIONS[unsegmented.decision[0]] != "marker under hand"


@pytest.mark.parametrize("facing_a, facing_b", [(0.4, 0.6), (0.6, 0.4)])
def test_where_both_sites_face_the_camera_without_the_marker_the_one_facing_it_more_loses(monkeypatch, facing_a,
                                                                                         facing_b):
    """Both sites' windows read as facing the camera, seen, and without the marker's colour (the site reading
    stubbed: the procedural probe's marker normal (0.59, 0, 0.81) leans along the long axis, so both turns' sites face
    a camera that looks along that axis): the one facing it more
    loses the half turn, whichever turn it is (the first turn's site lost it always, 77.9 -> 3.6 mm on 36 clinic
    val frames)."""
    R, t = MARKER_IN_VIEW
    points2d, points3d = network_output(R, t)
    readings = iter([facing_a, facing_b])

    def site(probe, R_, t_, *args):
        n = len(R_)
        return np.full(n, next(readings)), np.ones(n), np.zeros(n), np.ones(n)  # facing, seen, lead, measured

    monkeypatch.setattr(F, "_marker_site", site)
    _, out3d, decision = fit(render(R, t, marker_coloured=False), points2d, points3d)
    assert decision == "no marker"
    assert error_mm(out3d, R @ turn_z(0.0 if facing_a < facing_b else np.pi), t) < 2.0


@pytest.mark.parametrize("wrong_roll", [np.pi / 2, -np.pi / 2, 2.0])
def test_a_fitted_roll_that_puts_neither_site_near_the_marker_pixels_takes_the_roll_they_read(monkeypatch,
                                                                                             wrong_roll):
    """The depth's search stubbed to a roll about the long axis the image does not show (on the clinic val frames
    whose half turn the marker's pixels lost, 76 degrees off, median), the sites' windows blind (``marker_chroma`` 2):
    given a segmentation whose marker's pixels lie farther than ``marker_reroll_px`` from both turns' sites, the pose
    takes the roll they read (within 6 mm: the rolls tried are 10 degrees apart); with the threshold out of reach the
    wrong roll stays, and without a segmentation nothing is read again."""
    R, t = MARKER_IN_VIEW
    image = render(R, t)
    pixels = (image[3] > 0)[None]
    points2d, points3d = network_output(R, t)

    def search(probe, points, weight, R0, t0, s):
        return R0 @ turn_z(wrong_roll), t0, np.full(len(points), 500)

    monkeypatch.setattr(F, "_search", search)
    blind = dataclasses.replace(F.ProbeFitSettings(), marker_chroma=2.0)
    _, out3d, report = F.fit_probe(points2d, points3d, image[None], K, blind, pixels=pixels)
    assert F.DECISIONS[report.decision[0]] == "marker pixels"
    assert error_mm(out3d[0], R, t) < 6.0
    np.testing.assert_allclose(report.pose[0, :3, :3] @ build_probe().corners_probe.T + report.pose[0, :3, 3:],
                               out3d[0, kp.CORNER_SLICE].T, atol=1e-9)
    for settings, segmentation in ((dataclasses.replace(blind, marker_reroll_px=1e9), pixels), (blind, None)):
        _, stays, _ = F.fit_probe(points2d, points3d, image[None], K, settings, pixels=segmentation)
        assert error_mm(stays[0], R, t) > 20

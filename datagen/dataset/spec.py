"""What a dataset is: its spec (the config), the frame layout, the lamp per frame and the protocol record.

The frame index is the mixed-radix number of (grasp, z_ego, background, glove, view), viewpoints fastest:

    i = (((grasp * n_z + z) * n_bg + bg) * n_glove + glove) * n_view + view

and frame ``i`` is a pure function of (config, i): its camera comes from the sphere, its lamp from a
generator seeded with (seed, i).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.camera import Intrinsics
from hupbench.core.contract import CLINIC, SENSOR_DEPTH, SPLITS, TRACKS, UNSEEN_GRASPS, UNSEEN_VIEWS
from hupbench.core.depth_sensor import NONE, SensorPreset
from hupbench.core.depth_sensor import preset as sensor_preset
from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import check_int, is_whole
from hupbench.datagen.assets.backgrounds import MIN_SIZE_PX
from hupbench.datagen.assets.hand_anatomy import HAND_LENGTH_M
from hupbench.datagen.dataset.head import HeadSpec
from hupbench.datagen.dataset.finger_motion import FingerMotionSpec
from hupbench.datagen.dataset.head_motion import HeadMotionSpec
from hupbench.datagen.dataset.scan_motion import ScanMotionSpec, clip_frames
from hupbench.datagen.dataset.sphere import SphereSpec, excluded_view_ids, sphere_frame, unit_directions, viewpoints
from hupbench.datagen.render.renderer import MODALITIES, check_modalities


GENERATOR_VERSION = "0.3.0"
#: HUP-3D's lamp box (the published renderer, manuelbirlo/HUP-3D_renderer), metres in the published renderer's camera frame: Blender's camera axes
#: (x right, y up, looking down -z), so z = 0.5 is half a metre behind the camera
LAMP_LOW = np.array([-0.6, 0.1, 0.5])
LAMP_HIGH = np.array([0.6, 0.4, 0.5])
#: what the camera can aim at besides a keypoint (by name): the centre of the 29 keypoints' box in
#: the world (probe) frame (the forearm protocol's aim)
BOX_CENTRE = "box_centre"
#: the published renderer's aim: the right middle-finger MCP (SMPL-H joint 40, our keypoint 9)
PAPER_LOOK_AT = "middle_mcp"
#: pyrender intensity per Blender watt, calibrated with the lamp box behind the camera so that the
#: median gloved-hand pixel of the default grasps' frames stores about 170 of 255
LAMP_INTENSITY_PER_WATT = 0.015


#: the camera distances a dataset may use, metres: nearer than 0.1 m the hand and probe reach behind the
#: camera plane (z_ego 0.001: 8 keypoints behind it), beyond 10 m they cover a few pixels
Z_EGO_RANGE_M = (0.1, 10.0)
#: the largest image side the renderer is asked for (as predict's largest input); the smallest is the
#: smallest a background image is made at (hupbench.datagen.assets.backgrounds.MIN_SIZE_PX)
MAX_IMAGE_SIDE = 8192
_SIDE_HINT = " (pixels)"


def _distances(z_ego_m) -> tuple[float, ...]:
    """``dataset.z_ego_m`` as a tuple of distinct camera distances in :data:`Z_EGO_RANGE_M`, metres."""
    low, high = Z_EGO_RANGE_M
    values = list(z_ego_m) if not isinstance(z_ego_m, (str, bytes)) and hasattr(z_ego_m, "__iter__") else None
    if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                             and low <= v <= high for v in values):
        raise BadValueError(f"dataset.z_ego_m must be a non-empty list of camera distances from {low} to {high} m "
                         f"(e.g. [0.5, 0.8]), got {z_ego_m if values is None else values!r}")
    repeated = sorted({float(v) for v in values if values.count(v) > 1})
    if repeated:
        raise BadValueError(f"dataset.z_ego_m lists {repeated} more than once: each distance renders every view, so a "
                            f"repeat renders the same frames again; list each distance once, got {values!r}")
    return tuple(float(v) for v in values)


def max_focal_px(side_px: int, z_ego_m: tuple[float, ...]) -> float:
    """The longest focal length, pixels, at which an image side of ``side_px`` pixels still spans the hand's
    length (:data:`hupbench.datagen.assets.hand_anatomy.HAND_LENGTH_M`) at the farthest camera distance.

    A pinhole camera of focal length f pixels sees ``side_px / f`` metres across per metre of distance
    (Hartley and Zisserman, Multiple View Geometry, 2nd ed., eq. 6.1): at ``max(z_ego_m)`` the side spans
    ``side_px * z / f`` metres, which must hold the hand, or no frame of the dataset shows it whole.
    """
    return side_px * max(z_ego_m) / HAND_LENGTH_M


def check_principal_point(intrinsics: Intrinsics, prefix: str) -> None:
    """The principal point lies in the image: the camera aims at the scene's look-at point, which lands
    there, so outside it the camera sees no foreground.

    Args:
        intrinsics: the camera. prefix: the config node's dotted path, e.g. ``"dataset."``.
    """
    for name, side in (("cx", intrinsics.width), ("cy", intrinsics.height)):
        value = getattr(intrinsics, name)
        if not -0.5 <= value <= side - 0.5:
            raise BadValueError(f"{prefix}{name} must put the principal point inside the image, from -0.5 to "
                                f"{side - 0.5:g} pixels (the camera aims there), got {value!r}")


@dataclass(frozen=True)
class DatasetSpec:
    """Everything that determines the frames (the ``dataset`` node of ``conf/generate.yaml``), checked here.

    Attributes:
        z_ego_m: camera distances to the grasp, metres, each listed once.
        splits: grasps per split, in the order of the grasps file (train, val, test), on the
            "unseen_grasps" and "clinic" tracks; None on the "unseen_views" track, where every grasp is in every
            split.
        track: what the evaluation splits hold out (``TRACKS``): "unseen_grasps" (HUP-3D's protocol,
            DexYCB's S3: whole grasps), "unseen_views" (DexYCB's S2: every grasp in every split, the
            views split by :func:`split_of_views`) or "clinic" (whole grasps, each with its own subject's hand and
            patient placement, seen by ``head``'s cameras instead of the sphere's).
        head: on the "clinic" track, where the cameras can be (:class:`hupbench.datagen.dataset.head.HeadSpec`);
            None on the others, whose cameras are the sphere's at ``z_ego_m``.
        scan, head_motion: set (both) for a dataset of clips on the clinic track (``hupbench generate
            +track=clinic_sequences``): how the probe moves on the skin
            (:class:`hupbench.datagen.dataset.scan_motion.ScanMotionSpec`, one clip length: every clip has
            :attr:`frames_per_clip` frames) and how the wearer's head moves
            (:class:`hupbench.datagen.dataset.head_motion.HeadMotionSpec`); each of a grasp's
            ``head.views_per_grasp`` cameras starts one clip. None (both) for single frames.
        fingers: on a dataset of clips, how the fingers adjust over a clip
            (:class:`hupbench.datagen.dataset.finger_motion.FingerMotionSpec`); None: the hand holds its grasp's
            pose throughout. Only with ``scan``.
        view_stride: on the "unseen_views" track, of every ``view_stride`` consecutive views of the
            sphere one goes to test and one to val (:func:`split_of_views`).
        modalities: which of rgb, depth, seg to write.
        depth_sensor: the depth camera whose measurement is written beside the clean depth as "sensor_depth"
            (:data:`hupbench.core.depth_sensor.PRESETS`), or "none" (the z-buffer alone: the paper protocol). A sensor
            needs the depth and seg modalities (it is made from the clean depth and each pixel's material).
        rgb_format: "jpg" or "png". jpeg_quality: 0-100.
        seed: lamp randomisation seed.
        sphere: the viewpoint sphere.
        look_at: the point each camera looks at from distance z_ego, which lands at
            (0, 0, z_ego) in the camera frame: a keypoint name (default "middle_mcp", keypoint 9,
            as the published renderer) or "box_centre" (centre of the 29 keypoints' box in the
            world frame).
        width, height, fx, fy, cx, cy: the camera, pixels: square images (the training and evaluation
            readers take square frames), the principal point inside the image, and a focal length short
            enough for the image to span the hand at the farthest camera distance (:func:`max_focal_px`).
        n_backgrounds, n_gloves: counts (backgrounds come from the background set; 1 or 2 gloves, HUP-3D's
            two glove colours).
        intrinsics: the camera as :class:`hupbench.core.camera.Intrinsics`, built once from the fields above.
    """

    z_ego_m: tuple = (0.5, 0.8)
    splits: dict | None = field(default_factory=lambda: {"train": 7, "val": 2, "test": 2})
    track: str = UNSEEN_GRASPS
    view_stride: int = 5
    modalities: tuple = MODALITIES
    depth_sensor: str = NONE
    rgb_format: str = "jpg"
    jpeg_quality: int = 95
    seed: int = 0
    sphere: SphereSpec = SphereSpec()
    look_at: str = PAPER_LOOK_AT
    width: int = 256
    height: int = 256
    fx: float = 480.0
    fy: float = 480.0
    cx: float = 128.0
    cy: float = 128.0
    n_backgrounds: int = 8
    n_gloves: int = 2
    head: HeadSpec | None = None
    scan: ScanMotionSpec | None = None
    head_motion: HeadMotionSpec | None = None
    fingers: FingerMotionSpec | None = None
    intrinsics: Intrinsics = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "z_ego_m", _distances(self.z_ego_m))
        hints = {"width": _SIDE_HINT, "height": _SIDE_HINT, "n_gloves": " (HUP-3D's two glove colours)"}
        for name, low, high in (("jpeg_quality", 0, 100), ("seed", 0, None), ("width", MIN_SIZE_PX, MAX_IMAGE_SIDE),
                                ("height", MIN_SIZE_PX, MAX_IMAGE_SIDE), ("n_backgrounds", 1, None), ("n_gloves", 1, 2)):
            check_int(getattr(self, name), f"dataset.{name}", low, high, hint=hints.get(name, ""))
        if self.track not in TRACKS:
            raise BadValueError(f"dataset.track must be one of {', '.join(TRACKS)}, got {self.track!r}")
        check_int(self.view_stride, "dataset.view_stride", 3, None)
        if (self.track == CLINIC) != (self.head is not None):
            raise BadValueError("dataset.head places the clinic track's cameras and only theirs: "
                                + ("set it (`hupbench generate +track=clinic` does)" if self.track == CLINIC else
                                   f"set dataset.head=null on the {self.track} track, or dataset.track=clinic"))
        if (self.scan is None) != (self.head_motion is None) or (self.scan is not None and self.track != CLINIC):
            raise BadValueError("dataset.scan and dataset.head_motion make clips on the clinic track, both or neither: "
                                "`hupbench generate +track=clinic_sequences` sets both, got "
                                f"scan={'set' if self.scan is not None else 'null'}, head_motion="
                                f"{'set' if self.head_motion is not None else 'null'} on the {self.track} track")
        if self.fingers is not None and self.scan is None:
            raise BadValueError("dataset.fingers moves the fingers over a clip: set it with dataset.scan "
                                "(`hupbench generate +track=clinic_sequences`), or dataset.fingers=null")
        if self.scan is not None and self.scan.duration_s[0] != self.scan.duration_s[1]:
            raise BadValueError("dataset.scan.duration_s must be one clip length on a dataset of clips, [d, d] (each "
                                "clip has the same frames, so a frame's index places it in its clip), got "
                                f"{list(self.scan.duration_s)}")
        if self.track == UNSEEN_VIEWS:
            if self.splits is not None:
                raise BadValueError("dataset.splits counts grasps per split on the unseen_grasps track; the unseen_views "
                                 "track puts every grasp in every split and holds out views (dataset.view_stride): "
                                 "set dataset.splits=null, as `hupbench generate +track=unseen_views` does")
        else:
            if self.splits is None:
                raise BadValueError(f"dataset.splits must map {SPLITS} to grasp counts on the {self.track} track, got null")
            splits = dict(self.splits)
            if set(splits) - set(SPLITS) or any(not is_whole(v) or v < 0 for v in splits.values()):
                raise BadValueError(f"splits must map {SPLITS} to grasp counts >= 0, got {splits}")
            object.__setattr__(self, "splits", {s: splits.get(s, 0) for s in SPLITS})
            if self.track == CLINIC and self.splits["train"] < 1:
                raise BadValueError(f"dataset.splits must give train at least 1 grasp on the clinic track (its floor and "
                                    f"its models are made from the training grasps' frames), got {splits}")
        object.__setattr__(self, "modalities", check_modalities(self.modalities))
        if sensor_preset(self.depth_sensor) is not None and not {"depth", "seg"} <= set(self.modalities):
            raise BadValueError(f"dataset.depth_sensor={self.depth_sensor} is made from the clean depth and the seg "
                                f"labels: dataset.modalities must hold depth and seg, got {list(self.modalities)}")
        if self.rgb_format not in ("jpg", "png"):
            raise BadValueError(f"rgb_format must be 'jpg' or 'png', got {self.rgb_format!r}")
        if self.look_at != BOX_CENTRE and self.look_at not in kp.KEYPOINT_NAMES:
            raise BadValueError(f"look_at must be {BOX_CENTRE!r} or a keypoint name (e.g. {PAPER_LOOK_AT!r}), "
                             f"got {self.look_at!r}")
        self._set_camera()

    def _set_camera(self) -> None:
        """Build :attr:`intrinsics` from width, height, fx, fy, cx, cy (checked integers already) and check that
        it is square, aims inside the image and sees the hand whole."""
        if self.width != self.height:
            raise BadValueError(f"dataset.width and dataset.height must be equal (the training and evaluation readers "
                                f"take square frames), got {self.width} x {self.height}")
        intrinsics = Intrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height)
        check_principal_point(intrinsics, "dataset.")
        longest = max_focal_px(self.width, self.distances_m)
        if max(intrinsics.fx, intrinsics.fy) > longest:
            raise BadValueError(
                f"dataset.fx and dataset.fy must be at most {longest:.0f} px for {self.width} px images at "
                f"camera distances up to {max(self.distances_m):g} m, so that the image spans the hand "
                f"({HAND_LENGTH_M * 1000:.0f} mm, wrist to middle fingertip) at the farthest camera distance, "
                f"got fx={intrinsics.fx:g}, fy={intrinsics.fy:g}")
        object.__setattr__(self, "intrinsics", intrinsics)

    @property
    def sensor(self) -> SensorPreset | None:
        """The depth camera's preset, None for "none"."""
        return sensor_preset(self.depth_sensor)

    def sensor_record(self) -> dict:
        """The manifest's "depth_sensor" entry (the preset, the noise's seed and every parameter), {} without one."""
        if self.sensor is None:
            return {}
        return {"depth_sensor": {"preset": self.depth_sensor, "seed": self.seed, "parameters": self.sensor.parameters()}}

    @property
    def stored_modalities(self) -> tuple[str, ...]:
        """What each frame writes: ``modalities``, and "sensor_depth" when there is a depth sensor."""
        return self.modalities + ((SENSOR_DEPTH,) if self.sensor is not None else ())

    @property
    def distances_m(self) -> tuple[float, ...]:
        """The camera distances to the look-at point, metres: ``z_ego_m``, or the head's range on the clinic track."""
        return tuple(self.head.distance_m) if self.head is not None else self.z_ego_m

    @property
    def sequence(self) -> bool:
        """Whether the dataset is made of clips (``scan`` and ``head_motion`` set)."""
        return self.scan is not None

    @property
    def frames_per_clip(self) -> int:
        """Frames of each clip, both ends included (:func:`hupbench.datagen.dataset.scan_motion.scan_motion`)."""
        assert self.scan is not None
        return clip_frames(self.scan.duration_s[0], self.scan.fps)

    @property
    def n_views(self) -> int:
        """Cameras per (grasp, distance): the sphere's views in use, or the head's cameras per grasp (clinic)."""
        return self.head.views_per_grasp if self.head is not None else len(viewpoints(self.sphere)[0])


@dataclass(frozen=True)
class Layout:
    """The frame index <-> (grasp, z, background, glove, view) bijection."""

    n_grasps: int
    n_z: int
    n_backgrounds: int
    n_gloves: int
    n_views: int

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n_grasps, self.n_z, self.n_backgrounds, self.n_gloves, self.n_views)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def chunk_size(self) -> int:
        return self.n_gloves * self.n_views

    @property
    def n_chunks(self) -> int:
        return self.n_grasps * self.n_z * self.n_backgrounds

    def index(self, grasp: int, z: int, background: int, glove: int, view: int) -> int:
        """Frame index of a tuple (each component in range)."""
        return int(np.ravel_multi_index((grasp, z, background, glove, view), self.shape))

    def tuple(self, index: int) -> tuple[int, int, int, int, int]:
        """Inverse of :meth:`index`."""
        assert 0 <= index < self.size, (index, self.size)
        return tuple(int(v) for v in np.unravel_index(index, self.shape))

    def chunk_frames(self, chunk: int) -> range:
        return range(chunk * self.chunk_size, (chunk + 1) * self.chunk_size)


def split_of_grasps(spec: DatasetSpec, n_grasps: int) -> dict[str, list[int]]:
    """Grasp indices of each split: consecutive in the grasps file, train first (unseen_grasps), or every
    grasp in every split (unseen_views)."""
    if spec.track == UNSEEN_VIEWS:
        return {name: list(range(n_grasps)) for name in SPLITS}
    total = sum(spec.splits.values())
    if total != n_grasps:
        raise BadValueError(f"splits {spec.splits} add up to {total} grasps but the grasps file holds {n_grasps}")
    out, start = {}, 0
    for name in SPLITS:
        out[name] = list(range(start, start + spec.splits[name]))
        start += spec.splits[name]
    return out


def split_of_views(spec: DatasetSpec, n_views: int) -> dict[str, list[int]]:
    """View positions (into :func:`hupbench.datagen.dataset.sphere.viewpoints`) of each split.

    On the unseen_grasps and clinic tracks every split holds every view. On the unseen_views track the views,
    in the sphere's order (pole, then ring by ring from north to south), are dealt in runs of
    ``view_stride``: position ``stride // 2`` of each run goes to test, the last to val, the rest to
    train, so every ring of at least ``view_stride`` views has test and val views, and no test or val
    view is ever seen in training.
    """
    if spec.track != UNSEEN_VIEWS:
        return {name: list(range(n_views)) for name in SPLITS}
    stride = spec.view_stride
    held_out = {stride // 2: "test", stride - 1: "val"}
    out = {name: [] for name in SPLITS}
    for position in range(n_views):
        out[held_out.get(position % stride, "train")].append(position)
    return out


def chunk_plan(layout: Layout, grasps_of: dict[str, list[int]], views_of: dict[str, list[int]]
               ) -> list[tuple[str, tuple[int, ...]]]:
    """The chunks a dataset is rendered in: (split, frame indices) each, numbered by their place in the list.

    A chunk is the frames of one (grasp, z_ego, background) block that belong to one split (the
    split holding both the frame's grasp and its view): the whole block on the unseen_grasps track,
    one chunk per split on the unseen_views track.
    """
    out = []
    for block in range(layout.n_chunks):
        frames = layout.chunk_frames(block)
        grasp = layout.tuple(frames.start)[0]
        for name in SPLITS:
            if grasp in grasps_of[name]:
                views = set(views_of[name])
                chosen = tuple(i for i in frames if i % layout.n_views in views)
                if chosen:
                    out.append((name, chosen))
    return out


@dataclass(frozen=True)
class FramePlan:
    """How the frames of a dataset are laid out, split and grouped into chunks.

    Attributes:
        layout: the frame index <-> (grasp, z, background, glove, view) bijection.
        grasps: split -> the grasp indices (into the grasps file) it holds (:func:`split_of_grasps`).
        views: split -> the view positions (into the sphere's view list) it holds (:func:`split_of_views`);
            a frame is in the split that holds both its grasp and its view.
        chunks: (split, frame indices) of each chunk, numbered by their place (:func:`chunk_plan`).
    """

    layout: Layout
    grasps: dict[str, list[int]]
    views: dict[str, list[int]]
    chunks: list[tuple[str, tuple[int, ...]]]


def frame_plan(spec: DatasetSpec, n_grasps: int) -> FramePlan:
    """The :class:`FramePlan` of ``spec`` rendered from ``n_grasps`` grasps."""
    if spec.sequence:
        # a dataset of clips: (grasp, clip, -, -, frame), a clip per head camera; its room and glove are drawn
        # per clip (:func:`hupbench.datagen.dataset.clips.clip_scene`), so a chunk is one clip
        layout = Layout(n_grasps, spec.n_views, 1, 1, spec.frames_per_clip)
    else:
        n_z = 1 if spec.track == CLINIC else len(spec.z_ego_m)  # a clinic camera draws its own distance
        layout = Layout(n_grasps, n_z, spec.n_backgrounds, spec.n_gloves, spec.n_views)
    grasps, views = split_of_grasps(spec, n_grasps), split_of_views(spec, layout.n_views)
    return FramePlan(layout, grasps, views, chunk_plan(layout, grasps, views))


def lamp(spec: DatasetSpec, index: int) -> dict[str, np.ndarray]:
    """The frame's lamp, a pure function of (seed, frame index).

    Returns:
        "position_cam" (3,) metres in the OpenCV camera frame: HUP-3D's box in Blender's camera axes
        turned to OpenCV's (y and z negated), so the lamp is above the optical axis and 0.5 m behind
        the camera; "color" (3,) = (c, c, b); "energy_w" Blender watts.
    """
    rng = np.random.default_rng([spec.seed, index])
    x, y, z = rng.uniform(LAMP_LOW, LAMP_HIGH)
    c, b = rng.uniform(0.6, 1.0, size=2)
    return {"position_cam": np.array([x, -y, -z]), "color": np.array([c, c, b]),
            "energy_w": np.array(rng.uniform(50.0, 300.0))}


def view_directions_arm(sphere: SphereSpec, angles: np.ndarray) -> np.ndarray:
    """(V, 3) float64 unit vectors from the target to the camera in the arm frame.

    The arm frame's columns are hand -> elbow, dorsal and their cross product (the thumb side of
    a right hand), :func:`hupbench.datagen.dataset.sphere.arm_frame`; ``angles`` is (V, 2) (theta, phi) radians.
    """
    # the sphere frame of an arm frame equal to the identity gives the sphere's axes in arm coordinates
    frame = sphere_frame(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), sphere.axis)
    return unit_directions(angles) @ frame.T


def protocol(spec: DatasetSpec) -> dict:
    """The viewing protocol of a dataset, for its manifest.

    "name" is "paper" when the sphere, its exclusions and the look-at are the published
    renderer's, "forearm_box_centre" for the forearm sphere looking at the box centre, "clinic" for the clinic
    track's head cameras, else "custom".
    """
    if spec.track == CLINIC:
        return {"name": CLINIC, "track": CLINIC, "view_stride": None, "look_at": PAPER_LOOK_AT,
                "look_at_index": kp.KEYPOINT_NAMES.index(PAPER_LOOK_AT), "head": asdict(spec.head),
                "image_up": "the room's vertical projected into the image, turned by the head's roll",
                "cameras": "per grasp, a seeded draw of head.views_per_grasp cameras above the bed plane "
                           "(hupbench.datagen.dataset.head)"}
    s = spec.sphere
    geometry = (s.r_sph_m, s.r_circ_m, s.variant) == (0.8, 0.15, "ceil")
    if geometry and s.axis == "body" and s.exclude == ("elbow",) and s.elbow_cone_deg == 10.0 \
            and spec.look_at == PAPER_LOOK_AT:
        name = "paper"
    elif geometry and s.axis == "forearm" and s.exclude == ("poles",) and spec.look_at == BOX_CENTRE:
        name = "forearm_box_centre"
    else:
        name = "custom"
    polar = {"body": "dorsal (back of the hand: the body's vertical, perpendicular to the forearm)",
             "forearm": "forearm (north = hand -> elbow)"}[s.axis]
    up = {"body": "towards the north pole along the meridian (the body's vertical), defined at the poles",
          "forearm": "the fingers (-north); at the poles the dorsal direction"}[s.axis]
    return {"name": name, "track": spec.track, "view_stride": spec.view_stride if spec.track == UNSEEN_VIEWS else None,
            "sphere_axis": s.axis, "polar_axis": polar, "image_up": up,
            "exclude": list(s.exclude), "elbow_cone_deg": s.elbow_cone_deg,
            "excluded_view_ids": list(excluded_view_ids(s)), "look_at": spec.look_at,
            "look_at_index": None if spec.look_at == BOX_CENTRE else kp.KEYPOINT_NAMES.index(spec.look_at)}


def layout_record(spec: DatasetSpec, layout: Layout) -> dict:
    """The manifest's "layout": the frame index's mixed radix (a dataset of clips names its axes as it uses them)."""
    if spec.sequence:
        return {"order": ["grasp", "clip", "-", "-", "frame"], "shape": list(layout.shape),
                "index": "i = (grasp * clips_per_grasp + clip) * frames_per_clip + frame (a clip draws its room and "
                         "glove: the annotations hold them)", "chunk_size": layout.chunk_size}
    return {"order": ["grasp", "z_ego", "background", "glove", "view"], "shape": list(layout.shape),
            "index": "i = (((grasp * n_z + z) * n_bg + bg) * n_glove + glove) * n_view + view",
            "chunk_size": layout.chunk_size}


def sequence_record(spec: DatasetSpec, clips: list[dict]) -> dict:
    """The manifest's "sequence" record of a dataset of clips: the clips' rate and length, how the probe and the
    head move, and each clip's record (its split, grasp, room, glove, skill and the probe's kinematics: drawn,
    measured and their bounds, mm/s^n)."""
    return {"fps": spec.scan.fps, "frames_per_clip": spec.frames_per_clip, "clips_per_grasp": spec.n_views,
            "scan": asdict(spec.scan), "head_motion": asdict(spec.head_motion),
            "fingers": None if spec.fingers is None else asdict(spec.fingers),
            "kinematics_source": "Le Lous et al. 2024 (hupbench.datagen.dataset.scan_motion.SKILL_KINEMATICS)",
            "clips": clips}


def cameras_record(spec: DatasetSpec, views: dict[str, list[int]]) -> dict:
    """The manifest's "z_ego_m" and "viewpoints": the sphere's views, or on the clinic track the head's camera
    indices (each grasp draws its own cameras; the annotations hold every frame's); ``views`` the plan's split ->
    view positions (:func:`split_of_views`)."""
    if spec.track == CLINIC:
        ids = list(range(spec.n_views))
        return {"z_ego_m": list(spec.distances_m), "viewpoints": {
            "ids": ids, "head": asdict(spec.head), "split_view_ids": {split: ids for split in views}}}
    view_ids, angles = viewpoints(spec.sphere)
    return {"z_ego_m": list(spec.z_ego_m),
            "viewpoints": {"ids": view_ids.tolist(), "theta_rad": angles[:, 0].tolist(),
                           "phi_rad": angles[:, 1].tolist(), "sphere": asdict(spec.sphere),
                           # target -> camera per view in the arm frame (hand -> elbow, dorsal, thumb side):
                           # the same for every grasp, whichever way the sphere is attached
                           "direction_arm": view_directions_arm(spec.sphere, angles).round(12).tolist(),
                           "split_view_ids": {split: view_ids[positions].tolist()
                                              for split, positions in views.items()}}}

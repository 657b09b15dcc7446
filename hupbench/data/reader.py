"""The dataset reader: the frames of one split decoded and resized to the model's square input, with every
label moved into that input image, so that ``project(keypoints_3d, K) == keypoints_2d_px`` holds there.

Convention:
    3D keypoints: metres, OpenCV camera frame. 2D keypoints: pixels of the input image (pixel centres at
    integers) in ``keypoints_2d_px`` and normalised to [-1, 1] across it (:mod:`hupbench.input_geometry`)
    in ``keypoints_2d``. Frames: (S, S, 3) uint8 RGB, and with ``input_modalities: rgb+depth`` (S, S) uint16
    depth in the dataset's unit (a depth sensor's, ``data.reader.depth_sensor``); segmentation labels: (S, S) uint8
    ``SEGMENT_CLASSES`` indices on the depth's pixels; model images: (C, S, S) float32, RGB in [0, 1] then, for
    C = 4, the depth channel in metres (:func:`hupbench.input_geometry.depth_channel`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from hupbench.core.camera import resize_intrinsics, resize_points
from hupbench.core.contract import SENSOR_DEPTH, frame_path, read_annotations, read_manifest, segment_classes
from hupbench.core.depth_sensor import NONE, PRESETS, SensorPreset, stored_sensor_depth
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.input_checks import check_bool, check_choice, check_int, check_number
from hupbench.data.augment import model_images
from hupbench.input_geometry import (INPUT_MODALITIES, INPUT_SIZE_RANGE, depth_channel, inside_input, pad_and_resize,
                                     pixels_to_normalized)


def _decode_stored(path: str | Path, flags: int, what: str, image_size) -> np.ndarray:
    """A stored frame file decoded with OpenCV ``flags``, checked: it exists (``what`` names it otherwise),
    decodes, and has the manifest's ``image_size`` (width, height) unless that is None (a frame of another
    size would put every label in the wrong place)."""
    path = Path(path)
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except FileNotFoundError:
        raise MissingFileError(f"{path} does not exist ({what} the annotations list)") from None
    # imdecode, not imread: imread prints OpenCV's own warning for a missing or foreign file before
    # returning None, which a user cannot act on (the error below names the file)
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None:
        kind = "an image" if flags == cv2.IMREAD_COLOR else "a PNG"
        raise BadValueError(f"cannot decode {path} as {kind} ({data.size} bytes): damaged or not "
                            + ("a JPG/PNG" if flags == cv2.IMREAD_COLOR else "a PNG"))
    if image_size is not None:
        width, height = image_size
        if image.shape[:2] != (height, width):
            raise BadValueError(f"{path} is {image.shape[1]} x {image.shape[0]} px; the manifest says {width} x {height}")
    return image


def read_rgb(path: str | Path, image_size=None) -> np.ndarray:
    """A stored frame as (H, W, 3) uint8 RGB, checked by :func:`_decode_stored`."""
    return np.ascontiguousarray(_decode_stored(path, cv2.IMREAD_COLOR, "a frame", image_size)[..., ::-1])


def read_depth(path: str | Path, image_size=None) -> np.ndarray:
    """A stored depth map as (H, W) uint16 (the dataset's unit, 0 = no surface), checked by :func:`_decode_stored`
    and for its type."""
    depth = _decode_stored(path, cv2.IMREAD_UNCHANGED, "a depth map", image_size)
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise BadValueError(f"{path} is {depth.dtype} with {1 if depth.ndim == 2 else depth.shape[2]} channel(s); "
                            "a depth map is single-channel uint16")
    return depth


def read_seg(path: str | Path, image_size=None) -> np.ndarray:
    """A stored label map as (H, W) uint8, checked by :func:`_decode_stored` and for its type."""
    seg = _decode_stored(path, cv2.IMREAD_UNCHANGED, "a seg map", image_size)
    if seg.dtype != np.uint8 or seg.ndim != 2:
        raise BadValueError(f"{path} is {seg.dtype} with {1 if seg.ndim == 2 else seg.shape[2]} channel(s); "
                            "a seg map is single-channel uint8")
    return seg


#: ``data.reader.depth_sensor``: the depth the dataset gives the models ("dataset": its sensor's, else its clean
#: depth), the clean z-buffer ("none"), or a preset of hupbench.core.depth_sensor made from the clean depth
DATASET_SENSOR = "dataset"
DEPTH_SENSORS = (DATASET_SENSOR, NONE, *PRESETS)


@dataclass(frozen=True)
class ReaderConfig:
    """The ``data.reader`` config node: how frames become model inputs, checked here and nowhere else.

    Attributes:
        input_size: S, side of the square model input, pixels, within ``INPUT_SIZE_RANGE``.
        rotate_deg: in-plane rotation range (+-) of the training augmentation, degrees in [0, 180]; 0 disables it.
        photometric: colour jitter strength of the training augmentation, in [0, 1]; 0 disables it.
        seed: augmentation seed (item i of epoch e draws from (seed, e, i)), >= 0.
        input_modalities: what the model reads, a key of ``INPUT_MODALITIES``: "rgb", or "rgb+depth" (the
            dataset's metric depth as a fourth channel).
        depth_sensor: which depth a model that reads depth gets, one of ``DEPTH_SENSORS``: "dataset" (the
            dataset's depth sensor's, ``sensor_depth/``, else its clean depth), "none" (the clean z-buffer), or a
            preset name (that sensor made from the clean depth and seg maps with each frame's seeded noise: the bytes
            `hupbench generate` would have written with it).
        fresh_sensor_noise: training frames draw a new sample of the sensor's noise every epoch (epoch e reads
            draw e + 1; validation reads the dataset's own, draw 0), so that a model is not fitted to one sample.
    """

    input_size: int = 128
    rotate_deg: float = 0.0
    photometric: float = 0.0
    seed: int = 0
    input_modalities: str = "rgb"
    depth_sensor: str = DATASET_SENSOR
    fresh_sensor_noise: bool = False

    def __post_init__(self) -> None:
        check_int(self.input_size, "data.reader.input_size", *INPUT_SIZE_RANGE)
        check_number(self.rotate_deg, "data.reader.rotate_deg", 0.0, 180.0)
        check_number(self.photometric, "data.reader.photometric", 0.0, 1.0)
        check_int(self.seed, "data.reader.seed", 0)
        check_choice(self.input_modalities, "data.reader.input_modalities", tuple(INPUT_MODALITIES))
        check_choice(self.depth_sensor, "data.reader.depth_sensor", DEPTH_SENSORS)
        check_bool(self.fresh_sensor_noise, "data.reader.fresh_sensor_noise")

    @property
    def depth(self) -> bool:
        """Whether the model reads depth as well as RGB."""
        return self.input_modalities == "rgb+depth"


def input_labels(ann: dict, scale: float, size: int) -> dict[str, np.ndarray]:
    """Labels of stored frames moved into the square model input (one frame or many at once).

    Args:
        ann: "keypoints_3d_cam" (..., 29, 3) metres, OpenCV camera frame; "keypoints_2d" (..., 29, 2)
            pixels of the stored image; "K" (..., 3, 3) its intrinsics; "visible" (..., 29) bool.
        scale: input pixels per stored pixel (S / stored width). size: S, side of the input image.

    Returns:
        float32 "keypoints_3d" (..., 29, 3) metres, "keypoints_2d_px" (..., 29, 2) input pixels,
        "keypoints_2d" (..., 29, 2) normalised [-1, 1], "K" (..., 3, 3) of the input image, and
        "visible" (..., 29) bool: visible in the stored frame and inside the input image.
    """
    uv = resize_points(ann["keypoints_2d"], scale)
    return {
        "keypoints_3d": np.asarray(ann["keypoints_3d_cam"], dtype=np.float32),
        "keypoints_2d": pixels_to_normalized(uv, size).astype(np.float32),
        "keypoints_2d_px": uv.astype(np.float32),
        "visible": np.asarray(ann["visible"], dtype=bool) & inside_input(uv, size),
        "K": resize_intrinsics(ann["K"], scale).astype(np.float32),
    }


class HUPDataset(torch.utils.data.Dataset):
    """The frames of one split at the model's input size, un-augmented, with their labels.

    Args:
        root: dataset folder. split: "train", "val" or "test".
        config: the input size (the augmentation fields are :class:`hupbench.data.augment.BatchAugment`'s).

    Attributes:
        ann: the split's annotation arrays (N rows). labels: the input-image labels of every frame as
            tensors with a leading N axis ("keypoints_3d", "keypoints_2d", "keypoints_2d_px", "visible",
            "K" as :func:`input_labels`, and "frame_id" int64).

    Items are dicts: "image" (C, S, S) float32, the model's input (C = 3, or 4 with depth), and one row of
    every label.
    """

    def __init__(self, root, split: str, config: ReaderConfig = ReaderConfig()) -> None:
        self.root = Path(root)
        self.manifest = read_manifest(self.root, split)
        needed = {"rgb": "rgb images", **({"depth": "depth maps"} if config.depth else {})}
        lacking = [words for modality, words in needed.items() if modality not in self.manifest["modalities"]]
        if lacking:
            raise BadValueError(f"{self.root} has no {' and no '.join(lacking)} (modalities "
                                f"{self.manifest['modalities']}); input_modalities={config.input_modalities} needs them")
        self.split, self.config = split, config
        self.ann = read_annotations(self.root, split, ("keypoints_3d_cam", "keypoints_2d", "visible", "K"),
                                    self.manifest)
        width, height = self.manifest["image_size"]
        if width != height:  # the labels follow a resize, not a pad (pad_and_resize would need their offset)
            raise BadValueError(f"{self.path(0)}: the reader expects square images, got {width} x {height}")
        size = config.input_size
        labels = input_labels(self.ann, size / width, size)
        self.labels = {name: torch.from_numpy(np.ascontiguousarray(array)) for name, array in labels.items()}
        self.labels["frame_id"] = torch.from_numpy(self.ann["frame_id"].astype(np.int64))
        self.sensor, self.depth_files = self._depth_source()

    def _depth_source(self) -> tuple[SensorPreset | None, tuple[str, ...]]:
        """(the sensor whose depth :meth:`depth_frame` gives, None for the clean depth; the modalities it reads:
        ("sensor_depth",) stored, ("depth",) clean, ("depth", "seg") a sensor made here), checked against the
        dataset's files."""
        config, manifest = self.config, self.manifest
        stored = manifest.get("depth_sensor") or {}
        name = stored.get("preset", NONE) if config.depth_sensor == DATASET_SENSOR else config.depth_sensor
        sensor = None if name == NONE else PRESETS[name]
        files = ("depth",) if sensor is None else (SENSOR_DEPTH,) if name == stored.get("preset") else ("depth", "seg")
        if config.fresh_sensor_noise and sensor is None:
            raise BadValueError(f"data.reader.fresh_sensor_noise draws a depth sensor's noise, but {self.root} has no "
                                "depth sensor: set data.reader.depth_sensor to one of " + ", ".join(PRESETS))
        if config.fresh_sensor_noise:
            files = ("depth", "seg")
        lacking = [m for m in files if m not in manifest["modalities"]] if config.depth else []
        if lacking:
            raise BadValueError(f"data.reader.depth_sensor={config.depth_sensor} reads the {' and '.join(lacking)} "
                                f"maps, which {self.root} lacks (modalities {manifest['modalities']})")
        return sensor, files

    @property
    def depth_source(self) -> dict:
        """What the depth channel is, as JSON (the frame cache's key and the results record it)."""
        return {"sensor": None if self.sensor is None else self.sensor.name, "files": list(self.depth_files),
                "fresh_noise": self.config.fresh_sensor_noise}

    def __len__(self) -> int:
        return len(self.ann["frame_id"])

    def path(self, index: int, modality: str = "rgb") -> Path:
        """The file of row ``index``: its RGB image, or its ``modality`` ("depth", "seg", "sensor_depth") map."""
        return frame_path(self.root, self.split, modality, int(self.ann["frame_id"][index]), self.manifest["rgb_format"])

    def frame(self, index: int) -> np.ndarray:
        """(S, S, 3) uint8 RGB: row ``index``'s file decoded (checked by :func:`read_rgb`) and resized."""
        image, _ = pad_and_resize(read_rgb(self.path(index), self.manifest["image_size"]), self.config.input_size)
        return image

    def depth_frame(self, index: int, draw: int = 0) -> np.ndarray:
        """(S, S) uint16 depth in the dataset's unit: row ``index``'s map as ``data.reader.depth_sensor`` says
        (checked by :func:`read_depth`; ``draw`` > 0: a fresh sample of the sensor's noise), resized to the nearest
        pixel (every value one the sensor gave)."""
        size = self.manifest["image_size"]
        if self.depth_files[0] == "depth" and self.sensor is not None:
            seed = (self.manifest.get("depth_sensor") or {}).get("seed", 0)
            depth = stored_sensor_depth(read_depth(self.path(index, "depth"), size),
                                        read_seg(self.path(index, "seg"), size), np.asarray(self.manifest["K"]), self.sensor,
                                        self.manifest["seg_labels"], self.manifest["depth_scale_m"], seed,
                                        int(self.ann["frame_id"][index]), draw)
        else:
            depth = read_depth(self.path(index, self.depth_files[0]), size)
        return pad_and_resize(depth, self.config.input_size, interpolation=cv2.INTER_NEAREST)[0]

    def seg_frame(self, index: int) -> np.ndarray:
        """(S, S) uint8 ``SEGMENT_CLASSES`` indices (:func:`hupbench.core.contract.segment_classes`): row ``index``'s
        seg map (checked by :func:`read_seg`) resized to the nearest pixel as :meth:`depth_frame`, so that a label
        pixel lies on its depth pixel."""
        seg = read_seg(self.path(index, "seg"), self.manifest["image_size"])
        classes = segment_classes(seg, self.manifest["seg_labels"])
        return pad_and_resize(classes, self.config.input_size, interpolation=cv2.INTER_NEAREST)[0]

    def depth_metres(self, depth: np.ndarray) -> torch.Tensor:
        """Stored depth (uint16, any shape) as the model's depth channel (float32 metres, clipped)."""
        return torch.from_numpy(depth_channel(depth, self.manifest["depth_scale_m"]))

    def __getitem__(self, index: int) -> dict:
        depth = self.depth_metres(self.depth_frame(index))[None] if self.config.depth else None
        image = model_images(torch.from_numpy(self.frame(index))[None], torch.device("cpu"), depth=depth)[0]
        return {"image": image, **{name: value[index] for name, value in self.labels.items()}}

"""The dataset reader: a torch Dataset over the dataset contract of DESIGN.md.

Each item is one frame resized to the model's square input, with every label
moved into that input image: 2D keypoints and the intrinsics follow the
resize (and the optional in-plane rotation), 3D keypoints follow the rotation
about the optical axis, so that ``project(keypoints_3d, K) == keypoints_2d``
holds exactly in the input image.

Convention:
    3D keypoints: metres, OpenCV camera frame. 2D keypoints: pixels of the
    input image (pixel centres at integers) in ``keypoints_2d_px`` and
    normalised to [-1, 1] across the input (``u_norm = (u + 0.5) / S * 2 - 1``)
    in ``keypoints_2d``. Images: float32 RGB in [0, 1], (3, S, S).
    In-plane rotation: by ``angle`` radians about the principal point, image
    content turning counter-clockwise on screen for positive angles; the
    camera-frame points turn by the matching rotation about +z.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from datagen.camera import resize_intrinsics, resize_points  # noqa: F401  (part of the reader's API)
from datagen.dataset.contract import frame_path, read_annotations, read_manifest  # noqa: F401  (read_manifest: reader API)
from datagen.input_checks import check_int
from hupbench.inference.model_file import INPUT_SIZE_RANGE
from datagen.errors import BadValueError, MissingFileError


#: the model input side, pixels: below 16 the backbones' five stride-2 stages leave nothing; above 2048 a
#: split's frame cache (N x S x S x 3 bytes) outgrows any disk long before a model could use the detail
MIN_INPUT_SIZE, MAX_INPUT_SIZE = INPUT_SIZE_RANGE


def read_rgb(path: str | Path, image_size=None) -> np.ndarray:
    """A stored frame as (H, W, 3) uint8 RGB, checked: it exists, decodes, and has the manifest's size.

    Args:
        path: the image file.
        image_size: (width, height) the manifest gives for every frame, or None to skip that check.

    Raises:
        FileNotFoundError: no such file. ValueError: not a decodable image, or another size (the message
        names the file; a frame of another size would put every label in the wrong place).
    """
    path = Path(path)
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except FileNotFoundError:
        raise MissingFileError(f"{path} does not exist (a frame the annotations list)") from None
    # imdecode, not imread: imread prints OpenCV's own warning for a missing or foreign file before
    # returning None, which a user cannot act on (the error below names the file)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None:
        raise BadValueError(f"cannot decode {path} as an image ({data.size} bytes): damaged or not a JPG/PNG")
    if image_size is not None:
        width, height = (int(v) for v in image_size)
        if image.shape[:2] != (height, width):
            raise BadValueError(f"{path} is {image.shape[1]} x {image.shape[0]} px; the manifest says {width} x {height}")
    return np.ascontiguousarray(image[..., ::-1])


def rotation_about_optical_axis(angle: float) -> np.ndarray:
    """(3, 3) camera-frame rotation that turns the image content by ``angle`` about the principal point.

    With y pointing down in the image, a counter-clockwise turn on screen is a rotation of
    the camera-frame points by -angle about +z.
    """
    c, s = np.cos(-angle), np.sin(-angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ReaderConfig:
    """How frames become model inputs.

    Attributes:
        input_size: side of the square input, pixels.
        rotate_deg: in-plane rotation augmentation range (+-), degrees; 0 disables it.
        photometric: kornia colour jitter strength (0 disables it).
        seed: augmentation seed (item i of epoch e draws from (seed, e, i)).
    """

    input_size: int = 128
    rotate_deg: float = 0.0
    photometric: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_int(self.input_size, "input_size", MIN_INPUT_SIZE, MAX_INPUT_SIZE)
        for name, high in (("rotate_deg", 180.0), ("photometric", 1.0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= high:
                raise BadValueError(f"{name} must be a number in [0, {high:g}], got {value!r}")


class HUPDataset(torch.utils.data.Dataset):
    """Frames of one split, resized (and optionally augmented) for a model.

    Args:
        root: dataset folder (with ``manifest.json``).
        split: "train", "val" or "test".
        config: input size and augmentation.

    Items are dicts: "image" (3, S, S) float32; "keypoints_3d" (29, 3) float32 metres;
    "keypoints_2d" (29, 2) float32 in [-1, 1]; "keypoints_2d_px" (29, 2) float32 input pixels;
    "visible" (29,) bool; "K" (3, 3) float32 of the input image; "frame_id" int64.
    Only RGB is read: the models use nothing else.
    """

    def __init__(self, root, split: str, config: ReaderConfig = ReaderConfig()) -> None:
        self.root = Path(root)
        self.manifest = read_manifest(self.root, split)
        if "rgb" not in self.manifest["modalities"]:
            raise BadValueError(f"{self.root} has no rgb images (modalities {self.manifest['modalities']})")
        self.split, self.config = split, config
        self.ann = read_annotations(self.root, split, ("keypoints_3d_cam", "keypoints_2d", "visible", "K"),
                                    self.manifest)
        self.epoch = 0
        self._jitter = None
        if config.photometric > 0:
            import kornia.augmentation as KA

            p = config.photometric
            self._jitter = KA.ColorJiggle(brightness=0.4 * p, contrast=0.4 * p, saturation=0.4 * p, hue=0.05 * p, p=1.0)

    def __len__(self) -> int:
        return len(self.ann["frame_id"])

    def set_epoch(self, epoch: int) -> None:
        """Change the augmentation draws (call once per epoch)."""
        self.epoch = int(epoch)

    def __getitem__(self, index: int) -> dict:
        frame_id = int(self.ann["frame_id"][index])
        path = frame_path(self.root, self.split, "rgb", frame_id, self.manifest["rgb_format"])
        image = read_rgb(path, self.manifest["image_size"])
        size = self.config.input_size
        scale = size / image.shape[1]
        if image.shape[0] != image.shape[1]:
            raise BadValueError(f"{path}: the reader expects square images, got {image.shape[1]} x {image.shape[0]}")
        image = cv2.resize(np.ascontiguousarray(image), (size, size), interpolation=cv2.INTER_AREA)
        K = resize_intrinsics(self.ann["K"][index], scale)
        points_3d = self.ann["keypoints_3d_cam"][index].astype(np.float64)
        uv = resize_points(self.ann["keypoints_2d"][index], scale)
        rng = np.random.default_rng([self.config.seed, self.epoch, index])
        if self.config.rotate_deg > 0:
            angle = np.deg2rad(rng.uniform(-self.config.rotate_deg, self.config.rotate_deg))
            image, points_3d, uv = rotate_in_plane(image, points_3d, uv, K, angle)
        tensor = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float() / 255.0
        if self._jitter is not None:
            torch_rng = torch.Generator().manual_seed(int(rng.integers(2**62)))
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(int(torch.randint(0, 2**62, (1,), generator=torch_rng)))
                tensor = self._jitter(tensor[None])[0].clamp(0.0, 1.0)
        labels = input_labels({"keypoints_3d_cam": points_3d, "keypoints_2d": uv, "K": K,
                               "visible": self.ann["visible"][index]}, 1.0, size)
        return {"image": tensor, **{name: torch.from_numpy(value) for name, value in labels.items()},
                "frame_id": torch.tensor(frame_id, dtype=torch.int64)}


def input_labels(ann: dict, scale: float, size: int) -> dict[str, np.ndarray]:
    """Labels of stored frames moved into the square model input (one frame or many at once).

    Args:
        ann: "keypoints_3d_cam" (..., 29, 3) metres, OpenCV camera frame; "keypoints_2d" (..., 29, 2)
            pixels of the stored image; "K" (..., 3, 3) its intrinsics; "visible" (..., 29) bool.
        scale: input pixels per stored pixel (S / stored width).
        size: S, side of the input image.

    Returns:
        float32 "keypoints_3d" (..., 29, 3) metres, "keypoints_2d_px" (..., 29, 2) input pixels,
        "keypoints_2d" (..., 29, 2) normalised [-1, 1], "K" (..., 3, 3) of the input image, and
        "visible" (..., 29) bool: visible in the stored frame and inside the input image.
    """
    uv = resize_points(ann["keypoints_2d"], scale)
    inside = ((uv >= -0.5) & (uv < size - 0.5)).all(axis=-1)
    return {
        "keypoints_3d": np.asarray(ann["keypoints_3d_cam"], dtype=np.float32),
        "keypoints_2d": ((2.0 * uv + 1.0) / size - 1.0).astype(np.float32),
        "keypoints_2d_px": uv.astype(np.float32),
        "visible": np.asarray(ann["visible"], dtype=bool) & inside,
        "K": resize_intrinsics(ann["K"], scale).astype(np.float32),
    }


def rotate_in_plane(image: np.ndarray, points_3d: np.ndarray, uv: np.ndarray, K: np.ndarray, angle: float):
    """Turn the image about the principal point and the 3D points about the optical axis to match.

    Exact for a pinhole camera with fx == fy (square pixels), which the datasets have.

    Args:
        image: (S, S, 3) uint8. points_3d: (N, 3) metres, camera frame. uv: (N, 2) pixels.
        K: (3, 3) intrinsics of ``image``. angle: radians, counter-clockwise on screen.

    Returns:
        (image, points_3d, uv) rotated.
    """
    if not np.isclose(K[0, 0], K[1, 1]):
        raise BadValueError(f"in-plane rotation needs square pixels (fx == fy), got fx={K[0, 0]}, fy={K[1, 1]}")
    centre = (float(K[0, 2]), float(K[1, 2]))
    # cv2's positive angle is counter-clockwise on screen (y down)
    M = cv2.getRotationMatrix2D(centre, float(np.rad2deg(angle)), 1.0)
    rotated = cv2.warpAffine(image, M, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REFLECT_101)
    R = rotation_about_optical_axis(angle)
    uv_rot = np.asarray(uv) @ M[:, :2].T + M[:, 2]
    return rotated, points_3d @ R.T, uv_rot

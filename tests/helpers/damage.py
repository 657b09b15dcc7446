"""Damaged inputs for the matrix: a dataset or a checkpoint broken one named way, and what the error must name."""

from __future__ import annotations

import json
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np
import torch


def copy_dataset(src: Path, dst: Path) -> Path:
    """A writable copy of a dataset (without its frame cache)."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("cache"))
    return dst


def rewrite_annotations(root: Path, split: str, edit) -> Path:
    """Replace ``split``'s annotations.npz by ``edit(arrays)`` (a dict of arrays)."""
    path = root / split / "annotations.npz"
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(path, **edit(arrays))
    return path


def flip_member_byte(path: Path, member: str = "keypoints_3d_cam.npy") -> None:
    """Invert one byte inside the data of one array of an .npz (a bit rot that only the zip CRC sees)."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    data = bytearray(path.read_bytes())
    name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26: info.header_offset + 30])
    start = info.header_offset + 30 + name_len + extra_len
    data[start + info.compress_size - 16] ^= 0xFF  # in the last values, past the .npy header
    path.write_bytes(bytes(data))


def first_frame(root: Path, split: str) -> Path:
    return sorted((root / split / "rgb").iterdir())[0]


def write_image(path: Path, width: int, height: int) -> None:
    import cv2

    assert cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 255, (height, width, 3), dtype=np.uint8))


def damage_dataset(case: str, src: Path, tmp_path: Path, split: str) -> tuple[Path, tuple[str, ...]]:
    """(dataset folder, what the error must name) for a dataset case id; ``split`` is the one damaged."""
    if case == "dataset-missing":
        return tmp_path / "no_such_dataset", ("no_such_dataset", "does not exist")
    if case == "dataset-empty-folder":
        (tmp_path / "empty").mkdir()
        return tmp_path / "empty", ("manifest.json", "not a finished hupbench dataset")
    if case == "dataset-is-a-file":
        (tmp_path / "file.txt").write_text("not a dataset")
        return tmp_path / "file.txt", ("file.txt", "is a file")
    root = copy_dataset(src, tmp_path / "dataset")
    ann = root / split / "annotations.npz"
    rng = np.random.default_rng(1)
    if case == "manifest-bad-json":
        text = (root / "manifest.json").read_text()
        (root / "manifest.json").write_text(text[: len(text) // 2])
        return root, ("manifest.json", "not valid JSON")
    if case == "manifest-21-keypoints":
        manifest = json.loads((root / "manifest.json").read_text())
        manifest["keypoint_names"] = manifest["keypoint_names"][:21]
        (root / "manifest.json").write_text(json.dumps(manifest))
        return root, ("manifest.json", "21 keypoints", "29")
    if case == "annotations-missing":
        ann.unlink()
        return root, ("annotations.npz", "missing")
    if case == "annotations-empty":
        ann.write_bytes(b"")
        return root, ("annotations.npz", "damaged")
    if case == "annotations-truncated":
        data = ann.read_bytes()
        ann.write_bytes(data[: len(data) // 2])
        return root, ("annotations.npz", "damaged")
    if case == "annotations-random-bytes":
        ann.write_bytes(rng.integers(0, 256, ann.stat().st_size, dtype=np.uint8).tobytes())
        return root, ("annotations.npz", "damaged")
    if case == "annotations-flipped-byte":
        flip_member_byte(ann)
        return root, ("annotations.npz", "crc")
    if case == "annotations-row-short":
        rewrite_annotations(root, split, lambda a: {k: v[:-1] for k, v in a.items()})
        return root, ("annotations.npz", "rows as the manifest counts")
    if case == "annotations-21-keypoints":
        rewrite_annotations(root, split, lambda a: a | {"keypoints_3d_cam": a["keypoints_3d_cam"][:, :21],
                                                        "keypoints_2d": a["keypoints_2d"][:, :21],
                                                        "visible": a["visible"][:, :21]})
        return root, ("annotations.npz", "keypoints_3d_cam", "29, 3")
    if case == "annotations-nan":
        rewrite_annotations(root, split, lambda a: a | {"keypoints_3d_cam": np.where(
            np.arange(len(a["frame_id"]))[:, None, None] == 3, np.nan, a["keypoints_3d_cam"]).astype(np.float32)})
        return root, ("annotations.npz", "nan")
    if case == "annotations-K-zero":  # training ended in a traceback, eval warned and went on
        rewrite_annotations(root, split, lambda a: a | {"K": np.zeros_like(a["K"])})
        return root, ("annotations.npz", "K has fx or fy <= 0", "row 0")
    frame = first_frame(root, split)
    if case == "rgb-missing":
        frame.unlink()
        return root, (frame.name, "does not exist")
    if case == "rgb-undecodable":
        frame.write_bytes(rng.integers(0, 256, 2000, dtype=np.uint8).tobytes())
        return root, (frame.name, "cannot decode")
    if case == "rgb-tiny":
        write_image(frame, 8, 8)
        return root, (frame.name, "8 x 8", "64 x 64")
    if case == "rgb-huge":
        write_image(frame, 1024, 1024)
        return root, (frame.name, "1024 x 1024", "64 x 64")
    if case == "rgb-not-square":
        write_image(frame, 64, 48)
        return root, (frame.name, "64 x 48", "64 x 64")
    raise KeyError(case)


DATASET_CASES = ["dataset-missing", "dataset-empty-folder", "dataset-is-a-file", "manifest-bad-json",
                 "manifest-21-keypoints", "annotations-missing", "annotations-empty", "annotations-truncated",
                 "annotations-random-bytes", "annotations-flipped-byte", "annotations-row-short",
                 "annotations-21-keypoints", "annotations-nan", "annotations-K-zero", "rgb-missing", "rgb-undecodable",
                 "rgb-tiny", "rgb-huge", "rgb-not-square"]


def damage_checkpoint(case: str, src: Path, tmp_path: Path) -> tuple[Path, tuple[str, ...]]:
    """(checkpoint path, what the error must name) for a checkpoint case id, from a good checkpoint ``src``."""
    path = tmp_path / f"{case}.pt"
    if case == "ckpt-missing":
        return path, (path.name, "does not exist")
    if case == "ckpt-empty":
        path.write_bytes(b"")
        return path, (path.name, "not a readable torch checkpoint")
    if case == "ckpt-truncated":
        data = src.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        return path, (path.name, "not a readable torch checkpoint")
    if case == "ckpt-random-bytes":
        path.write_bytes(np.random.default_rng(2).integers(0, 256, 100_000, dtype=np.uint8).tobytes())
        return path, (path.name, "not a readable torch checkpoint")
    if case == "ckpt-not-hupbench":
        torch.save({"state_dict": {"w": torch.zeros(3)}}, path)
        return path, (path.name, "not a hupbench checkpoint")
    payload = torch.load(src, map_location="cpu", weights_only=True)
    if case == "ckpt-wrong-shapes":
        key = next(k for k, v in payload["model"].items() if v.ndim == 4)
        payload["model"][key] = torch.zeros(3, 3, 3, 3)
        torch.save(payload, path)
        return path, (path.name, key, "shape")
    if case == "ckpt-other-model-weights":
        # the weights of one model under the config of another (a hand-edited or mixed-up file)
        payload["model_config"] = {"name": "resnet_regressor", "backbone": "resnet10", "n_keypoints": 29}
        torch.save(payload, path)
        return path, (path.name, "resnet_regressor")
    if case == "ckpt-unknown-model":
        payload["model_config"] = payload["model_config"] | {"name": "hopenet9"}
        torch.save(payload, path)
        return path, (path.name, "'hopenet9'")
    if case == "ckpt-lacks-fields":
        del payload["K_input"]
        torch.save(payload, path)
        return path, (path.name, "lacks K_input")
    raise KeyError(case)


CHECKPOINT_CASES = ["ckpt-missing", "ckpt-empty", "ckpt-truncated", "ckpt-random-bytes", "ckpt-not-hupbench",
                    "ckpt-wrong-shapes", "ckpt-other-model-weights", "ckpt-unknown-model", "ckpt-lacks-fields"]

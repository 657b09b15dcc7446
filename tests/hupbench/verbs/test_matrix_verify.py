"""The bad-input matrix of ``hupbench verify DATASET`` (docs/robustness.md, section verify).

Two kinds of answer:
- a fatal error (nothing to verify against: no dataset, no readable manifest, a manifest field
  missing or malformed, a bad option): one ``hupbench verify: error: ...`` line naming the file or
  field, exit 1 (argparse's usage errors exit 2);
- a reported problem (a split's files damaged or disagreeing with the manifest): a problem line
  naming its kind and the file, ``hupbench verify: FAILED ...`` naming the kind, exit 1, nothing
  on stderr (no traceback, no decoder warning), and the other splits still checked.

Every case damages a copy of the ``tiny_dataset`` fixture (64 px, 1 glove, 2 backgrounds, 10 views,
20 frames in each of train, val and test).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest

from helpers.cli import assert_clean_error, run_cli
from hupbench.core.io import save_npz

FIRST_TRAIN = 0  # frame ids of the tiny dataset: train 0-19 (2 backgrounds x 10 views), val 20-39, test 40-59


@dataclass(frozen=True)
class Error:
    """A fatal answer: one error line naming all of ``needles`` ("{root}" stands for the dataset path)."""

    needles: tuple[str, ...]


@dataclass(frozen=True)
class Problem:
    """A reported problem of ``kind`` whose line names all of ``needles``; ``splits_checked``: the
    splits whose frames must still have been checked (their count is in the FAILED line)."""

    kind: str
    needles: tuple[str, ...]
    frames_checked: int | None = None


def error(*needles: str) -> Error:
    return Error(needles)


def problem(kind: str, *needles: str, frames_checked: int | None = None) -> Problem:
    return Problem(kind, needles, frames_checked)


# --- damage helpers: each takes the dataset copy and returns the argv after "verify" -------------


def _path(root: Path, split: str, modality: str, fid: int) -> Path:
    ext = "jpg" if modality == "rgb" else "png"
    return root / split / modality / f"{fid:06d}.{ext}"


def _manifest(root: Path) -> dict:
    return json.loads((root / "manifest.json").read_text())


def _edit_manifest(edit: Callable[[dict], None]):
    def damage(root: Path) -> list[str]:
        manifest = _manifest(root)
        edit(manifest)
        (root / "manifest.json").write_text(json.dumps(manifest))
        return [str(root)]
    return damage


def _write_manifest_bytes(data: bytes):
    def damage(root: Path) -> list[str]:
        (root / "manifest.json").write_bytes(data)
        return [str(root)]
    return damage


def _edit_annotations(split: str, edit: Callable[[dict], None]):
    def damage(root: Path) -> list[str]:
        path = root / split / "annotations.npz"
        with np.load(path) as data:
            ann = {k: data[k].copy() for k in data.files}
        edit(ann)
        save_npz(path, ann)
        return [str(root)]
    return damage


def _file_bytes(relative: str, change: Callable[[bytes], bytes]):
    def damage(root: Path) -> list[str]:
        path = root / relative
        path.write_bytes(change(path.read_bytes()))
        return [str(root)]
    return damage


def _remove(relative: str):
    def damage(root: Path) -> list[str]:
        (root / relative).unlink()
        return [str(root)]
    return damage


def _flip_middle_bytes(data: bytes) -> bytes:
    """Flip 16 bytes in the middle of a stored (uncompressed) zip member: the zip stays a zip, its CRC fails."""
    out = bytearray(data)
    middle = len(out) // 2
    for i in range(middle, middle + 16):
        out[i] ^= 0xFF
    return bytes(out)


def _random_bytes(data: bytes) -> bytes:
    return np.random.default_rng(0).integers(0, 256, max(len(data), 64), dtype=np.uint8).tobytes()


def _image(relative: str, make: Callable[[np.ndarray], np.ndarray]):
    def damage(root: Path) -> list[str]:
        path = root / relative
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert cv2.imwrite(str(path), make(image))
        return [str(root)]
    return damage


def _swap(split: str, modality: str, a: int, b: int):
    def damage(root: Path) -> list[str]:
        pa, pb = _path(root, split, modality, a), _path(root, split, modality, b)
        tmp = pa.with_suffix(".swap")
        pa.rename(tmp)
        pb.rename(pa)
        tmp.rename(pb)
        return [str(root)]
    return damage


def _cycle(split: str, modality: str, ids: tuple[int, ...]):
    """Each frame gets the next one's file (a shuffle)."""
    def damage(root: Path) -> list[str]:
        data = [_path(root, split, modality, f).read_bytes() for f in ids]
        for k, fid in enumerate(ids):
            _path(root, split, modality, fid).write_bytes(data[(k + 1) % len(ids)])
        return [str(root)]
    return damage


def _argv(*extra: str):
    def damage(root: Path) -> list[str]:
        return [str(root), *extra]
    return damage


def _missing_dataset(root: Path) -> list[str]:
    return [str(root.parent / "no_such_dataset")]


def _file_as_dataset(root: Path) -> list[str]:
    path = root.parent / "dataset.txt"
    path.write_text("not a dataset")
    return [str(path)]


def _empty_folder(root: Path) -> list[str]:
    path = root.parent / "empty"
    path.mkdir()
    return [str(path)]


def _set(key, value):
    return lambda m: m.__setitem__(key, value)


def _del(*keys):
    def edit(m):
        for k in keys:
            del m[k]
    return edit


def _names_21(m):
    m["keypoint_names"] = m["keypoint_names"][:21]


def _names_reordered(m):
    names = m["keypoint_names"]
    names[1], names[2] = names[2], names[1]


def _K_disagrees(m):
    m["K"][0][0] = m["K"][0][0] * 1.1


def _counts_over(m):
    m["counts"]["train"] += 1


def _counts_moved(m):
    m["counts"]["train"] -= 1
    m["counts"]["test"] += 1


def _row_short(a):
    for k in a:
        a[k] = a[k][:-1]


def _keypoints_21(a):
    a["keypoints_3d_cam"] = a["keypoints_3d_cam"][:, :21]


def _nan_keypoints(a):
    a["keypoints_3d_cam"][3, 5] = np.nan


def _nan_hand_pose(a):
    a["hand_pose"][2, 7] = np.nan


def _duplicate_id(a):
    a["frame_id"][1] = a["frame_id"][0]


def _glove_out_of_range(a):
    a["glove_id"][4] = 7


def _view_out_of_range(a):
    a["view_id"][4] = 999


def _all_invisible(a):
    a["visible"][:] = False


def _K_zero(rows):
    def edit(a):
        a["K"][rows] = 0.0
    return edit


def _negative_lamp_power(a):
    a["light_energy_w"][4] = -120.0


def _lamp_colour_above_one(a):
    a["light_color"][4] = [1.0, 2.5, 1.0]


def _sheet_folder(root: Path) -> list[str]:
    folder = root.parent / "sheet.png"
    folder.mkdir()
    return [str(root), "--sample-sheet", str(folder)]


def _labels_swapped(m):
    m["seg_labels"].update(hand=3, probe=1)


def _red_blue_swapped(image):
    return np.ascontiguousarray(image[..., ::-1])


def _nothing_in_view(image):
    return np.zeros_like(image)


def _other_grasps(root: Path) -> list[str]:
    path = root / "grasps.npz"
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    save_npz(path, {**arrays, "hand_pose": arrays["hand_pose"][::-1].copy()})
    return [str(root)]


# train frame ids: fid = background * 10 + view (one grasp, one z, one glove)
SAME_VIEW_OTHER_BG = (3, 13)
OTHER_VIEW_SAME_BG = (2, 7)

ANN = "train/annotations.npz"
RGB3 = "train/rgb/000003.jpg"
DEPTH3 = "train/depth/000003.png"
SEG3 = "train/seg/000003.png"

CASES: dict[str, tuple[Callable[[Path], list[str]], Error | Problem]] = {
    # the dataset argument
    "dataset-missing": (_missing_dataset, error("no_such_dataset", "does not exist")),
    "dataset-is-a-file": (_file_as_dataset, error("dataset.txt", "is a file")),
    "dataset-empty-folder": (_empty_folder, error("empty", "no manifest.json")),
    # manifest.json: fatal, verify has nothing to check against
    "manifest-missing": (_remove("manifest.json"), error("dataset", "no manifest.json")),
    "manifest-empty": (_write_manifest_bytes(b""), error("manifest.json", "not valid JSON")),
    "manifest-bad-json": (_write_manifest_bytes(b'{"counts": {"train": 20,'), error("manifest.json", "not valid JSON")),
    "manifest-random-bytes": (_file_bytes("manifest.json", _random_bytes), error("manifest.json", "not")),
    "manifest-not-an-object": (_write_manifest_bytes(b"[1, 2, 3]"), error("manifest.json", "JSON object", "list")),
    "manifest-missing-fields": (_edit_manifest(_del("K", "counts")), error("manifest.json", "lacks", "counts", "K")),
    "manifest-21-keypoint-names": (_edit_manifest(_names_21), error("manifest.json", "keypoint_names", "21", "29")),
    "manifest-reordered-keypoint-names": (_edit_manifest(_names_reordered),
                                          error("manifest.json", "keypoint_names[1]", "thumb_cmc")),
    "manifest-K-wrong-shape": (_edit_manifest(_set("K", [[120.0, 0.0], [0.0, 120.0]])), error("manifest.json", "K")),
    "manifest-image-size-malformed": (_edit_manifest(_set("image_size", [64])), error("manifest.json", "image_size")),
    "manifest-protocol-look-at-unknown": (_edit_manifest(lambda m: m["protocol"].__setitem__("look_at", "elbow")),
                                          error("manifest.json", "protocol", "look_at", "elbow")),
    # manifest.json readable but disagreeing with the files: reported
    "manifest-K-disagrees-with-annotations": (_edit_manifest(_K_disagrees),
                                              problem("manifest_mismatch", "annotations.npz", "K", frames_checked=60)),
    "manifest-counts-over-layout": (_edit_manifest(_counts_over), problem("count_mismatch", "train", "21")),
    "manifest-counts-moved-between-splits": (_edit_manifest(_counts_moved), problem("count_mismatch", "test", "21")),
    "manifest-image-size-disagrees": (_edit_manifest(_set("image_size", [128, 128])),
                                      problem("manifest_mismatch", "image_size", "64 x 64")),
    # <split>/annotations.npz: reported, the other splits still checked (40 frames)
    "annotations-missing": (_remove(ANN), problem("missing_file", ANN, frames_checked=40)),
    "annotations-empty": (_file_bytes(ANN, lambda b: b""), problem("damaged_file", ANN, frames_checked=40)),
    "annotations-truncated": (_file_bytes(ANN, lambda b: b[: len(b) // 2]), problem("damaged_file", ANN, frames_checked=40)),
    "annotations-random-bytes": (_file_bytes(ANN, _random_bytes), problem("damaged_file", ANN, frames_checked=40)),
    "annotations-flipped-bytes": (_file_bytes(ANN, _flip_middle_bytes), problem("damaged_file", ANN, frames_checked=40)),
    "annotations-one-row-short": (_edit_annotations("train", _row_short), problem("count_mismatch", ANN, "19", "20")),
    "annotations-21-keypoints": (_edit_annotations("train", _keypoints_21),
                                 problem("bad_annotations", ANN, "keypoints_3d_cam", "(20, 29, 3)", frames_checked=40)),
    "annotations-wrong-dtype": (_edit_annotations("train", lambda a: a.__setitem__("keypoints_2d", a["keypoints_2d"].astype(np.float64))),
                                problem("bad_annotations", ANN, "keypoints_2d", "float32", frames_checked=40)),
    "annotations-missing-array": (_edit_annotations("train", lambda a: a.pop("T_cam_world")),
                                  problem("bad_annotations", ANN, "T_cam_world", frames_checked=40)),
    "annotations-nan-keypoints": (_edit_annotations("train", _nan_keypoints),
                                  problem("bad_annotations", ANN, "keypoints_3d_cam", "NaN", frames_checked=40)),
    "annotations-nan-hand-pose": (_edit_annotations("train", _nan_hand_pose), problem("bad_annotations", ANN, "hand_pose", "000002")),
    "annotations-duplicate-frame-id": (_edit_annotations("train", _duplicate_id), problem("frame_ids", ANN, frames_checked=40)),
    "annotations-glove-id-out-of-range": (_edit_annotations("train", _glove_out_of_range),
                                          problem("bad_annotations", ANN, "glove_id", "000004")),
    "annotations-view-id-out-of-range": (_edit_annotations("train", _view_out_of_range),
                                         problem("bad_annotations", ANN, "view_id 999", "000004", frames_checked=59)),
    "annotations-all-invisible": (_edit_annotations("train", _all_invisible),
                                  problem("marked_invisible", "train/seg/000003.png", "marked invisible")),
    # the contract's reader refuses the file (hupbench.core.contract.read_annotations): the split is not checked
    "annotations-K-zero": (_edit_annotations("train", _K_zero([3])),
                           problem("bad_annotations", ANN, "K has fx or fy <= 0 in 1 rows", "row 3", frames_checked=40)),
    "annotations-K-zero-every-frame": (_edit_annotations("train", _K_zero(slice(None))),
                                       problem("bad_annotations", ANN, "K has fx or fy <= 0", "row 0",
                                               frames_checked=40)),
    "manifest-hand-and-probe-labels-swapped": (_edit_manifest(_labels_swapped),
                                               error("manifest.json", "seg_labels", "'hand': 3")),
    "manifest-modalities-drop-seg": (_edit_manifest(_set("modalities", ["rgb", "depth"])),
                                     problem("manifest_mismatch", "manifest.json", "do not list seg", "train/seg/ 20")),
    "annotations-negative-lamp-power": (_edit_annotations("train", _negative_lamp_power),
                                        problem("bad_annotations", ANN, "light_energy_w", "000004", "-120")),
    "annotations-lamp-colour-above-one": (_edit_annotations("train", _lamp_colour_above_one),
                                          problem("bad_annotations", ANN, "light_color", "000004", "[0, 1]")),
    "grasps-sha256-not-the-manifest's": (_edit_manifest(_set("grasps_sha256", "0" * 64)),
                                         problem("grasps_file", "grasps.npz", "not the manifest's grasps_sha256")),
    "grasps-missing": (_remove("grasps.npz"), problem("grasps_file", "grasps.npz", "missing")),
    "grasps-replaced": (_other_grasps, problem("grasps_file", "grasps.npz", "not the grasps the frames were rendered with")),
}
for modality, rel in (("rgb", RGB3), ("depth", DEPTH3), ("seg", SEG3)):
    CASES |= {
        f"{modality}-missing": (_remove(rel), problem("missing_file", rel)),
        f"{modality}-empty": (_file_bytes(rel, lambda b: b""), problem("undecodable_file", rel, "empty")),
        f"{modality}-truncated": (_file_bytes(rel, lambda b: b[: len(b) // 2]), problem("undecodable_file", rel, "truncated")),
        f"{modality}-random-bytes": (_file_bytes(rel, _random_bytes), problem("undecodable_file", rel)),
        f"{modality}-wrong-size": (_image(rel, lambda im: cv2.resize(im, (48, 48), interpolation=cv2.INTER_NEAREST)),
                                   problem("image_format", rel, "48 x 48", "64 x 64")),
    }
CASES |= {
    "depth-8-bit": (_image(DEPTH3, lambda im: (im // 256).astype(np.uint8)), problem("image_format", DEPTH3, "uint8", "uint16")),
    "seg-unknown-labels": (_image(SEG3, lambda im: np.where(im == 1, 9, im).astype(np.uint8)), problem("image_format", SEG3, "9")),
    "rgb-swapped-same-view-other-background": (_swap("train", "rgb", *SAME_VIEW_OTHER_BG), problem("rgb_mismatch", "rgb/000003.jpg")),
    "rgb-swapped-other-view": (_swap("train", "rgb", *OTHER_VIEW_SAME_BG), problem("rgb_mismatch", "rgb/000002.jpg")),
    "rgb-shuffled": (_cycle("train", "rgb", (4, 9, 15)), problem("rgb_mismatch", "train/rgb/")),
    "depth-swapped": (_swap("train", "depth", *OTHER_VIEW_SAME_BG), problem("mask_depth", "depth/000002.png")),
    "seg-swapped": (_swap("train", "seg", *OTHER_VIEW_SAME_BG), problem("mask_depth", "seg/000002.png")),
    "rgb-red-and-blue-swapped": (_image(RGB3, _red_blue_swapped), problem("rgb_channels", RGB3, "swapped")),
    "depth-and-seg-show-nothing": (lambda root: (_image(DEPTH3, _nothing_in_view)(root), _image(SEG3, _nothing_in_view)(root))[0],
                                   problem("empty_frame", SEG3, "nothing")),
    "depth-and-seg-swapped": (lambda root: (_swap("train", "depth", 2, 7)(root), _swap("train", "seg", 2, 7)(root))[0],
                              problem("rgb_mismatch", "rgb/000002.jpg")),
    # options
    "workers-zero": (_argv("--workers", "0"), error("--workers", "0")),
    "workers-not-a-number": (_argv("--workers", "abc"), error("--workers", "abc")),
    "max-report-negative": (_argv("--max-report", "-1"), error("--max-report", "-1")),
    "sample-sheet-a-folder": (_sheet_folder, error("--sample-sheet", "sheet.png", "is a folder")),
    "sample-sheet-empty": (_argv("--sample-sheet", ""), error("--sample-sheet", "file path")),
}


def damaged_copy(tiny_dataset: Path, tmp_path: Path, case: str) -> list[str]:
    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset, root)
    damage, _ = CASES[case]
    return damage(root)


def check_answer(answer, expected: Error | Problem) -> None:
    if isinstance(expected, Error):
        assert_clean_error(answer, *expected.needles)
        return
    assert answer.rc == 1, f"expected FAILED (exit 1): {answer!r}"
    assert "Traceback" not in answer.out + answer.err, answer
    assert answer.err.strip() == "", f"stderr must stay empty (no decoder warnings): {answer.err!r}"
    failed = [line for line in answer.out.splitlines() if line.startswith("hupbench verify: FAILED")]
    assert len(failed) == 1 and expected.kind in failed[0], answer
    lines = [line for line in answer.out.splitlines() if line.strip().startswith(expected.kind)]
    assert any(all(n.lower() in line.lower() for n in expected.needles) for line in lines), \
        f"no {expected.kind} line names {expected.needles}: {answer.out}"
    if expected.frames_checked is not None:
        assert f"in {expected.frames_checked} frames" in failed[0], failed[0]


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_verify(tiny_dataset, tmp_path, capfd, case):
    argv = damaged_copy(tiny_dataset, tmp_path, case)
    if "--workers" not in argv:
        argv.append("--workers=1")  # the tiny dataset is checked in this process
    answer = run_cli(capfd, "verify", *argv)
    check_answer(answer, CASES[case][1])


def test_verify_cli_passes_the_intact_dataset(tiny_dataset, tmp_path, capfd):
    """The control of the matrix: the undamaged copy passes, every frame checked, nothing on stderr."""
    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset, root)
    answer = run_cli(capfd, "verify", root, "--workers", "1")
    assert answer.rc == 0, answer
    assert answer.out.strip().splitlines()[-1] == "hupbench verify: OK, 60 frames checked"
    assert answer.err == ""


def _with_truncated_rgb(tiny_dataset, tmp_path, frames):
    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset, root)
    for fid in frames:
        path = _path(root, "train", "rgb", fid)
        path.write_bytes(path.read_bytes()[:100])
    return root


def test_verify_cli_max_report_says_how_many_it_left_out(tiny_dataset, tmp_path, capfd):
    root = _with_truncated_rgb(tiny_dataset, tmp_path, (1, 2, 3))
    answer = run_cli(capfd, "verify", root, "--workers", "1", "--max-report", "1")
    problem_lines = [line for line in answer.out.splitlines() if line.startswith("  undecodable_file")]
    assert answer.rc == 1 and problem_lines == ["  undecodable_file   train/rgb/000001.jpg (frame 1): truncated "
                                                "(no JPEG end-of-image marker)"]
    assert "  ... and 2 more (--max-report 3 prints all)" in answer.out.splitlines()
    assert answer.out.splitlines()[-1] == "hupbench verify: FAILED, 3 problem(s) in 60 frames: undecodable_file 3"


def test_verify_cli_progress_bar_on_request(tiny_dataset, capfd):
    answer = run_cli(capfd, "verify", tiny_dataset, "--workers", "1", "--progress")
    assert answer.rc == 0 and "verify: 100%" in answer.err and "60/60" in answer.err
    assert answer.out.splitlines()[-1] == "hupbench verify: OK, 60 frames checked"


@pytest.mark.matrix
def test_matrix_verify_sample_sheet_on_a_read_only_mount(tiny_dataset, tmp_path):
    """One line naming the sheet before the checks run, not a traceback after them."""
    from helpers.faults import run_in_namespace

    mount = tmp_path / "ro"
    mount.mkdir()
    answer = run_in_namespace(["verify", tiny_dataset, "--workers", "1", "--sample-sheet", mount / "sheet.png"],
                              read_only=(mount,))
    assert_clean_error(answer, f"cannot write --sample-sheet {mount / 'sheet.png'}", "read-only file system")
    assert "hupbench verify: OK" not in answer.out, "the checks ran before the sheet's path was refused"


def test_verify_prints_the_manifest_grasps_sha256(tiny_dataset, tmp_path, capfd):
    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset, root)
    manifest = _manifest(root)
    manifest.pop("grasps_sha256", None)
    (root / "manifest.json").write_text(json.dumps(manifest))
    answer = run_cli(capfd, "verify", root, "--workers", "1")
    assert answer.rc == 0 and "  grasps.npz sha256: not recorded (a manifest written before datasets recorded it)" \
        in answer.out.splitlines(), answer
    manifest["grasps_sha256"] = hashlib.sha256((root / "grasps.npz").read_bytes()).hexdigest()
    (root / "manifest.json").write_text(json.dumps(manifest))
    answer = run_cli(capfd, "verify", root, "--workers", "1")
    assert answer.rc == 0 and f"  grasps.npz sha256: {manifest['grasps_sha256']}" in answer.out.splitlines(), answer


def test_verify_cli_sample_sheet_after_the_report(tiny_dataset, tmp_path, capfd):
    sheet = tmp_path / "sheet.png"
    answer = run_cli(capfd, "verify", tiny_dataset, "--workers", "1", "--sample-sheet", sheet)
    assert answer.rc == 0 and cv2.imread(str(sheet)) is not None
    assert answer.out.splitlines()[-1] == f"sample sheet: {sheet}"
    # a damaged train split: the report comes first, then the sheet's one-line error
    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset, root)
    (root / ANN).write_bytes(b"")
    answer = run_cli(capfd, "verify", root, "--workers", "1", "--sample-sheet", tmp_path / "sheet2.png")
    assert "hupbench verify: FAILED, 1 problem(s) in 40 frames: damaged_file 1" in answer.out
    assert_clean_error(answer, "annotations.npz")
    assert not (tmp_path / "sheet2.png").exists()

"""hupbench.datagen.dataset.verify: the image statistics on known inputs, the RGB checks on rendered frames, and
verify's own options (workers, progress, the pool path, checks that cannot run)."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from helpers.datasets import TINY_SPEC, write_grasps
from hupbench.core import tolerances as tol
from hupbench.datagen.dataset import verify as V
from hupbench.datagen.dataset import verify_images as VI
from hupbench.core.contract import read_annotations, read_manifest
from hupbench.datagen.dataset.verify import verify
from hupbench.datagen.dataset.verify_images import background_mismatch_px, image_format_problem, mask_depth_mismatch_px, read_image

GLOVES = np.array([[0.5647, 0.5922, 0.7686], [0.3804, 0.6196, 0.8667]])  # hupbench.datagen.render.scene.GLOVE_RGB


def quiet(*_):
    pass


# --- files -----------------------------------------------------------------------------------


@pytest.fixture()
def images(tmp_path):
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (32, 40, 3), dtype=np.uint8)
    depth = rng.integers(0, 65535, (32, 40), dtype=np.uint16)
    paths = {"rgb": tmp_path / "a.jpg", "depth": tmp_path / "a.png"}
    assert cv2.imwrite(str(paths["rgb"]), rgb) and cv2.imwrite(str(paths["depth"]), depth)
    return paths, depth


def test_read_image_reads_whole_files(images):
    paths, depth = images
    image, why = read_image(paths["depth"], "depth")
    assert why is None and image.dtype == np.uint16
    np.testing.assert_array_equal(image, depth)
    image, why = read_image(paths["rgb"], "rgb")
    assert why is None and image.shape == (32, 40, 3) and image.dtype == np.uint8


@pytest.mark.parametrize("damage, why", [
    (lambda b: b"", "empty (0 bytes)"),
    (lambda b: b[: len(b) - 40], "truncated"),
    (lambda b: b"GIF89a" + b[6:], "not a"),
])
@pytest.mark.parametrize("modality", ["rgb", "depth"])
def test_read_image_refuses_damaged_files_without_decoder_noise(images, capfd, damage, why, modality):
    paths, _ = images
    path = paths[modality]
    path.write_bytes(damage(path.read_bytes()))
    capfd.readouterr()
    image, answer = read_image(path, modality)
    assert image is None and why in answer
    # libjpeg warns "Premature end of JPEG file" on stderr when it decodes a truncated JPEG: it must not run
    assert capfd.readouterr().err == ""


def test_read_image_missing(tmp_path):
    assert read_image(tmp_path / "no.png", "seg") == (None, "missing")


def test_image_format_problem():
    size = (40, 32)
    assert image_format_problem(np.zeros((32, 40), np.uint16), "depth", size) is None
    assert image_format_problem(np.zeros((32, 40, 3), np.uint8), "rgb", size) is None
    assert image_format_problem(np.zeros((40, 32), np.uint16), "depth", size) == \
        "32 x 40 pixels, the manifest's image_size is 40 x 32"
    assert "expected single-channel uint16" in image_format_problem(np.zeros((32, 40), np.uint8), "depth", size)
    assert "expected single-channel uint8" in image_format_problem(np.zeros((32, 40), np.uint16), "seg", size)
    seg = np.zeros((32, 40), np.uint8)
    seg[3, 4], seg[5, 6] = 3, 200
    assert image_format_problem(seg, "seg", size).startswith("labels [200] outside")


# --- statistics on known inputs ----------------------------------------------------------------


def test_mask_depth_mismatch_counts_only_off_the_edge():
    seg = np.zeros((48, 48), np.uint8)
    seg[10:30, 10:30] = 1
    depth = np.where(seg > 0, 5000, 0).astype(np.uint16)
    assert mask_depth_mismatch_px(depth, seg) == 0
    # a 1-pixel disagreement all along the edge is how two rasterisations differ: not counted
    grown = cv2.dilate(seg, np.ones((3, 3), np.uint8))
    assert mask_depth_mismatch_px(np.where(grown > 0, 5000, 0).astype(np.uint16), seg) == 0
    # depth shifted down 5 rows: rows 31-34 have depth outside the grown mask (4 x 20), rows 11-14 of
    # the shrunk mask (cols 11-28) have none (4 x 18)
    shifted = np.zeros_like(depth)
    shifted[15:35, 10:30] = 5000
    assert mask_depth_mismatch_px(shifted, seg) == 4 * 20 + 4 * 18


def _off_by(image, y, x, channel, levels):
    value = int(image[y, x, channel])
    image[y, x, channel] = value + levels if value < 128 else value - levels


def test_background_mismatch_counts_changed_background_pixels():
    rng = np.random.default_rng(2)
    background = rng.integers(0, 256, (80, 80, 3), dtype=np.uint8)
    seg = np.zeros((80, 80), np.uint8)
    seg[10:20, 10:20] = 2  # JPEG blocks (16 px) 0-1 hold it; with their neighbours, rows and columns 0-47 are near
    rgb = background.copy()
    rgb[10:20, 10:20] = 0  # the object: not counted
    assert background_mismatch_px(rgb, seg, background) == 0
    near, far = tol.VERIFY_BACKGROUND_LEVELS, tol.VERIFY_BACKGROUND_FAR_LEVELS
    _off_by(rgb, 30, 30, 0, near + 1)  # near the object: counted
    _off_by(rgb, 33, 5, 2, near)  # near, within the JPEG tolerance of an edge block: not counted
    rgb[20, 15] = 255 - background[20, 15]  # in the 1-pixel band next to the object: not counted
    _off_by(rgb, 70, 70, 1, far + 1)  # in a block of background only: counted
    _off_by(rgb, 60, 75, 1, far)  # not counted
    assert background_mismatch_px(rgb, seg, background) == 2


def test_jpeg_reference_is_the_background_as_stored():
    from hupbench.datagen.assets.backgrounds import BackgroundSet

    background = BackgroundSet.builtin().image(2, 64, 64)
    np.testing.assert_array_equal(VI.jpeg_reference(background, None), background)
    ok, buf = cv2.imencode(".jpg", background[..., ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 80])
    np.testing.assert_array_equal(VI.jpeg_reference(background, 80), cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    assert np.abs(VI.jpeg_reference(background, 80).astype(int) - background).max() > 0


def _shade(albedo, light, k_diffuse, k_specular):
    """Stored uint8 RGB of pyrender's shading model (module docstring of hupbench.datagen.dataset.verify)."""
    linear = VI.RENDER_AMBIENT * albedo + k_diffuse[:, None] * (albedo * light) + k_specular[:, None] * light
    return np.round(255 * np.clip(linear, 0, 1) ** (1 / VI.RENDER_GAMMA)).astype(np.uint8)


def _hand_image(glove, light, seed):
    """A 32 x 32 image whose 24 x 24 hand (20 x 20 after shrinking: 100 blocks) is shaded by the model."""
    rng = np.random.default_rng(seed)
    n = 24 * 24
    rgb = np.zeros((32, 32, 3), np.uint8)
    rgb[4:28, 4:28] = _shade(GLOVES[glove], np.asarray(light), rng.uniform(0, 0.5, n), rng.uniform(0, 0.05, n)).reshape(24, 24, 3)
    assert rgb.max() < tol.VERIFY_GLOVE_CLIPPED_LEVEL
    return rgb


SEG_HAND = np.pad(np.ones((24, 24), np.uint8), 4)


@pytest.mark.parametrize("light", [(1.0, 1.0, 1.0), (0.6, 0.6, 1.0), (1.0, 1.0, 0.6)])
def test_glove_cost_tells_the_gloves_apart_on_the_shading_model(light):
    """Pixels shaded by the renderer's model fit their own glove's plane and not the other's, whatever the lamp."""
    for g in (0, 1):
        blocks, noise = VI.hand_blocks(_hand_image(g, light, seed=g), SEG_HAND)
        assert blocks.shape == (100, 3) and noise.shape == (100,)
        own, other = VI.glove_cost(blocks, noise, GLOVES[g], light), VI.glove_cost(blocks, noise, GLOVES[1 - g], light)
        assert own < 0.05 * other, (own, other)


def test_glove_pair_ratio_own_copied_swapped():
    light_a, light_b = (0.9, 0.9, 0.65), (0.62, 0.62, 0.95)
    a, b = _hand_image(0, light_a, 1), _hand_image(1, light_b, 2)
    ratio, limit, (ra, rb) = VI.glove_pair_ratio(a, b, SEG_HAND, GLOVES, 0, 1, light_a, light_b)
    assert limit == tol.VERIFY_GLOVE_PAIR_RATIO and ratio < 0.05 and ra < 0.05 and rb < 0.05
    swapped, _, (ra, rb) = VI.glove_pair_ratio(b, a, SEG_HAND, GLOVES, 0, 1, light_a, light_b)
    assert swapped > 20 and ra > 20 and rb > 20
    copied, _, (ra, rb) = VI.glove_pair_ratio(b, b, SEG_HAND, GLOVES, 0, 1, light_a, light_b)
    assert copied == pytest.approx(1.0) and ra > 20 and rb < 0.05  # frame a holds b's image


def test_glove_pair_ratio_needs_enough_blocks():
    seg = np.zeros((32, 32), np.uint8)
    seg[10:17, 10:17] = 1  # 3 x 3 pixels after shrinking: one whole 2 x 2 block per frame
    rgb = np.full((32, 32, 3), 120, np.uint8)
    assert len(VI.hand_blocks(rgb, seg)[0]) == 1
    ratio, limit, _ = VI.glove_pair_ratio(rgb, rgb, seg, GLOVES, 0, 1, np.ones(3), np.ones(3))
    assert ratio is None and limit == tol.VERIFY_GLOVE_PAIR_RATIO_FEW


# --- rendered frames with two gloves ---------------------------------------------------------------


@pytest.fixture(scope="module")
def two_gloves(tmp_path_factory):
    """20 frames at 128 px: one grasp, one background, both gloves, 10 views (frame = glove * 10 + view)."""
    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    folder = tmp_path_factory.mktemp("two_gloves")
    grasps, root = write_grasps(folder / "grasps.npz", n=1), folder / "dataset"
    spec = DatasetSpec(**(TINY_SPEC | dict(splits={"train": 1, "val": 0, "test": 0}, n_gloves=2, n_backgrounds=1,
                                           width=128, height=128, fx=240.0, fy=240.0, cx=64.0, cy=64.0)))
    generate(GenerateRun(spec, root, grasps, progress=False), {"test": "two_gloves"}, log=quiet)
    return root


def _copy(root, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(root, out)
    return out


def _swap(root, a, b, modality="rgb", ext="jpg"):
    pa, pb = (root / "train" / modality / f"{f:06d}.{ext}" for f in (a, b))
    data = pa.read_bytes()
    pa.write_bytes(pb.read_bytes())
    pb.write_bytes(data)


def _pair_ratios(root):
    """{view: (pair ratio, limit)} of the frames v (glove 0) and 10 + v (glove 1)."""
    manifest = read_manifest(root)
    ann = read_annotations(root, "train", manifest=manifest)
    out = {}
    for v in range(10):
        rgb = [read_image(root / "train" / "rgb" / f"{f:06d}.jpg", "rgb")[0][..., ::-1].copy() for f in (v, 10 + v)]
        seg, _ = read_image(root / "train" / "seg" / f"{v:06d}.png", "seg")
        assert ann["glove_id"][v] == 0 and ann["glove_id"][10 + v] == 1
        out[v] = VI.glove_pair_ratio(*rgb, seg, manifest["gloves_rgb"], 0, 1, ann["light_color"][v],
                                    ann["light_color"][10 + v])[:2]
    return out


def test_correct_two_glove_frames_pass(two_gloves):
    result = verify(two_gloves, workers=1, log=quiet)
    assert result["ok"], result["problems"]
    assert result["frames"] == 20 and result["skipped"] == []
    ratios = _pair_ratios(two_gloves)
    assert all(r is not None and r < 0.5 * limit for r, limit in ratios.values()), ratios


def test_rgb_swapped_between_gloves_of_the_same_view_is_found(two_gloves, tmp_path):
    """The two frames share geometry, mask, depth and background: only glove and lamp tell them apart."""
    broken = _copy(two_gloves, tmp_path)
    views = (1, 4, 6)
    for v in views:
        _swap(broken, v, 10 + v)
    problems = verify(broken, workers=1, log=quiet)["problems"]
    found = {(p["kind"], p["frame_id"]) for p in problems}
    assert found == {("rgb_mismatch", f) for v in views for f in (v, 10 + v)}, problems
    assert all("swapped with or copied from that frame" in p["detail"] and p["file"].startswith("train/rgb/")
               for p in problems)


def test_rgb_copied_from_the_other_glove_is_found(two_gloves, tmp_path):
    broken = _copy(two_gloves, tmp_path)
    (broken / "train" / "rgb" / "000003.jpg").write_bytes((broken / "train" / "rgb" / "000013.jpg").read_bytes())
    problems = verify(broken, workers=1, log=quiet)["problems"]
    assert [(p["kind"], p["frame_id"]) for p in problems] == [("rgb_mismatch", 3)], problems
    assert "frame 000013" in problems[0]["detail"]


@pytest.mark.parametrize("modality, ext", [("seg", "png"), ("rgb", "jpg")])
def test_a_file_from_another_view_does_not_implicate_the_other_glove(two_gloves, tmp_path, modality, ext):
    """Frames 1 and 5 hold each other's seg (or RGB): their glove partners 11 and 15 are not named (read
    through frame 5's new mask, the images of frames 5 and 15 had made frame 15 the stranger)."""
    broken = _copy(two_gloves, tmp_path)
    _swap(broken, 1, 5, modality, ext)
    problems = verify(broken, workers=1, log=quiet)["problems"]
    assert {p["frame_id"] for p in problems} == {1, 5}, problems


@pytest.mark.parametrize("a, b", [(2, 15), (4, 6)], ids=["other-glove-other-view", "same-glove-other-view"])
def test_rgb_swapped_between_views_is_found(two_gloves, tmp_path, a, b):
    broken = _copy(two_gloves, tmp_path)
    _swap(broken, a, b)
    problems = verify(broken, workers=1, log=quiet)["problems"]
    assert {p["frame_id"] for p in problems} == {a, b} and {p["kind"] for p in problems} == {"rgb_mismatch"}


# --- verify's options and what it cannot check ---------------------------------------------------


@pytest.mark.parametrize("workers", [0, -1, 1.5, "2", True])
def test_verify_refuses_bad_worker_counts(tiny_dataset, workers):
    with pytest.raises(ValueError, match=r"workers must be a whole number >= 1, got"):
        verify(tiny_dataset, workers=workers, log=quiet)


def test_worker_processes_find_what_one_process_finds(tiny_dataset, tmp_path, monkeypatch):
    broken = _copy(tiny_dataset, tmp_path)
    _swap(broken, 2, 7)
    (broken / "test" / "seg" / "000045.png").write_bytes(b"")
    one = verify(broken, workers=1, log=quiet)
    monkeypatch.setattr(V, "POOL_MIN_FRAMES", 0)  # the pool serves datasets of more than 64 frames
    two = verify(broken, workers=2, log=quiet)
    assert two["problems"] == one["problems"] and two["frames"] == one["frames"] == 60
    assert {(p["kind"], p["frame_id"]) for p in one["problems"]} == \
        {("rgb_mismatch", 2), ("rgb_mismatch", 7), ("undecodable_file", 45)}


def test_progress_bar_only_when_asked_or_on_a_terminal(tiny_dataset, capsys):
    verify(tiny_dataset, workers=1, log=quiet)  # stderr is not a terminal under pytest
    assert capsys.readouterr().err == ""
    verify(tiny_dataset, workers=1, log=quiet, progress=True)
    bar = capsys.readouterr().err
    assert "verify: 100%" in bar and "60/60" in bar and "frame/s" in bar


def test_checks_that_cannot_run_are_named(tiny_dataset, tmp_path):
    """Photographs that are not here, or a manifest without glove colours: those checks are skipped, said so."""
    broken = _copy(tiny_dataset, tmp_path)
    manifest = json.loads((broken / "manifest.json").read_text())
    manifest["backgrounds"]["fingerprint"] = "0" * 64
    manifest["config"]["backgrounds"] = {"dir": str(tmp_path / "photos_gone")}
    del manifest["gloves_rgb"]
    (broken / "manifest.json").write_text(json.dumps(manifest))
    lines = []
    result = verify(broken, workers=1, log=lines.append)
    assert result["ok"] and result["frames"] == 60
    assert result["skipped"] == [
        "RGB against background images: the backgrounds it was rendered with are not here (fingerprint differs "
        f"from backgrounds.dir {tmp_path / 'photos_gone'} or the built-in backgrounds)",
        "RGB against glove colours: the manifest records no gloves_rgb"]
    assert [line for line in lines if line.startswith("not checked:")] == [f"not checked: {s}" for s in result["skipped"]]


def test_sample_sheet_reads_through_the_contract(tiny_dataset, tmp_path):
    from hupbench.datagen.dataset.sample_sheet import sample_sheet

    sheet = sample_sheet(tiny_dataset, view=3, tile_px=32)
    assert sheet.dtype == np.uint8 and sheet.ndim == 3
    broken = _copy(tiny_dataset, tmp_path)
    (broken / "train" / "annotations.npz").write_bytes(b"")
    with pytest.raises(ValueError, match="annotations.npz"):
        sample_sheet(broken)


@pytest.mark.parametrize("modalities", [["rgb"], ["depth"], ["seg"], ["rgb", "depth"]])
def test_datasets_with_some_modalities(tiny_dataset, tmp_path, modalities):
    """Only the files a dataset has are checked, and only the comparisons its files allow."""
    broken = _copy(tiny_dataset, tmp_path)
    manifest = json.loads((broken / "manifest.json").read_text())
    manifest["modalities"] = modalities
    (broken / "manifest.json").write_text(json.dumps(manifest))
    for modality in {"rgb", "depth", "seg"} - set(modalities):
        for split in ("train", "val", "test"):
            shutil.rmtree(broken / split / modality)
    result = verify(broken, workers=1, log=quiet)
    assert result["ok"] and result["frames"] == 60, result["problems"]
    (broken / "train" / modalities[0] / ("000004.jpg" if modalities[0] == "rgb" else "000004.png")).write_bytes(b"")
    problems = verify(broken, workers=1, log=quiet)["problems"]
    assert [(p["kind"], p["frame_id"]) for p in problems] == [("undecodable_file", 4)]


def test_a_K_whose_last_row_is_not_0_0_1_is_no_camera(tiny_dataset):
    """The contract's reader takes K with positive focal lengths; verify's row check refuses the frame whose last
    row is not 0 0 1 and checks no further with it."""
    from hupbench.datagen.dataset.verify_annotations import check_rows

    manifest = read_manifest(tiny_dataset)
    ann = read_annotations(tiny_dataset, "train", manifest=manifest)
    ann["K"][4, 2] = [0.0, 0.0, 2.0]
    problems, usable = check_rows(ann, "train", manifest)
    frame = int(ann["frame_id"][4])
    bad = [p for p in problems if p["kind"] == "bad_annotations"]
    assert [p["frame_id"] for p in bad] == [frame] and "is not a camera matrix" in bad[0]["detail"]
    assert np.flatnonzero(~usable).tolist() == [4]
    assert [p["kind"] for p in problems if p["kind"] != "bad_annotations"] == ["manifest_mismatch"]

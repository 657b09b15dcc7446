import hashlib
import itertools
import os
import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest

from hupbench.datagen.assets.background_scenes import BASE_PX
from hupbench.datagen.assets.backgrounds import BUILTIN_NAMES, BackgroundSet, composite

LUMA_REC709 = np.array([0.2126, 0.7152, 0.0722])
#: (index, width, height) -> one of the 8 built-in backgrounds
builtin_background = BackgroundSet.builtin().image


def _write_rgb(path, rgb):
    """Save an RGB image through OpenCV (which wants BGR)."""
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def _solid(height, width, rgb):
    return np.tile(np.array(rgb, np.uint8), (height, width, 1))


def _digest(images):
    digest = hashlib.sha256()
    for image in images:
        digest.update(np.ascontiguousarray(image).tobytes())
    return digest.hexdigest()


# --------------------------------------------------------------------------- built-ins


def test_builtin_names_in_paper_order():
    assert BUILTIN_NAMES == ("plain_white", "consultation_room", "phantom_1", "phantom_2", "phantom_3",
                             "abdomen_light", "abdomen_brown", "abdomen_dark")


@pytest.mark.parametrize("width, height", [(256, 256), (128, 96), (96, 128), (16, 16), (BASE_PX, BASE_PX), (600, 300)])
def test_builtin_shape_and_dtype(width, height):
    for index in range(len(BUILTIN_NAMES)):
        image = builtin_background(index, width, height)
        assert image.shape == (height, width, 3)
        assert image.dtype == np.uint8


def test_plain_white_is_exactly_255():
    for width, height in [(256, 256), (128, 96), (17, 300)]:
        assert np.all(builtin_background(0, width, height) == 255)


def test_builtins_are_cached_read_only_and_repeatable():
    first = builtin_background(3, 128, 96)
    assert builtin_background(3, 128, 96) is first
    with pytest.raises(ValueError):
        first[0, 0, 0] = 7  # read-only: a caller cannot corrupt the cache
    from hupbench.datagen.assets import background_scenes, backgrounds

    # repaint from scratch: the painting itself, not only the cache, must be deterministic
    repainted = np.clip(np.rint(background_scenes.SCENES[3]() * 255.0), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(repainted, backgrounds._base_image(3))


def test_builtins_identical_in_a_second_process():
    """The second process runs OpenBLAS's oldest x86-64 kernel (Prescott; the variable is ignored elsewhere): the
    painting's ``a @ b`` once took the last bits from the CPU's BLAS kernel, and an Intel Xeon (SkylakeX kernel)
    painted 6 pixels of phantom_2 one level apart from the AMD EPYCs (Haswell kernel), another fingerprint."""
    size = (64, 48)
    here_images = _digest(builtin_background(i, *size) for i in range(len(BUILTIN_NAMES)))
    here_fingerprint = BackgroundSet.builtin().fingerprint()
    script = textwrap.dedent(f"""
        import hashlib
        import numpy as np
        from hupbench.datagen.assets.backgrounds import BUILTIN_NAMES, BackgroundSet
        digest = hashlib.sha256()
        for i in range(len(BUILTIN_NAMES)):
            digest.update(np.ascontiguousarray(BackgroundSet.builtin().image(i, {size[0]}, {size[1]})).tobytes())
        print(digest.hexdigest(), BackgroundSet.builtin().fingerprint())
    """)
    env = {**os.environ, "OPENBLAS_CORETYPE": "Prescott"}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, env=env)
    there_images, there_fingerprint = out.stdout.split()
    assert there_images == here_images
    assert there_fingerprint == here_fingerprint


def test_builtins_differ_pairwise():
    images = [builtin_background(i, 64, 64).astype(np.float64) for i in range(len(BUILTIN_NAMES))]
    for a, b in itertools.combinations(range(len(images)), 2):
        mean_abs = np.abs(images[a] - images[b]).mean()
        assert mean_abs > 20.0, f"{BUILTIN_NAMES[a]} vs {BUILTIN_NAMES[b]}: mean |diff| {mean_abs:.1f}"


def test_non_white_builtins_are_not_flat():
    for index in range(1, len(BUILTIN_NAMES)):
        assert builtin_background(index, 128, 128).std() > 10.0, BUILTIN_NAMES[index]


def test_abdomen_tones_ordered_by_luminance():
    names = ("abdomen_light", "abdomen_brown", "abdomen_dark")
    images = [builtin_background(BUILTIN_NAMES.index(n), 128, 128).astype(np.float64) for n in names]
    whole = [(im @ LUMA_REC709).mean() for im in images]
    skin = [(im[40:88, 32:96] @ LUMA_REC709).mean() for im in images]  # the belly fills the centre
    assert whole[0] > whole[1] > whole[2]
    assert skin[0] > skin[1] + 30 > skin[2] + 60


def test_abdomen_centre_is_skin_coloured():
    for name in ("abdomen_light", "abdomen_brown", "abdomen_dark"):
        r, g, b = builtin_background(BUILTIN_NAMES.index(name), 128, 128)[40:88, 32:96].reshape(-1, 3).mean(0)
        assert r > g > b, name  # skin reflects red most, blue least


@pytest.mark.parametrize("width, height", [(15, 64), (64, 0), (-3, 64)])
def test_builtin_bad_size_is_a_bug(width, height):
    """DatasetSpec refuses an image side under MIN_SIZE_PX: asking a background for one is a bug."""
    with pytest.raises(AssertionError):
        builtin_background(1, width, height)


def test_builtin_accepts_numpy_integers():
    np.testing.assert_array_equal(builtin_background(np.int64(2), np.int32(40), np.int64(30)),
                                  builtin_background(2, 40, 30))


# --------------------------------------------------------------------------- BackgroundSet


def test_builtin_set_names_and_fingerprint():
    bs = BackgroundSet.builtin()
    assert len(bs) == 8
    assert bs.names == BUILTIN_NAMES
    fingerprint = bs.fingerprint()
    assert len(fingerprint) == 64 and int(fingerprint, 16) >= 0
    assert BackgroundSet.builtin().fingerprint() == fingerprint


@pytest.fixture()
def photo_dir(tmp_path):
    _write_rgb(tmp_path / "b_blue.png", _solid(40, 60, (10, 20, 230)))
    _write_rgb(tmp_path / "a_red.PNG", _solid(30, 30, (220, 30, 40)))
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "sub.png").mkdir()  # a folder with an image suffix is not a file
    return tmp_path


def test_from_dir_reads_sorted_images_as_rgb(photo_dir):
    bs = BackgroundSet.from_dir(photo_dir)
    assert len(bs) == 2
    assert bs.names == ("a_red.PNG", "b_blue.png")
    red = bs.image(0, 32, 16)
    assert red.shape == (16, 32, 3) and red.dtype == np.uint8
    assert np.all(red == (220, 30, 40))
    assert np.all(bs.image(1, 20, 20) == (10, 20, 230))


def test_from_dir_caches_read_only(photo_dir):
    bs = BackgroundSet.from_dir(photo_dir)
    image = bs.image(1, 24, 24)
    assert bs.image(1, 24, 24) is image
    assert not image.flags.writeable
    assert bs.image(1, 24, 25) is not image


def test_from_dir_fingerprint_follows_pixels(photo_dir, tmp_path_factory):
    first = BackgroundSet.from_dir(photo_dir).fingerprint()
    assert BackgroundSet.from_dir(photo_dir).fingerprint() == first
    assert first != BackgroundSet.builtin().fingerprint()
    changed = _solid(40, 60, (10, 20, 230))
    changed[5, 5] = (10, 20, 231)
    _write_rgb(photo_dir / "b_blue.png", changed)
    assert BackgroundSet.from_dir(photo_dir).fingerprint() != first


def test_from_dir_unreadable_file_is_named(photo_dir):
    (photo_dir / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n but then garbage")
    with pytest.raises(ValueError, match=r"cannot read background image .*broken\.png"):
        BackgroundSet.from_dir(photo_dir)


def test_from_dir_empty_file_is_named(tmp_path):
    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.jpg"):
        BackgroundSet.from_dir(tmp_path)


def test_from_dir_without_images(tmp_path):
    (tmp_path / "readme.md").write_text("no pictures here")
    with pytest.raises(ValueError, match="no images found in"):
        BackgroundSet.from_dir(tmp_path)


def test_from_dir_missing_folder(tmp_path):
    with pytest.raises(ValueError, match="does not exist or is not a folder"):
        BackgroundSet.from_dir(tmp_path / "nope")


def test_set_image_bad_size_is_a_bug(photo_dir):
    with pytest.raises(AssertionError):
        BackgroundSet.from_dir(photo_dir).image(0, 8, 32)


RED, BLUE, GREEN = (200, 0, 0), (0, 0, 200), (0, 200, 0)


def test_centre_crop_of_wide_image(tmp_path):
    # 400 x 200: green | red | blue | green, each 100 px wide; a square crop keeps only red | blue
    wide = _solid(200, 400, GREEN)
    wide[:, 100:200] = RED
    wide[:, 200:300] = BLUE
    _write_rgb(tmp_path / "wide.png", wide)
    out = BackgroundSet.from_dir(tmp_path).image(0, 100, 100)
    assert out.shape == (100, 100, 3)
    assert np.all(out[:, :50] == RED)
    assert np.all(out[:, 50:] == BLUE)


def test_centre_crop_of_tall_image(tmp_path):
    tall = _solid(400, 200, GREEN)
    tall[100:200] = RED
    tall[200:300] = BLUE
    _write_rgb(tmp_path / "tall.png", tall)
    out = BackgroundSet.from_dir(tmp_path).image(0, 100, 100)
    assert np.all(out[:50] == RED)
    assert np.all(out[50:] == BLUE)


def test_enlarging_keeps_the_colour(tmp_path):
    _write_rgb(tmp_path / "small.png", _solid(20, 20, (1, 2, 3)))
    out = BackgroundSet.from_dir(tmp_path).image(0, 64, 48)
    assert out.shape == (48, 64, 3)
    assert np.all(out == (1, 2, 3))


# --------------------------------------------------------------------------- composite


def test_composite_alpha_extremes_and_half():
    fg_rgb, bg_rgb = (200, 100, 50), (10, 20, 30)
    fg = np.zeros((2, 3, 4), np.uint8)
    fg[..., :3] = fg_rgb
    fg[0, 0, 3], fg[0, 1, 3], fg[0, 2, 3] = 0, 255, 128
    bg = _solid(2, 3, bg_rgb)
    out = composite(fg, bg)
    assert out.shape == (2, 3, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[0, 0], bg_rgb)
    np.testing.assert_array_equal(out[0, 1], fg_rgb)
    half = (128 * np.array(fg_rgb) + 127 * np.array(bg_rgb)) / 255  # 105.3, 60.2, 40.0
    assert np.all(np.abs(out[0, 2] - half) <= 1)
    np.testing.assert_array_equal(out[0, 2], (105, 60, 40))


def test_composite_matches_float_over_operator_for_every_alpha():
    alpha = np.arange(256, dtype=np.uint8).reshape(16, 16)
    fg = np.zeros((16, 16, 4), np.uint8)
    fg[..., 0], fg[..., 1], fg[..., 2], fg[..., 3] = 255, 0, 77, alpha
    bg = _solid(16, 16, (0, 255, 201))
    a = alpha[..., None] / 255.0
    expected = a * fg[..., :3] + (1 - a) * bg
    out = composite(fg, bg)
    assert np.abs(out - expected).max() <= 0.5 + 1e-9  # rounded to nearest


def test_composite_leaves_inputs_untouched():
    fg = np.full((4, 4, 4), 90, np.uint8)
    bg = builtin_background(1, 16, 16)[:4, :4]
    fg_before, bg_before = fg.copy(), bg.copy()
    composite(fg, bg)
    np.testing.assert_array_equal(fg, fg_before)
    np.testing.assert_array_equal(bg, bg_before)

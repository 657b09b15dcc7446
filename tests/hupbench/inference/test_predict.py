"""hupbench predict: geometry, camera conversion, image reading, overlays, the CLI, and no torch.

Most tests use the known-answer ONNX graph of tests/helpers/dot_model.py (a red dot in, a known
prediction out).
"""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import REPO
from helpers.dot_model import (
    DEPTHS_M,
    K_TRAIN,
    OFFSETS_NORM,
    N,
    S,
    contract_metadata,
    dot_image,
    make_dot_model,
    photo_like,
)

from hupbench.core import keypoints as kp
from hupbench.core.draw import FINGER_RGB, PROBE_RGB
from hupbench.core.io import compact_json
from hupbench.cli import main
from hupbench.inference.images import decode_image, expand_inputs
from hupbench.inference.model_file import read_metadata
from hupbench.inference.overlay import draw_prediction, keypoint_color, line_width
from hupbench.inference.predict import (
    PAD_VALUE,
    PredictOptions,
    preprocess,
    run_predict,
)
from hupbench.inference.user_camera import (
    CAMERA_ASSUMED,
    CAMERA_USER,
    keypoints_for_image,
    parse_intrinsics,
    user_camera_points,
)
from hupbench.inference.runtime import load_onnx_model
from hupbench.input_geometry import InputGeometry, apply_affine


@pytest.fixture(scope="module")
def dot_model(tmp_path_factory) -> Path:
    return make_dot_model(tmp_path_factory.mktemp("onnx") / "dot.onnx")






def project(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    return (points_cam[:, :2] / points_cam[:, 2:]) * np.diag(K)[:2] + K[:2, 2]


# ------------------------------------------------------------------ geometry


def test_preprocess_pads_with_grey_and_keeps_content():
    image = np.ones((60, 100, 3), dtype=np.float32)  # white, wide: grey bands top and bottom
    model_input, g = preprocess(image, S)
    assert model_input.shape == (3, S, S) and model_input.dtype == np.float32
    # rows of the input fully in the padding are grey, rows fully inside the image white
    top_band = int(np.floor(apply_affine(g.image_to_input, [0, -0.5])[1]))  # first input row touching the image
    np.testing.assert_allclose(model_input[:, : top_band - 1], PAD_VALUE, atol=1e-6)
    np.testing.assert_allclose(model_input[:, S // 2], 1.0, atol=1e-6)
    assert g.pad_top == 20 and g.pad_left == 0


# ------------------------------------------------------------------ camera


def test_user_camera_points_known_answer():
    """Known 3D points seen by the user's camera; an ideal training-camera network sees the same pixels."""
    rng = np.random.default_rng(3)
    points_user = rng.uniform([-0.15, -0.1, 0.4], [0.15, 0.1, 0.9], size=(N, 3))
    K_user_in = np.array([[95.0, 0.0, 14.2], [0.0, 95.0, 17.1], [0.0, 0.0, 1.0]])
    uv_in = project(points_user, K_user_in)
    # the training camera sees the same pixels from a point at depth z * f_train / f_user on the same pixel ray
    z_train = points_user[:, 2] * K_TRAIN[0, 0] / K_user_in[0, 0]
    points_train = np.stack([(uv_in[:, 0] - K_TRAIN[0, 2]) * z_train / K_TRAIN[0, 0],
                             (uv_in[:, 1] - K_TRAIN[1, 2]) * z_train / K_TRAIN[1, 1], z_train], axis=1)
    np.testing.assert_allclose(project(points_train, K_TRAIN), uv_in, atol=1e-9)  # two K's, same pixels
    np.testing.assert_allclose(user_camera_points(uv_in, points_train, K_TRAIN, K_user_in), points_user, atol=1e-12)
    # with the principal points equal, only depth changes: (x, y, z) -> (x, y, z * f_user / f_train)
    K_same_c = K_user_in.copy()
    K_same_c[:2, 2] = K_TRAIN[:2, 2]
    uv_same = project(points_train, K_TRAIN)
    expected = points_train * [1.0, 1.0, K_same_c[0, 0] / K_TRAIN[0, 0]]
    np.testing.assert_allclose(user_camera_points(uv_same, points_train, K_TRAIN, K_same_c), expected, atol=1e-12)


def test_user_camera_equal_to_training_camera_is_identity_for_consistent_outputs():
    points = np.random.default_rng(4).uniform([-0.1, -0.1, 0.4], [0.1, 0.1, 0.8], size=(N, 3))
    np.testing.assert_allclose(user_camera_points(project(points, K_TRAIN), points, K_TRAIN, K_TRAIN), points,
                               atol=1e-12)


def test_keypoints_for_image_assumed_and_user_camera():
    g = InputGeometry(100, 60, S)
    xy_norm = OFFSETS_NORM.astype(np.float64)
    uv_in = g.normalized_to_input_px(xy_norm)
    points3d = np.concatenate([(uv_in - K_TRAIN[:2, 2]) * DEPTHS_M[:, None] / 60.0, DEPTHS_M[:, None]], axis=1)
    assumed = keypoints_for_image(xy_norm, points3d, g, K_TRAIN)
    assert assumed["camera"] == CAMERA_ASSUMED
    np.testing.assert_allclose(assumed["keypoints_3d_m"], points3d)  # the network's output as it is
    # f = 60 / 0.32; c = (16 + 0.5) / 0.32 - 0.5 - pad, pad = (0, 20)
    np.testing.assert_allclose(assumed["K"], [[187.5, 0, 51.0625], [0, 187.5, 31.0625], [0, 0, 1]])
    np.testing.assert_allclose(project(points3d, assumed["K"]), assumed["keypoints_2d_px"], atol=1e-9)
    K_user = np.array([[250.0, 0.0, 52.0], [0.0, 250.0, 27.0], [0.0, 0.0, 1.0]])
    user = keypoints_for_image(xy_norm, points3d, g, K_TRAIN, K_user)
    assert user["camera"] == CAMERA_USER
    np.testing.assert_allclose(user["keypoints_3d_m"][:, 2], DEPTHS_M * 250.0 / 187.5, rtol=1e-6)
    np.testing.assert_allclose(project(user["keypoints_3d_m"], K_user), user["keypoints_2d_px"], atol=1e-9)


def test_parse_intrinsics():
    np.testing.assert_allclose(parse_intrinsics("480, 470,320,240"), [[480, 0, 320], [0, 470, 240], [0, 0, 1]])
    for bad in ("480,480,320", "a,b,c,d", "1,2,3,4,5", "0,480,320,240", "-1,480,320,240", "nan,1,1,1"):
        with pytest.raises(ValueError, match="--K"):
            parse_intrinsics(bad)


# ------------------------------------------------------------------ images and inputs


def _encode(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def test_decode_grey_16bit_alpha_and_colour_order():
    grey = decode_image(_encode(".png", np.full((16, 18), 51, np.uint8)))  # 16 px: the smallest side predict reads
    assert grey.shape == (16, 18, 3)
    np.testing.assert_allclose(grey, 0.2, atol=1e-6)
    deep = decode_image(_encode(".png", np.full((16, 16), 65535 // 5, np.uint16)))
    np.testing.assert_allclose(deep, (65535 // 5) / 65535, atol=1e-6)
    bgra = np.zeros((16, 16, 4), np.uint8)
    bgra[..., 2] = 255  # red
    bgra[0, 0, 3] = 255  # only one opaque pixel; the rest is transparent
    rgba = decode_image(_encode(".png", bgra))
    np.testing.assert_allclose(rgba[0, 0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(rgba[1, 1], [PAD_VALUE] * 3)


@pytest.mark.parametrize(("data", "message"), [
    (b"", "empty file"),
    (b"hello, this is text\n", "not a PNG or JPEG"),
    (b"\x89PNG\r\n\x1a\n" + bytes(range(200)), "could not be decoded"),
])
def test_decode_errors(data, message):
    with pytest.raises(ValueError, match=message):
        decode_image(data, "x.png")


def test_expand_inputs(tmp_path):
    d = tmp_path / "dir"
    (d / "sub").mkdir(parents=True)
    for name in ("b.PNG", "a.jpg", "c.JpEg", "notes.txt", "d.bmp"):
        (d / name).write_bytes(b"x")
    files, skipped = expand_inputs([d, tmp_path / "missing.png"])
    assert [f.name for f in files] == ["a.jpg", "b.PNG", "c.JpEg", "missing.png"]
    assert sorted(Path(s["path"]).name for s in skipped) == ["d.bmp", "notes.txt", "sub"]
    with pytest.raises(TypeError, match="list of paths"):
        PredictOptions("m.onnx", str(d))


# ------------------------------------------------------------------ model metadata


def test_metadata_parsing_and_errors(tmp_path):
    meta = read_metadata(contract_metadata())
    assert meta["input_size"] == S and meta["keypoint_names"] == kp.KEYPOINT_NAMES and meta["run_name"] == "dot-run"
    with pytest.raises(ValueError, match="no hupbench metadata"):
        read_metadata({"producer": "x"}, "m.onnx")
    with pytest.raises(ValueError, match="onnx_schema '2'"):
        read_metadata(contract_metadata(**{"hupbench.onnx_schema": "2"}))
    with pytest.raises(ValueError, match="lacks metadata hupbench.K_input"):
        read_metadata(contract_metadata(**{"hupbench.K_input": None}))
    with pytest.raises(ValueError, match="skeleton_edges"):
        read_metadata(contract_metadata(**{"hupbench.skeleton_edges": "[[0, 29]]"}))
    with pytest.raises(ValueError, match="K_input"):
        read_metadata(contract_metadata(**{"hupbench.K_input": "[[0, 0, 1], [0, 1, 1], [0, 0, 1]]"}))


def test_model_without_metadata_is_refused(tmp_path, capsys):
    bare = make_dot_model(tmp_path / "bare.onnx", metadata={})
    with pytest.raises(ValueError, match="has no hupbench metadata"):
        load_onnx_model(bare)
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), dot_image(40, 40, (3, 3)))
    assert main(["predict", str(bare), str(image), "--out", str(tmp_path / "out")]) == 1
    assert "hupbench predict: error:" in capsys.readouterr().err
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not a protobuf at all")
    with pytest.raises(ValueError, match="not a readable ONNX model"):
        load_onnx_model(garbage)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_onnx_model(tmp_path / "none.onnx")


def test_model_input_size_must_match_metadata(tmp_path):
    wrong = make_dot_model(tmp_path / "wrong.onnx", metadata=contract_metadata(**{"hupbench.input_size": "64"}))
    with pytest.raises(ValueError, match=r"expected \(batch, 3, 64, 64\)"):
        load_onnx_model(wrong)


# ------------------------------------------------------------------ overlay


def test_overlay_colours_box_edges_and_line_width():
    h, w = 750, 1000  # lines 3 px wide: their centre pixels carry the exact colour
    image = np.full((h, w, 3), 255, np.uint8)
    uv = np.full((N, 2), np.nan)
    uv[0] = (150, 625)  # wrist
    uv[1] = (375, 625)  # thumb_cmc
    for c, (ix, iy, iz) in enumerate(itertools.product((0, 1), repeat=3)):
        uv[kp.NUM_HAND + c] = (500 + 300 * ix + 125 * iz, 100 + 300 * iy + 75 * iz)
    out = draw_prediction(image, uv, kp.KEYPOINT_NAMES, kp.SKELETON_EDGES)
    assert out.shape == image.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(out[300, 712], [255, 255, 255])  # unchanged where nothing is drawn
    assert tuple(out[625, 262]) == FINGER_RGB["thumb"]  # edge wrist -> thumb_cmc: the thumb's colour
    assert tuple(out[625, 150]) == FINGER_RGB["wrist"] and tuple(out[625, 375]) == FINGER_RGB["thumb"]  # markers
    corners = uv[kp.CORNER_SLICE]
    for a, b in itertools.combinations(range(8), 2):
        u, v = np.round((corners[a] + corners[b]) / 2).astype(int)
        bits_differ = sum(x != y for x, y in zip(kp.CORNER_BITS[a], kp.CORNER_BITS[b]))
        if bits_differ == 1:  # the 12 box edges are drawn in the probe colour
            assert tuple(out[v, u]) == PROBE_RGB, (a, b)
        else:  # face and body diagonals are not drawn
            np.testing.assert_array_equal(out[v, u], [255, 255, 255], err_msg=str((a, b)))
    assert line_width(60, 100) == 1 and line_width(1080, 1920) == 6
    assert keypoint_color("probe_corner_-x-y-z") == PROBE_RGB and keypoint_color("little_tip") == FINGER_RGB["little"]


# ------------------------------------------------------------------ run_predict end to end


def predict(model, inputs, out_dir, log=lambda line: None, **options):
    """``run_predict`` of the options given as keywords, quiet unless ``log`` is given."""
    return run_predict(PredictOptions(model, inputs, out_dir, **options), log=log)


@pytest.fixture(scope="module")
def image_set(tmp_path_factory) -> dict[str, Path]:
    """Images not from the dataset, with the red dot where the graph can find it, and broken files."""
    d = tmp_path_factory.mktemp("images")
    files = {
        "wide": (dot_image(100, 60, (71, 13)), ".png"), "tall": (dot_image(60, 100, (12, 83)), ".png"),
        "square": (dot_image(300, 300, (222, 41)), ".png"), "small": (dot_image(24, 16, (5, 10)), ".png"),
        "grey": (dot_image(50, 80, (0, 0), gray=True), ".png"),
    }
    paths = {}
    for name, (image, ext) in files.items():
        paths[name] = d / f"{name}{ext}"
        cv2.imwrite(str(paths[name]), image)
    paths["photo"] = d / "photo.jpg"
    cv2.imwrite(str(paths["photo"]), photo_like(320, 240), [cv2.IMWRITE_JPEG_QUALITY, 90])
    paths["broken"] = d / "broken.png"
    paths["broken"].write_bytes(np.random.default_rng(5).integers(0, 256, 500, dtype=np.uint8).tobytes())
    paths["empty"] = d / "empty.png"
    paths["empty"].write_bytes(b"")
    paths["text"] = d / "readme.txt"
    paths["text"].write_text("not an image\n")
    return paths


DOTS = {"wide": ((71, 13), (100, 60)), "tall": ((12, 83), (60, 100)), "square": ((222, 41), (300, 300)),
        "small": ((5, 10), (24, 16))}


@pytest.fixture(scope="module")
def predicted(dot_model, image_set, tmp_path_factory):
    out = tmp_path_factory.mktemp("pred")
    order = ["wide", "broken", "tall", "square", "empty", "small", "grey", "photo", "text"]
    messages: list[str] = []
    result = predict(dot_model, [image_set[k] for k in order], out, batch_size=3, log=messages.append)
    document = json.loads((out / "predictions.json").read_text())
    records = {Path(r["path"]).stem: r for r in document["images"]}
    return {"result": result, "doc": document, "records": records, "out": out, "messages": messages,
            "order": order}


def test_predict_dot_lands_on_the_original_pixel(predicted):
    for name, (dot, (w, h)) in DOTS.items():
        record = predicted["records"][name]
        assert record["ok"] and record["error"] is None
        assert record["image_size"] == {"width": w, "height": h}
        g = InputGeometry(w, h, S)
        uv = np.array(record["keypoints_2d_px"])
        assert uv.shape == (N, 2)
        # the graph finds the input pixel containing the dot: within half an input pixel, in original pixels
        half_input_pixel = 0.5 / g.scale
        np.testing.assert_array_less(np.abs(uv[0] - dot), half_input_pixel + 1e-3)
        # every other keypoint sits at its normalised offset from the wrist, scaled to the padded square
        np.testing.assert_allclose(uv - uv[0], OFFSETS_NORM * g.side / 2, atol=2e-3)


def test_predict_grey_image_known_answer(predicted):
    """No red anywhere: ArgMax picks input pixel (0, 0), which lies in the left padding of a 50 x 80 image."""
    record = predicted["records"]["grey"]
    g = InputGeometry(50, 80, S)
    expected = (0.0 + 0.5) / g.scale - 0.5 - np.array([g.pad_left, g.pad_top])  # (-14.25, 0.75)
    np.testing.assert_allclose(record["keypoints_2d_px"][0], expected, atol=1e-3)
    np.testing.assert_allclose(expected, [-14.25, 0.75])


def test_predict_json_content_and_assumed_camera(predicted):
    doc = predicted["doc"]
    assert doc["schema_version"] == 4 and doc["model"]["run_name"] == "dot-run" and doc["videos"] == []
    assert doc["counts"] == {"images": 9, "ok": 6, "failed": 3}
    # a file exported before the confidence output and the calibration existed: both null, and said why
    assert doc["keypoint_confidence"]["available"] is False and doc["ood_check"]["available"] is False
    assert "re-export" in doc["ood_check"]["reason"]
    assert all(r["keypoint_confidence"] is None and r["ood"] is None for r in doc["images"])
    assert [Path(r["path"]).stem for r in doc["images"]] == [
        "wide", "broken", "tall", "square", "empty", "small", "grey", "photo", "readme"]  # input order kept
    for stem in ("wide", "tall", "square", "small", "grey", "photo"):
        record = predicted["records"][stem]
        assert record["camera"] == CAMERA_ASSUMED and record["run_name"] == "dot-run"
        assert record["keypoint_names"] == list(kp.KEYPOINT_NAMES)
        xyz, uv, K = (np.array(record[k]) for k in ("keypoints_3d_m", "keypoints_2d_px", "K"))
        assert xyz.shape == (N, 3)
        np.testing.assert_allclose(xyz[:, 2], DEPTHS_M, atol=1e-6)  # the network's 3D output, unchanged
        np.testing.assert_allclose(project(xyz, K), uv, atol=0.05)  # the reported K is the assumed camera
        np.testing.assert_allclose(K, InputGeometry(**record["image_size"], input_size=S).intrinsics_to_image(K_TRAIN),
                                   atol=1e-6)


def test_predict_errors_are_per_file(predicted):
    records, messages = predicted["records"], predicted["messages"]
    expected = {"broken": "not a PNG or JPEG", "empty": "empty file", "readme": "not a PNG or JPEG"}
    for stem, text in expected.items():
        record = records[stem]
        assert not record["ok"] and text in record["error"] and record["keypoints_3d_m"] is None
        assert any(text in m and stem in m and m.startswith("hupbench predict: error:") for m in messages)
    assert predicted["result"]["failed"] == 3 and predicted["result"]["ok"] == 6


def test_predict_overlays_have_the_original_size(predicted):
    out = predicted["out"]
    for stem in ("wide", "tall", "square", "small", "grey", "photo"):
        path = out / f"{stem}_overlay.png"
        assert predicted["records"][stem]["overlay"] == str(path)
        overlay = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        w, h = (predicted["records"][stem]["image_size"][k] for k in ("width", "height"))
        assert overlay.shape == (h, w, 3)
    # markers sit at the predicted keypoints of the 300 x 300 image, in their keypoint's colour
    uv = np.array(predicted["records"]["square"]["keypoints_2d_px"])
    gaps = np.linalg.norm(uv[:, None] - uv[None], axis=2) + np.eye(N) * 1e9
    isolated = [k for k in range(N) if gaps[k].min() > 10 and np.all((uv[k] > 5) & (uv[k] < 295))]
    assert len(isolated) >= 5
    overlay = cv2.imread(str(out / "square_overlay.png"))[..., ::-1]
    for k in isolated:
        u, v = np.round(uv[k]).astype(int)
        assert tuple(overlay[v, u]) == keypoint_color(kp.KEYPOINT_NAMES[k]), k
    assert not (out / "broken_overlay.png").exists()


def test_predict_user_K_known_answer(dot_model, image_set, tmp_path):
    """--K: depth scales by f_user_in / f_train; the 3D points project through the user's K onto the 2D."""
    K_user = np.array([[150.0, 0.0, 48.0], [0.0, 150.0, 33.0], [0.0, 0.0, 1.0]])
    result = predict(dot_model, [image_set["wide"]], tmp_path, K="150,150,48,33", overlay=False)
    record = result["records"][0]
    assert record["camera"] == CAMERA_USER and record["overlay"] is None
    np.testing.assert_allclose(record["K"], K_user)
    f_user_in = 150.0 * S / 100  # the wide image's scale is S / L = 0.32
    xyz, uv = np.array(record["keypoints_3d_m"]), np.array(record["keypoints_2d_px"])
    np.testing.assert_allclose(xyz[:, 2], DEPTHS_M * f_user_in / K_TRAIN[0, 0], atol=2e-6)
    np.testing.assert_allclose(project(xyz, K_user), uv, atol=2e-3)
    assert not list(tmp_path.glob("*_overlay.png"))


def test_predict_directory_and_stem_collisions(dot_model, image_set, tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    cv2.imwrite(str(d / "x.png"), dot_image(40, 30, (3, 3)))
    cv2.imwrite(str(d / "x.JPG"), photo_like(64, 48))
    (d / "notes.txt").write_text("skip me")
    messages: list[str] = []
    result = predict(dot_model, [d], tmp_path / "out", log=messages.append)
    assert [Path(r["path"]).name for r in result["records"]] == ["x.JPG", "x.png"]
    assert result["failed"] == 0 and [p.name for p in result["overlays"]] == ["x_overlay.png", "x_2_overlay.png"]
    assert result["skipped"] == [{"path": str(d / "notes.txt"), "reason": "not an image or video file name "
                                  "(.png, .jpg, .jpeg, .mp4, .avi, .mov, .mkv, .webm)"}]
    assert any("note:" in m and "notes.txt" in m for m in messages)
    (d / "x.png").unlink()
    (d / "x.JPG").unlink()
    with pytest.raises(ValueError, match="no image or video files"):
        predict(dot_model, [d], tmp_path / "out2", log=messages.append)


def test_json_layout_round_trips():
    document = {"b": [[1.5, -2.0, None], [3, 4, 5]], "a": {"path": "img[1,  2].png", "empty": [], "d": {}},
                "names": ["x", "y"], "flag": True}
    text = compact_json(document)
    assert json.loads(text) == document
    assert '  "b": [\n    [1.5, -2.0, null],\n    [3, 4, 5]\n  ],' in text  # one row per line
    assert '"path": "img[1,  2].png"' in text  # strings untouched


def test_batching_does_not_change_answers(dot_model, image_set, tmp_path):
    names = ["wide", "tall", "square", "small", "grey", "photo"]
    one = predict(dot_model, [image_set[k] for k in names], tmp_path / "a", overlay=False, batch_size=1)
    all_ = predict(dot_model, [image_set[k] for k in names], tmp_path / "b", overlay=False, batch_size=16)
    for r1, r2 in zip(one["records"], all_["records"]):
        assert r1["keypoints_3d_m"] == r2["keypoints_3d_m"] and r1["keypoints_2d_px"] == r2["keypoints_2d_px"]


# ------------------------------------------------------------------ CLI and the no-torch rule


def test_cli_exit_codes(dot_model, image_set, tmp_path, capsys):
    good = [str(image_set["wide"]), str(image_set["photo"])]
    assert main(["predict", str(dot_model), *good, "--out", str(tmp_path / "ok"), "--no-overlay"]) == 0
    assert json.loads((tmp_path / "ok" / "predictions.json").read_text())["counts"]["failed"] == 0
    assert not list((tmp_path / "ok").glob("*.png"))
    rc = main(["predict", str(dot_model), *good, str(image_set["empty"]), "--out", str(tmp_path / "bad"),
               "--K", "100,100,50,30"])
    captured = capsys.readouterr()
    assert rc == 1
    assert f"hupbench predict: error: {image_set['empty']}: empty file" in captured.err
    assert "1 of 3 failed" in captured.out
    assert main(["predict", str(dot_model), *good, "--K", "1,2,3", "--out", str(tmp_path / "k")]) == 1
    assert "--K must be four numbers" in capsys.readouterr().err


def test_predict_does_not_import_torch(dot_model, image_set, tmp_path):
    code = (
        "import sys\n"
        "from hupbench.cli import main\n"
        f"rc = main(['predict', {str(dot_model)!r}, {str(image_set['photo'])!r}, {str(image_set['wide'])!r}, "
        f"'--out', {str(tmp_path)!r}, '--K', '300,300,160,120'])\n"
        "assert rc == 0, rc\n"
        "heavy = sorted(m for m in sys.modules if m == 'torch' or m.startswith(('torch.', 'torchvision', 'kornia')))\n"
        "print('IMPORTED', heavy)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False,
                          cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert "IMPORTED []" in proc.stdout, proc.stdout
    assert (tmp_path / "photo_overlay.png").is_file() and (tmp_path / "wide_overlay.png").is_file()


# ------------------------------------------------------------------ with a real exported model


@pytest.mark.slow
def test_exported_model_matches_pytorch_on_dataset_images(tiny_dataset, tmp_path):
    """export an untrained HOPE-Net, predict on rendered frames, compare with PyTorch on the reader's inputs."""
    export = pytest.importorskip("hupbench.inference.export")
    import torch

    from hupbench.checkpoint import Checkpoint, load_model
    from hupbench.data import HUPDataset, ReaderConfig
    from hupbench.models.build import build_model

    manifest = json.loads((tiny_dataset / "manifest.json").read_text())
    size = manifest["image_size"][0]  # square frames, and the model input the same size: no resize
    K = np.array(manifest["K"], dtype=np.float64).reshape(3, 3)
    torch.manual_seed(0)
    model = build_model({"name": "hopenet", "backbone": "resnet10"})
    ckpt = Checkpoint(model_config=model.config.saved(), model=model.state_dict(), step=0, input_size=size,
                      K_input=K.tolist(), config={"run_name": "tiny-untrained"},
                      dataset={"path": str(tiny_dataset), "manifest_sha256": "x"}).save(tmp_path / "tiny.pt")
    onnx_path = Path(export.run_export(export.ExportOptions(ckpt, tmp_path / "tiny.onnx", dataset=tiny_dataset,
                                                            parity_frames=2), log=lambda *_: None)["onnx"])
    reader = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=size))
    frames = [reader[i] for i in range(4)]
    paths = sorted((tiny_dataset / "test" / "rgb").iterdir())[:4]
    result = predict(onnx_path, paths, tmp_path / "out")
    assert result["failed"] == 0
    module = export.contract_model(*load_model(ckpt), str(ckpt))
    with torch.no_grad():
        points2d, points3d = module(torch.stack([f["image"] for f in frames]))
    for record, path, p2, p3 in zip(result["records"], paths, points2d.numpy(), points3d.numpy()):
        assert record["run_name"] == "tiny-untrained" and record["camera"] == CAMERA_ASSUMED
        np.testing.assert_allclose(record["K"], K, atol=1e-6)  # a dataset-size image: the training camera itself
        np.testing.assert_allclose(record["keypoints_3d_m"], p3, atol=1e-4)  # 0.1 mm
        np.testing.assert_allclose(record["keypoints_2d_px"], ((p2 + 1.0) * size - 1.0) / 2.0, atol=1e-2)
        overlay = cv2.imread(record["overlay"])
        assert overlay.shape == (size, size, 3)

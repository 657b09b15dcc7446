"""The bad-input and fault matrix of ``hupbench predict`` (docs/robustness.md, section predict).

Run-level refusals (the model, --K, --batch-size, --out, no images at all) answer one error line, exit
1 (2 for argparse's own usage errors) and write nothing into --out; the --K values past its one wiring
case (``UNIT_CASES``) are unit cases of :class:`PredictOptions`: the same line, without running the verb. A bad image is a per-file error:
its own error line naming it, the other images still predicted, exit 1, and predictions.json records
which ones failed. The known-answer ONNX graph of test_predict.py puts keypoint 0 on the most red
pixel, so an accepted odd image (16-bit, grey, RGBA) is checked by where its dot lands.

Also home of the mount-namespace runner the other matrix modules of this package use for a read-only
folder or a small full disk (as root a chmod does not stop a write).
"""

from __future__ import annotations

import json
import shlex
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
from helpers.cli import assert_clean_error, run_cli
from helpers.answers import assert_refusal
from helpers.two_writers import finish, start_writing
from onnx import TensorProto, helper

from hupbench.inference.images import MAX_IMAGE_SIDE, MIN_IMAGE_SIDE
from hupbench.inference.predict import PredictOptions
from hupbench.input_geometry import InputGeometry
from helpers.dot_model import S, contract_metadata, depth_metadata, dot_image, make_dot_model, photo_like, seal
from helpers.faults import run_in_namespace

pytestmark = pytest.mark.matrix


# ------------------------------------------------------------------ a private mount namespace




# ------------------------------------------------------------------ broken models


def _graph_model(path: Path, nodes, inputs, outputs, metadata: dict[str, str]) -> Path:
    model = helper.make_model(helper.make_graph(nodes, "m", inputs, outputs),
                              opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    helper.set_model_props(model, metadata)
    onnx.save(seal(model), path)
    return path


def needs_other_size_model(path: Path) -> Path:
    """Declares (batch, 3, S, S) as its metadata says, but its graph reshapes to (-1, 3 * 2S * 2S): a model
    made for another input size whose input shape and metadata were edited. Fails inside onnxruntime."""
    n = 29
    nodes = [
        helper.make_node("Constant", [], ["shape"], value=helper.make_tensor("s", TensorProto.INT64, [2],
                                                                                 [-1, 3 * (2 * S) ** 2])),
        helper.make_node("Reshape", ["image", "shape"], ["flat"]),
        helper.make_node("ReduceMean", ["flat"], ["mean"], keepdims=1),  # (B, 1)
        helper.make_node("Constant", [], ["pshape2"], value=helper.make_tensor("p2", TensorProto.INT64, [3], [-1, 1, 1])),
        helper.make_node("Reshape", ["mean", "pshape2"], ["m3"]),
        helper.make_node("Constant", [], ["rep2"], value=helper.make_tensor("r2", TensorProto.INT64, [3], [1, n, 2])),
        helper.make_node("Constant", [], ["rep3"], value=helper.make_tensor("r3", TensorProto.INT64, [3], [1, n, 3])),
        helper.make_node("Tile", ["m3", "rep2"], ["points2d"]),
        helper.make_node("Tile", ["m3", "rep3"], ["points3d"]),
    ]
    return _graph_model(path, nodes, [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["batch", 3, S, S])],
                        [helper.make_tensor_value_info("points2d", TensorProto.FLOAT, ["batch", n, 2]),
                         helper.make_tensor_value_info("points3d", TensorProto.FLOAT, ["batch", n, 3])],
                        contract_metadata())


def foreign_graph_model(path: Path, donor: Path) -> Path:
    """Another graph with the dot model's inputs and outputs (constant points), carrying a copy of ``donor``'s
    hupbench metadata, its graph sha256 included: the metadata describe a graph that is not this one."""
    n = 29
    nodes = [
        helper.make_node("Constant", [], ["axes"], value=helper.make_tensor("a", TensorProto.INT64, [3], [1, 2, 3])),
        helper.make_node("ReduceMean", ["image", "axes"], ["m"], keepdims=1),  # (B, 1, 1, 1)
        helper.make_node("Constant", [], ["shape"], value=helper.make_tensor("s", TensorProto.INT64, [3], [-1, 1, 1])),
        helper.make_node("Reshape", ["m", "shape"], ["m3"]),
        helper.make_node("Constant", [], ["c2"], value=helper.make_tensor("c2v", TensorProto.FLOAT, [1, n, 2],
                                                                          [0.1] * (2 * n))),
        helper.make_node("Constant", [], ["c3"], value=helper.make_tensor("c3v", TensorProto.FLOAT, [1, n, 3],
                                                                          [0.5] * (3 * n))),
        helper.make_node("Add", ["m3", "c2"], ["points2d"]),
        helper.make_node("Add", ["m3", "c3"], ["points3d"]),
    ]
    model = helper.make_model(helper.make_graph(
        nodes, "foreign", [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["batch", 3, S, S])],
        [helper.make_tensor_value_info("points2d", TensorProto.FLOAT, ["batch", n, 2]),
         helper.make_tensor_value_info("points3d", TensorProto.FLOAT, ["batch", n, 3])]),
        opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    for entry in onnx.load(str(donor)).metadata_props:
        model.metadata_props.add(key=entry.key, value=entry.value)
    onnx.save(model, path)
    return path


def torch_checkpoint(path: Path) -> Path:
    torch = pytest.importorskip("torch")
    torch.save({"model": {"w": torch.zeros(3)}, "step": 0}, path)
    return path


# ------------------------------------------------------------------ broken images


def png_bytes(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    assert ok
    return buf.tobytes()


def jpeg_bytes(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def declared_huge_png(width: int, height: int) -> bytes:
    """A PNG whose header declares width x height RGB, with the first rows of data only: decoding it would
    allocate width * height * 3 bytes before finding the data short, so it must be refused from its header."""
    rows = zlib.compress((b"\x00" + b"\x40" * (3 * width)) * 4)
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + _png_chunk(b"IDAT", rows) + _png_chunk(b"IEND", b""))


def declared_huge_jpeg(width: int, height: int) -> bytes:
    """A small real JPEG with its frame header (SOF0) edited to declare width x height."""
    data = bytearray(jpeg_bytes(photo_like(64, 48)))
    sof = data.find(b"\xff\xc0")
    assert sof > 0
    data[sof + 5:sof + 9] = struct.pack(">HH", height, width)
    return bytes(data)


def scratched_jpeg(image: np.ndarray) -> bytes:
    """A JPEG with 16 stray bytes before its end marker: libjpeg still decodes the whole image and says
    "Corrupt JPEG data: ... extraneous bytes before marker 0xd9"."""
    data = jpeg_bytes(image)
    return data[:-2] + b"\xab" * 16 + data[-2:]


def red_block(width: int, height: int, centre: tuple[int, int]) -> np.ndarray:
    """Black BGR with a 5 x 5 red square: its centre stays the reddest pixel through JPEG's blur."""
    image = np.zeros((height, width, 3), np.uint8)
    u, v = centre
    image[v - 2:v + 3, u - 2:u + 3] = (0, 0, 255)
    return image


def write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


@pytest.fixture(scope="module")
def dot_model(tmp_path_factory) -> Path:
    return make_dot_model(tmp_path_factory.mktemp("onnx") / "dot.onnx")


@pytest.fixture
def good_image(tmp_path) -> Path:
    path = tmp_path / "in" / "good.png"
    return write(path, png_bytes(dot_image(40, 30, (30, 7))))


def predict_argv(model: Path, inputs: list[Path], out: Path, *extra: str) -> list[str]:
    return ["predict", str(model), *map(str, inputs), "--out", str(out), *extra]


# ------------------------------------------------------------------ run-level refusals

# case id -> (make(tmp_path, dot_model, good_image) -> (model, inputs, extra argv), needles of the error line)
REFUSED = {
    "model-missing": (lambda t, m, g: (t / "none.onnx", [g], []), ("none.onnx", "does not exist")),
    "model-empty": (lambda t, m, g: (write(t / "empty.onnx", b""), [g], []), ("empty.onnx", "empty file")),
    "model-random-bytes": (lambda t, m, g: (write(t / "noise.onnx", np.random.default_rng(1).bytes(4096)), [g], []),
                           ("noise.onnx", "not a readable ONNX model")),
    "model-is-a-folder": (lambda t, m, g: ((t / "dir.onnx").mkdir() or t / "dir.onnx", [g], []),
                          ("dir.onnx", "a folder")),
    "model-without-hupbench-metadata": (lambda t, m, g: (make_dot_model(t / "bare.onnx", metadata={}), [g], []),
                                        ("bare.onnx", "no hupbench metadata", "hupbench export")),
    "model-metadata-bad-json": (
        lambda t, m, g: (make_dot_model(t / "badjson.onnx", contract_metadata(**{"hupbench.K_input": "[[60, 0"})), [g], []),
        ("badjson.onnx", "hupbench.K_input", "not JSON")),
    "model-metadata-input-size-not-a-number": (
        lambda t, m, g: (make_dot_model(t / "size.onnx", contract_metadata(**{"hupbench.input_size": "big"})), [g], []),
        ("size.onnx", "hupbench.input_size", "whole number")),
    "model-metadata-input-size-disagrees-with-graph": (
        lambda t, m, g: (make_dot_model(t / "wrong.onnx", contract_metadata(**{"hupbench.input_size": "64"})), [g], []),
        ("wrong.onnx", "hupbench.input_size", "64", f"{S}")),
    "model-graph-made-for-another-size": (lambda t, m, g: (needs_other_size_model(t / "other.onnx"), [g], []),
                                          ("other.onnx", "onnxruntime", "input size")),
    "model-keypoint-count-disagrees-with-outputs": (
        lambda t, m, g: (make_dot_model(t / "kp.onnx", contract_metadata(**{
            "hupbench.keypoint_names": json.dumps([f"k{i}" for i in range(21)]),
            "hupbench.skeleton_edges": "[[0, 1]]"})), [g], []),
        ("kp.onnx", "21 keypoint names", "29")),
    "model-foreign-graph-with-copied-metadata": (lambda t, m, g: (foreign_graph_model(t / "foreign.onnx", m), [g], []),
                                                 ("foreign.onnx", "metadata were not written for this graph",
                                                  "hupbench export")),
    "model-metadata-without-graph-sha256": (
        lambda t, m, g: (make_dot_model(t / "unsealed.onnx", sealed=False), [g], []),
        ("unsealed.onnx", "no hupbench.graph_sha256", "hupbench export")),
    "model-torch-checkpoint": (lambda t, m, g: (torch_checkpoint(t / "last.pt"), [g], []),
                               ("last.pt", "PyTorch checkpoint", "hupbench export")),
    "folder-without-images": (lambda t, m, g: (m, [write(t / "docs" / "notes.txt", b"x").parent], []),
                              ("no image or video files", "docs")),
    "K-letters": (lambda t, m, g: (m, [g], ["--K", "a,b"]), ("--K", "four numbers")),
    "K-three-values": (lambda t, m, g: (m, [g], ["--K", "480,480,320"]), ("--K", "four numbers")),
    "K-huge": (lambda t, m, g: (m, [g], ["--K", "1e308,1e308,320,240"]), ("--K", "fx", "1e+06")),
    "K-zero-focal": (lambda t, m, g: (m, [g], ["--K", "0,0,320,240"]), ("--K", "fx")),
    "K-negative-focal": (lambda t, m, g: (m, [g], ["--K=-480,480,320,240"]), ("--K", "fx")),
    "K-nan": (lambda t, m, g: (m, [g], ["--K", "nan,480,320,240"]), ("--K", "finite")),
    "K-inf": (lambda t, m, g: (m, [g], ["--K", "480,480,inf,240"]), ("--K", "finite")),
    "batch-size-zero": (lambda t, m, g: (m, [g], ["--batch-size", "0"]), ("--batch-size", ">= 1")),
    "batch-size-negative": (lambda t, m, g: (m, [g], ["--batch-size=-1"]), ("--batch-size", ">= 1")),
    "batch-size-not-an-integer": (lambda t, m, g: (m, [g], ["--batch-size", "2.5"]), ("--batch-size", "2.5")),
    "unknown-option": (lambda t, m, g: (m, [g], ["--overlay-colour", "red"]), ("--overlay-colour",)),
}


#: --K cases checked by :class:`PredictOptions` alone (K-letters wires the option through the CLI)
UNIT_CASES = ("K-three-values", "K-huge", "K-zero-focal", "K-negative-focal", "K-nan", "K-inf")


@pytest.mark.parametrize("case", list(REFUSED))
def test_matrix_predict(case, dot_model, good_image, tmp_path, capsys):
    make, needles = REFUSED[case]
    model, inputs, extra = make(tmp_path, dot_model, good_image)
    out = tmp_path / "out"
    if case in UNIT_CASES:
        K = extra[-1].removeprefix("--K=")
        assert_refusal(lambda: PredictOptions(model, inputs, out, K=K), *needles, prog="hupbench predict")
        return
    answer = run_cli(capsys, *predict_argv(model, inputs, out, *extra))
    assert_clean_error(answer, *needles)
    assert not out.exists(), f"a refused run created {out}: {sorted(out.rglob('*'))}"


@pytest.mark.parametrize("case", ["out-is-a-file", "out-read-only", "out-empty", "out-is-the-input-folder"])
def test_matrix_predict_out(case, dot_model, good_image, tmp_path, capsys, monkeypatch):
    """An --out that cannot take the files, or that would feed this run's overlays to the next: refused before any
    inference, nothing written (``--out ''`` wrote into the current folder; ``--out`` the input folder made the
    next run read the overlays back as images)."""
    if case == "out-empty":
        monkeypatch.chdir(tmp_path)
        answer = run_cli(capsys, *predict_argv(dot_model, [good_image], ""))
        assert_clean_error(answer, "output folder (--out)", "must be a folder path", "''")
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]
    elif case == "out-is-the-input-folder":
        folder = good_image.parent
        answer = run_cli(capsys, *predict_argv(dot_model, [folder], folder))
        assert_clean_error(answer, "--out", str(folder), "is the input folder", "read this run's overlays back")
        assert sorted(p.name for p in folder.iterdir()) == [good_image.name]
        # a folder inside the inputs' is not read back (folders are not searched recursively)
        answer = run_cli(capsys, *predict_argv(dot_model, [folder], folder / "predictions"))
        assert answer.rc == 0 and sorted(p.name for p in folder.iterdir()) == [good_image.name, "predictions"]
    elif case == "out-is-a-file":
        out = write(tmp_path / "results.txt", b"keep me\n")
        answer = run_cli(capsys, *predict_argv(dot_model, [good_image], out))
        assert_clean_error(answer, "--out", "results.txt", "not a folder")
        assert out.read_bytes() == b"keep me\n"
    else:
        out = tmp_path / "locked"
        out.mkdir()
        answer = run_in_namespace(predict_argv(dot_model, [good_image], out), read_only=(out,))
        assert_clean_error(answer, "cannot write", str(out), "read-only")
        assert not list(out.iterdir())


# ------------------------------------------------------------------ per-image errors and odd images accepted

GOOD_DOT = (30, 7)  # where good_image's red dot is, pixels of its 40 x 30


def _odd_images():
    """case id -> (make(folder) -> path, needles of its error line, or None when it must be predicted)."""
    photo = photo_like(80, 60)
    rgba = np.zeros((40, 50, 4), np.uint8)
    rgba[..., 3] = 0  # transparent everywhere ...
    rgba[12, 33] = (0, 0, 255, 255)  # ... but one opaque red pixel
    deep = np.zeros((30, 40, 3), np.uint16)
    deep[20, 11] = (0, 0, 65535)
    return {
        "image-missing": (lambda d: d / "missing.png", ("missing.png", "no such file")),
        "image-empty": (lambda d: write(d / "empty.png", b""), ("empty.png", "empty file")),
        "image-truncated-jpeg": (lambda d: write(d / "cut.jpg", jpeg_bytes(photo)[:900]),
                                 ("cut.jpg", "could not be decoded")),
        "image-truncated-png": (lambda d: write(d / "cut.png", png_bytes(photo)[:2000]),
                                ("cut.png", "could not be decoded")),
        "image-random-bytes": (lambda d: write(d / "noise.png", np.random.default_rng(3).bytes(3000)),
                               ("noise.png", "not a PNG or JPEG")),
        "image-text-file": (lambda d: write(d / "notes.jpg", b"this is text, not a photo\n"),
                            ("notes.jpg", "not a PNG or JPEG")),
        "image-1x1": (lambda d: write(d / "pixel.png", png_bytes(np.zeros((1, 1, 3), np.uint8))),
                      ("pixel.png", "1 x 1", f"at least {MIN_IMAGE_SIDE}")),
        "image-below-minimum-side": (lambda d: write(d / "strip.png", png_bytes(np.zeros((MIN_IMAGE_SIDE - 1, 300, 3), np.uint8))),
                                     ("strip.png", f"300 x {MIN_IMAGE_SIDE - 1}", f"at least {MIN_IMAGE_SIDE}")),
        "image-huge-png-declared": (lambda d: write(d / "huge.png", declared_huge_png(20000, 20000)),
                                    ("huge.png", "20000 x 20000", f"at most {MAX_IMAGE_SIDE}")),
        "image-huge-jpeg-declared": (lambda d: write(d / "huge.jpg", declared_huge_jpeg(30000, 200)),
                                     ("huge.jpg", "30000 x 200", f"at most {MAX_IMAGE_SIDE}")),
        "image-jpeg-data-end-early": (lambda d: write(d / "short.jpg", jpeg_bytes(photo)[:700] + b"\xff\xd9"),
                                      ("short.jpg", "end early", "premature end")),
        "image-jpeg-corrupt-but-whole": (lambda d: write(d / "scratched.jpg", scratched_jpeg(red_block(40, 30, (9, 22)))),
                                         None),
        "image-16bit-png": (lambda d: write(d / "deep.png", png_bytes(deep)), None),
        "image-grayscale": (lambda d: write(d / "grey.png", png_bytes(np.full((30, 50), 90, np.uint8))), None),
        "image-rgba": (lambda d: write(d / "alpha.png", png_bytes(rgba)), None),
        "image-at-minimum-side": (lambda d: write(d / "small.png", png_bytes(dot_image(MIN_IMAGE_SIDE, MIN_IMAGE_SIDE, (3, 12)))),
                                  None),
    }


ODD = _odd_images()
# accepted odd images: where keypoint 0 (the most red pixel) must land, original pixels, and the image size
ACCEPTED = {"image-16bit-png": ((11, 20), (40, 30)), "image-rgba": ((33, 12), (50, 40)),
            "image-at-minimum-side": ((3, 12), (MIN_IMAGE_SIDE, MIN_IMAGE_SIDE)),
            "image-jpeg-corrupt-but-whole": ((9, 22), (40, 30)),
            # no red anywhere: ArgMax takes input pixel (0, 0), in the top padding of a wide image
            "image-grayscale": (None, (50, 30))}


@pytest.mark.parametrize("case", list(ODD))
def test_matrix_predict_image(case, dot_model, good_image, tmp_path, capsys):
    make, needles = ODD[case]
    odd = make(tmp_path / "in")
    out = tmp_path / "out"
    answer = run_cli(capsys, *predict_argv(dot_model, [good_image, odd], out))
    document = json.loads((out / "predictions.json").read_text())
    good, other = document["images"]
    # the good image is always predicted, wherever the odd one fails
    assert good["ok"] and good["path"] == str(good_image)
    g = InputGeometry(40, 30, S)
    assert np.abs(np.array(good["keypoints_2d_px"][0]) - GOOD_DOT).max() <= 0.5 / g.scale + 1e-3
    assert other["path"] == str(odd)
    if needles is not None:
        line = assert_clean_error(answer, *needles)
        assert line.startswith("hupbench predict: error:")
        assert not other["ok"] and other["keypoints_3d_m"] is None and other["error"] in line
        assert document["counts"] == {"images": 2, "ok": 1, "failed": 1}
        assert not list(out.glob(f"{odd.stem}_overlay.png"))
        assert "1 of 2 failed" in answer.out
        return
    assert answer.rc == 0 and "error" not in answer.err, answer
    notes = [line for line in answer.err.splitlines() if "note:" in line]
    if case == "image-jpeg-corrupt-but-whole":  # what libjpeg said, as a note naming the file
        assert len(notes) == 1 and str(odd) in notes[0] and "Corrupt JPEG data" in notes[0], notes
    else:
        assert not notes, notes
    assert other["ok"] and other["error"] is None
    dot, (w, h) = ACCEPTED[case]
    assert other["image_size"] == {"width": w, "height": h}
    g = InputGeometry(w, h, S)
    if dot is None:
        dot = (0.5 / g.scale - 0.5 - g.pad_left, 0.5 / g.scale - 0.5 - g.pad_top)
    assert np.abs(np.array(other["keypoints_2d_px"][0]) - dot).max() <= 0.5 / g.scale + 1e-3, other["keypoints_2d_px"][0]
    assert cv2.imread(other["overlay"]).shape[:2] == (h, w)


@pytest.mark.parametrize("case", ["folder-mixing-good-and-broken-files"])
def test_matrix_predict_folder(case, dot_model, tmp_path, capsys):
    """Good images predicted, every broken one named on its own error line, other files noted, exit 1."""
    d = tmp_path / "photos"
    write(d / "a_good.png", png_bytes(dot_image(40, 30, (30, 7))))
    write(d / "b_empty.jpg", b"")
    write(d / "c_good.jpg", jpeg_bytes(photo_like(64, 48)))
    write(d / "d_cut.png", png_bytes(photo_like(80, 60))[:1500])
    write(d / "e_text.png", b"not a png\n")
    write(d / "notes.txt", b"skipped")
    out = tmp_path / "out"
    answer = run_cli(capsys, "predict", dot_model, d, "--out", out)
    assert answer.rc == 1 and "Traceback" not in answer.err + answer.out
    errors = [line for line in answer.err.splitlines() if "error:" in line]
    assert len(errors) == 3, errors
    for line, (name, why) in zip(errors, [("b_empty.jpg", "empty file"), ("d_cut.png", "could not be decoded"),
                                          ("e_text.png", "not a PNG or JPEG")]):
        assert line.startswith("hupbench predict: error:") and name in line and why in line, line
    assert any("note:" in line and "notes.txt" in line for line in answer.err.splitlines())
    document = json.loads((out / "predictions.json").read_text())
    assert [(Path(r["path"]).name, r["ok"]) for r in document["images"]] == [
        ("a_good.png", True), ("b_empty.jpg", False), ("c_good.jpg", True), ("d_cut.png", False),
        ("e_text.png", False)]
    assert sorted(p.name for p in out.glob("*_overlay.png")) == ["a_good_overlay.png", "c_good_overlay.png"]
    assert "2 image(s) predicted, 3 of 5 failed" in answer.out


# ------------------------------------------------------------------ depth maps of another unit, or none

DEPTH_CASES = {
    # the map's median depth against the training frames' 0.4-0.8 m (accepted: 0.27-1.2 m)
    "depth-all-zero": (lambda d: d * 0, [], ("a.png", "0 everywhere")),
    "depth-ten-times-the-scale": (lambda d: d, ["--depth-scale-m", "1e-3"],
                                  ("a.png", "median depth is 6 m at --depth-scale-m 0.001", "another unit")),
    "depth-in-millimetres": (lambda d: d // 10, [], ("a.png", "median depth is 0.06 m at --depth-scale-m 0.0001",
                                                     "another unit")),
    "depth-in-range": (lambda d: d, [], None),
}


@pytest.mark.parametrize("case", list(DEPTH_CASES))
def test_matrix_predict_depth(case, tmp_path, capsys):
    """A depth map that is 0 everywhere, or whose median lies outside the training frames' by the factor of a unit
    slip (predicted with exit 0 before): that image fails alone, one line naming its depth file."""
    change, extra, needles = DEPTH_CASES[case]
    model = make_dot_model(tmp_path / "rgbd.onnx", depth_metadata((0.4, 0.8)), reads_depth=True)
    image = write(tmp_path / "in" / "a.png", png_bytes(dot_image(40, 30, (30, 7))))
    depth = np.zeros((30, 40), np.uint16)
    depth[5:20, 10:30] = 6000  # 0.6 m in the dataset's 0.1 mm
    (tmp_path / "depth").mkdir()
    cv2.imwrite(str(tmp_path / "depth" / "a.png"), change(depth))
    out = tmp_path / "out"
    answer = run_cli(capsys, *predict_argv(model, [image], out, "--depth", tmp_path / "depth", *extra))
    record = json.loads((out / "predictions.json").read_text())["images"][0]
    if needles is None:
        assert answer.rc == 0 and record["ok"], answer
        return
    line = assert_clean_error(answer, str(tmp_path / "depth" / "a.png"), *needles)
    assert not record["ok"] and record["keypoints_3d_m"] is None and record["error"] in line


def test_matrix_predict_fitting_model_on_another_probes_dataset(tiny_dataset, tmp_path, capsys):
    """A model with probe_fit: depth on the depth maps of a dataset made with another probe's mesh (predicted with
    exit 0 before, the procedural probe fitted to the other probe's surface): refused in one line naming the
    dataset's manifest and its probe; nothing written."""
    metadata = depth_metadata((0.4, 0.8)) | {"hupbench.model_config": json.dumps(
        {"name": "dot", "input_channels": 4, "probe_fit": "depth"})}
    model = make_dot_model(tmp_path / "fit.onnx", metadata, reads_depth=True)
    dataset = tmp_path / "linear_probe_dataset"
    manifest = json.loads((tiny_dataset / "manifest.json").read_text())
    manifest["probe"] = {"kind": "mesh", "path": "/data/probes/linear.stl", "unit": "m", "align": False,
                         "sha256": "0" * 64, "geometry_sha256": "0" * 64}  # as generate probe.mesh=... records it
    write(dataset / "manifest.json", json.dumps(manifest).encode())
    image = write(dataset / "test" / "rgb" / "a.png", png_bytes(dot_image(40, 30, (30, 7))))
    depth = np.zeros((30, 40), np.uint16)
    depth[5:20, 10:30] = 6000
    (dataset / "test" / "depth").mkdir(parents=True)
    cv2.imwrite(str(dataset / "test" / "depth" / "a.png"), depth)
    out = tmp_path / "out"
    answer = run_cli(capsys, *predict_argv(model, [image], out, "--depth", dataset / "test" / "depth"))
    assert_clean_error(answer, str(dataset / "manifest.json"), "linear.stl", "probe fit",
                       "knows only the default procedural probe")
    assert not out.exists()


# ------------------------------------------------------------------ faults


def test_fault_predict_two_runs_at_once(dot_model, tmp_path, capsys):
    """A second predict into the folder a running one writes (measured before: both exited 0, and the
    folder's predictions.json described one run's images beside the other's overlays): refused with one
    line naming the running one; the first completes with all its images."""
    images = [write(tmp_path / "in" / f"photo{k:03d}.png", png_bytes(photo_like(320, 240, seed=k))) for k in range(200)]
    out = tmp_path / "out"
    first = start_writing(predict_argv(dot_model, [tmp_path / "in"], out), out)
    try:
        answer = run_cli(capsys, *predict_argv(dot_model, images[:2], out))
    finally:
        finish(first)
    assert_clean_error(answer, str(out), "in use by another predict run", f"pid {first.pid}")
    document = json.loads((out / "predictions.json").read_text())
    assert document["counts"] == {"images": 200, "ok": 200, "failed": 0}
    assert len(list(out.glob("*_overlay.png"))) == 200 and not list(out.glob(".*"))


def test_fault_predict_second_run_while_the_first_loads_its_model(dot_model, good_image, tmp_path, capsys,
                                                                 monkeypatch):
    """The folder is locked before the model is loaded: a second predict started while the first one is still
    loading is refused (measured before: both exited 0 and the first one's predictions.json was gone)."""
    from hupbench.inference import predict

    out, answers = tmp_path / "out", []
    load = predict.load_onnx_model

    def load_while_another_starts(path, *args, **kwargs):
        if not answers:  # the first run: a second one starts now, into the same folder
            answers.append(run_cli(capsys, *predict_argv(dot_model, [good_image], out)))
        return load(path, *args, **kwargs)

    monkeypatch.setattr(predict, "load_onnx_model", load_while_another_starts)
    first = run_cli(capsys, *predict_argv(dot_model, [good_image], out))
    assert_clean_error(answers[0], str(out), "in use by another predict run")
    assert first.rc == 0, first
    assert json.loads((out / "predictions.json").read_text())["counts"] == {"images": 1, "ok": 1, "failed": 0}


def test_fault_predict_disk_full(dot_model, tmp_path):
    """A disk that fills up while the overlays are written: one line naming the disk and the file, exit 1;
    no predictions.json (an earlier run's is removed when this run starts writing), none of this run's
    overlays, no temporary file."""
    images = [write(tmp_path / "in" / f"photo{k}.png", png_bytes(photo_like(400, 300, seed=k))) for k in range(6)]
    out, listing = tmp_path / "out", tmp_path / "listing.txt"
    old = write(tmp_path / "old.json", b'{"counts": {"images": 9}}\n')
    answer = run_in_namespace(predict_argv(dot_model, images, out), tmpfs=(out, 600), listing=listing,
                              setup=f"cp {shlex.quote(str(old))} {shlex.quote(str(out / 'predictions.json'))}"
                                    f" && cp {shlex.quote(str(old))} {shlex.quote(str(out / 'keep.txt'))}")
    line = assert_clean_error(answer, "no space left on", str(out), "_overlay.png")
    assert line.startswith("hupbench predict: error: no space left on")
    left = sorted(row.split()[0] for row in listing.read_text().splitlines())
    assert left == ["keep.txt"], f"a full disk left {left}"


def test_fault_predict_disk_full_at_the_json(dot_model, tmp_path):
    """--no-overlay on a disk with room for nothing: the JSON itself fails; nothing is left."""
    images = [write(tmp_path / "in" / f"p{k}.png", png_bytes(dot_image(40, 30, (k % 40, k % 30)))) for k in range(300)]
    out, listing = tmp_path / "out", tmp_path / "listing.txt"
    answer = run_in_namespace(predict_argv(dot_model, images, out, "--no-overlay"), tmpfs=(out, 8), listing=listing)
    assert_clean_error(answer, "no space left on", "predictions.json")
    assert listing.read_text() == ""


@pytest.mark.parametrize("stdout", ["full", "closed"])
def test_matrix_predict_stdout_full_or_closed(stdout, dot_model, tmp_path):
    """predict's report on a closed pipe (``| head -1``) is dropped: the predictions are written and predict exits
    0 (it exited 1 with a traceback although its results were written); on a full standard output
    (``> /dev/full``) the predictions are written too, and the lost report is one line with exit 1."""
    import sys

    from helpers.answers import record_answer
    from helpers.cli import run_with_stdout

    images = tmp_path / "in"
    images.mkdir()
    cv2.imwrite(str(images / "a.png"), dot_image(S, S, (S // 3, S // 2)))
    done = run_with_stdout([sys.executable, "-m", "hupbench.cli", "predict", str(dot_model), str(images / "a.png"),
                            "--out", str(tmp_path / "out")], stdout, timeout=300)
    predictions = json.loads((tmp_path / "out" / "predictions.json").read_text())
    assert predictions["counts"] == {"images": 1, "ok": 1, "failed": 0}
    if stdout == "closed":
        assert done.rc == 0 and done.err == "", done.err
        return
    lines = done.err.strip().splitlines()
    assert done.rc == 1 and len(lines) == 1, done.err
    assert lines[0].startswith("hupbench predict: error: cannot write to standard output"), lines
    record_answer(lines[0])

"""hupbench predict on videos: every frame in order, an overlay video OpenCV reads back, and one line for a
video that cannot be read or is cut short. The known-answer dot graph (tests/helpers/dot_model.py) finds a red
dot that moves across the frames."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.dot_model import S, depth_metadata, make_dot_model

from hupbench.cli import main
from hupbench.core.errors import BadValueError
from hupbench.inference.predict import PredictOptions, run_predict
from hupbench.input_geometry import InputGeometry

W, H, FRAMES, FPS = 64, 48, 10, 25.0


def _dot_uv(i: int) -> tuple[int, int]:
    return 6 + 5 * i, 10 + 2 * i


def write_video(path: Path, frames: int = FRAMES, fourcc: str = "FFV1") -> Path:
    """A lossless video of a 3 x 3 red dot moving right and down, one step per frame."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), FPS, (W, H))
    assert writer.isOpened()
    for i in range(frames):
        image = np.zeros((H, W, 3), np.uint8)
        u, v = _dot_uv(i)
        image[v - 1:v + 2, u - 1:u + 2] = (0, 0, 255)
        writer.write(image)
    writer.release()
    return path


@pytest.fixture(scope="module")
def dot_model(tmp_path_factory) -> Path:
    return make_dot_model(tmp_path_factory.mktemp("onnx") / "dot.onnx")


def test_a_ten_frame_video_gives_ten_poses_in_order_and_an_overlay_video(dot_model, tmp_path):
    video = write_video(tmp_path / "scan.mkv")
    result = run_predict(PredictOptions(dot_model, [video], tmp_path / "out", batch_size=4), log=lambda line: None)
    document = json.loads((tmp_path / "out" / "predictions.json").read_text())
    frames = [r for r in document["images"] if r["path"] == str(video)]
    assert [r["frame"] for r in frames] == list(range(FRAMES)) and all(r["ok"] for r in frames)
    np.testing.assert_allclose([r["time_s"] for r in frames], np.arange(FRAMES) / FPS)
    half_input_pixel = 0.5 / InputGeometry(W, H, S).scale
    for i, record in enumerate(frames):  # the graph's wrist lands on the dot's pixel, frame by frame
        assert np.abs(np.array(record["keypoints_2d_px"][0]) - _dot_uv(i)).max() <= half_input_pixel + 1.0
    (summary,) = document["videos"]
    assert summary == {"path": str(video), "fps": FPS, "frames": FRAMES, "frames_declared": FRAMES, "ok": True,
                       "error": None, "overlay": str(tmp_path / "out" / "scan_overlay.mp4")}
    assert result["overlays"] == [tmp_path / "out" / "scan_overlay.mp4"]
    reader = cv2.VideoCapture(summary["overlay"])
    assert reader.isOpened() and reader.get(cv2.CAP_PROP_FPS) == pytest.approx(FPS)
    read = []
    while True:
        ok, frame = reader.read()
        if not ok:
            break
        read.append(frame)
    assert len(read) == FRAMES and read[0].shape == (H, W, 3)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["predictions.json", "scan_overlay.mp4"]


def test_videos_and_images_keep_the_inputs_order(dot_model, tmp_path):
    video = write_video(tmp_path / "a.avi", frames=3)
    image = tmp_path / "b.png"
    cv2.imwrite(str(image), np.zeros((40, 40, 3), np.uint8))
    result = run_predict(PredictOptions(dot_model, [image, video, image], tmp_path / "out", overlay=False),
                         log=lambda line: None)
    assert [(Path(r["path"]).name, r["frame"]) for r in result["records"]] == [
        ("b.png", None), ("a.avi", 0), ("a.avi", 1), ("a.avi", 2), ("b.png", None)]


def test_an_unreadable_video_fails_alone_in_one_line(dot_model, tmp_path, capsys):
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    good = write_video(tmp_path / "good.mkv", frames=2)
    rc = main(["predict", str(dot_model), str(broken), str(good), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "broken.mp4" in line]
    assert rc == 1 and len(lines) == 1 and "not a readable video" in lines[0], err
    document = json.loads((tmp_path / "out" / "predictions.json").read_text())
    assert [v["ok"] for v in document["videos"]] == [False, True]
    assert len(document["images"]) == 2 and not (tmp_path / "out" / "broken_overlay.mp4").exists()


def test_a_truncated_video_keeps_what_decodes_and_says_what_is_missing(dot_model, tmp_path, capsys):
    """A Matroska file cut in half: its header still declares 10 frames, 3 of them decode (an AVI or MP4 cut so
    keeps no index and is refused as unreadable, the test above)."""
    video = write_video(tmp_path / "cut.mkv", frames=FRAMES)
    data = video.read_bytes()
    video.write_bytes(data[:len(data) // 2])
    rc = main(["predict", str(dot_model), str(video), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "cut.mkv" in line]
    assert rc == 1 and len(lines) == 1 and "truncated" in lines[0] and f"of the {FRAMES} frames" in lines[0], err
    (summary,) = json.loads((tmp_path / "out" / "predictions.json").read_text())["videos"]
    assert 0 < summary["frames"] < FRAMES and summary["ok"] is False


def test_a_model_that_reads_depth_refuses_a_video(tmp_path):
    model = make_dot_model(tmp_path / "depth.onnx", depth_metadata(), reads_depth=True)
    video = write_video(tmp_path / "scan.mkv", frames=2)
    (tmp_path / "depth").mkdir()
    with pytest.raises(BadValueError, match="scan.mkv is a video, which holds no depth maps"):
        run_predict(PredictOptions(model, [video], tmp_path / "out", depth_dir=tmp_path / "depth"))


def test_tracking_carries_the_filter_from_frame_to_frame(dot_model, tmp_path):
    """--track: each frame's 3D keypoints are the 1-euro filter of the per-frame predictions so far (kept under
    "untracked"), its 2D their projection; the first frame passes as it is; a still image is not tracked."""
    from hupbench.inference.tracking import parse_track
    from hupbench.inference.tracking import OneEuroFilter

    video = write_video(tmp_path / "scan.mkv")
    still = tmp_path / "still.png"
    cv2.imwrite(str(still), np.zeros((H, W, 3), np.uint8))
    settings = {"min_cutoff_hz": 0.5, "beta": 0.0}
    run_predict(PredictOptions(dot_model, [video, still], tmp_path / "out", batch_size=3, track="0.5,0"),
                log=lambda line: None)
    document = json.loads((tmp_path / "out" / "predictions.json").read_text())
    frames = [r for r in document["images"] if r["path"] == str(video)]
    assert all(r["tracking"] == {"filter": "1-euro", **settings} for r in frames)
    smoother = OneEuroFilter(**settings)
    for record in frames:
        want = smoother(np.array(record["untracked"]["keypoints_3d_m"]), record["time_s"])
        np.testing.assert_allclose(record["keypoints_3d_m"], want, atol=1e-6)
        K = np.array(record["K"])
        uv = want[:, :2] / want[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
        np.testing.assert_allclose(record["keypoints_2d_px"], uv, atol=2e-3)
    assert frames[0]["keypoints_3d_m"] == frames[0]["untracked"]["keypoints_3d_m"]
    # the dot moves: the filter lags behind it
    assert np.abs(np.array(frames[-1]["keypoints_3d_m"]) - frames[-1]["untracked"]["keypoints_3d_m"]).max() > 1e-4
    (image,) = [r for r in document["images"] if r["path"] == str(still)]
    assert "tracking" not in image and "untracked" not in image
    assert parse_track({"min_cutoff_hz": 2, "beta": 1}) == {"min_cutoff_hz": 2.0, "beta": 1.0}
    for bad in ("1", "a,b", "0,1", "1,-1"):
        with pytest.raises(BadValueError, match="--track"):
            PredictOptions(dot_model, [video], tmp_path / "bad", track=bad)

"""hupbench predict on a folder of ordered frames with depth (--track with --fps): the frames are one sequence, their
fits started where they left the frame before and their keypoints through the 1-euro filter, as eval tracks a clip;
frames whose names' numbers disagree with name order, and --fps without what it needs, are refused in one line."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers.cli import assert_clean_error, run_cli
from helpers.models import fitting_onnx
from hupbench.core.errors import BadValueError
from hupbench.data import HUPDataset, ReaderConfig
from hupbench.inference.predict import PredictOptions, run_predict

FPS = 30.0


@pytest.fixture(scope="module")
def fitting(tmp_path_factory, tiny_dataset):
    """(onnx, frames folder, depth folder) of an untrained model with both fits that recalls the first test frame's
    truth (so that both fits find their points), and 4 test frames renamed frame_08 ... frame_11 with their depth."""
    folder = tmp_path_factory.mktemp("frames")
    onnx_path = fitting_onnx(folder, tiny_dataset)
    frames, depth = folder / "rgb", folder / "depth"
    frames.mkdir()
    depth.mkdir()
    for k, rgb in enumerate(sorted((tiny_dataset / "test" / "rgb").iterdir())[:4]):
        shutil.copy(rgb, frames / f"frame_{k + 8:02d}.png")
        shutil.copy(tiny_dataset / "test" / "depth" / f"{rgb.stem}.png", depth / f"frame_{k + 8:02d}.png")
    return onnx_path, frames, depth


def test_ordered_frames_are_tracked_with_the_fits_started_at_the_frame_before(fitting, tiny_dataset, tmp_path):
    from hupbench.fits import after_network, track_fits
    from hupbench.inference.runtime import load_onnx_model, run_onnx_outputs
    from hupbench.inference.tracking import OneEuroFilter

    onnx_path, frames, depth = fitting
    result = run_predict(PredictOptions(onnx_path, [frames], tmp_path / "out", depth_dir=depth, batch_size=3,
                                        track="1,0", fps=FPS), log=lambda *_: None)
    records = result["records"]
    assert [r["frame"] for r in records] == [0, 1, 2, 3] and result["failed"] == 0
    assert [r["time_s"] for r in records] == pytest.approx([k / FPS for k in range(4)], abs=1e-6)
    assert [Path(r["path"]).name for r in records] == [f"frame_{k:02d}.png" for k in range(8, 12)]
    assert all(r["tracking"] == {"filter": "1-euro", "min_cutoff_hz": 1.0, "beta": 0.0} for r in records)
    assert all(Path(r["overlay"]).is_file() for r in records)

    # the same frames at the model input, as eval reads them (the dataset's first 4 test frames)
    model = load_onnx_model(onnx_path)
    reader = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=64, input_modalities="rgb+depth"))
    batch = np.stack([reader[i]["image"].numpy() for i in range(4)])
    out = run_onnx_outputs(model, batch[:, :3], batch[:, 3:])
    start, chained = None, []
    smoother = OneEuroFilter(min_cutoff_hz=1.0, beta=0.0)
    for k, record in enumerate(records):
        _, p3, start = track_fits(model.model_config, out["points2d"][k:k + 1], out["points3d"][k:k + 1],
                                  batch[k:k + 1], model.K_input, start, fitted=model.fit_probe,
                                  segmentation=out.get("segmentation"))
        chained.append(p3[0])
        np.testing.assert_allclose(record["untracked"]["keypoints_3d_m"], p3[0], atol=1e-4)
        np.testing.assert_allclose(record["keypoints_3d_m"], smoother(p3[0], record["time_s"]), atol=2e-6)
    alone = after_network(model.model_config, out["points2d"], out["points3d"], batch, model.K_input,
                          fitted=model.fit_probe)[1]
    assert np.abs(np.array(chained) - alone).max() > 1e-3, "the tracked fits are not each frame's alone"


def test_frames_out_of_their_numbers_order_and_a_lone_fps_are_refused(fitting, tmp_path, capsys):
    onnx_path, frames, depth = fitting
    shuffled, shuffled_depth = tmp_path / "shuffled", tmp_path / "shuffled_depth"
    shuffled.mkdir()
    shuffled_depth.mkdir()
    for name in ("f_2.png", "f_10.png"):
        shutil.copy(frames / "frame_08.png", shuffled / name)
        shutil.copy(depth / "frame_08.png", shuffled_depth / name)
    with pytest.raises(BadValueError, match=r"f_10.png comes before .*f_2.png in name order.*zero-padded"):
        run_predict(PredictOptions(onnx_path, [shuffled], tmp_path / "out", depth_dir=shuffled_depth, track="1,0",
                                   fps=FPS))
    assert not (tmp_path / "out").exists()
    # untracked, the same folder is read in name order as before
    assert run_predict(PredictOptions(onnx_path, [shuffled], tmp_path / "plain", depth_dir=shuffled_depth,
                                      overlay=False), log=lambda *_: None)["ok"] == 2
    with pytest.raises(BadValueError, match="--fps .* give --track too"):
        PredictOptions(onnx_path, [frames], tmp_path / "o", fps=FPS)
    for bad in (0.0, -30.0, float("nan")):
        with pytest.raises(BadValueError, match="--fps"):
            PredictOptions(onnx_path, [frames], tmp_path / "o", track="1,0", fps=bad)
    proc = run_cli(capsys, "predict", str(onnx_path), str(frames), "--depth", str(depth), "--fps", "30",
                   "--out", str(tmp_path / "cli"))
    assert_clean_error(proc, "--fps")

"""hupbench eval on a split of clips: the model is run over val too, the tracking filter chosen there, and the
results carry the sequence block (untracked and tracked, with intervals) in the table and the JSON."""

from __future__ import annotations

import numpy as np
import pytest

from helpers.datasets import CLINIC_SPLITS, CLIPS_PER_GRASP
from hupbench.evaluation import evaluate as EV
from hupbench.evaluation.prediction import SplitPrediction
from hupbench.evaluation.results import load_results
from hupbench.evaluation.sequence_metrics import SCORES

NOISE_M = 0.004


def _noisy_truth(calls):
    """predict_split's stand-in: the split's labels plus seeded white noise, recording which splits ran."""
    real = EV.predict_split

    def predict(net, reader, batch_size, **kwargs):
        out = real(net, reader, batch_size, **kwargs)
        calls.append(reader.split)
        rng = np.random.default_rng(len(calls))
        return SplitPrediction(out.rows, out.labels2d, out.labels3d + rng.normal(0.0, NOISE_M, out.labels3d.shape),
                               out.labels2d, out.labels3d, out.images, out.seconds, out.segmentation)

    return predict


def test_eval_on_clips_chooses_the_filter_on_val_and_scores_both(exported, tiny_clips, tmp_path, monkeypatch):
    ckpt, _ = exported
    calls = []
    monkeypatch.setattr(EV, "predict_split", _noisy_truth(calls))
    lines = []
    answer = EV.run_eval(EV.EvalOptions(ckpt, tiny_clips, out=tmp_path / "clips.json", latency=False,
                                        interval_resamples=500), log=lines.append)
    assert calls == ["test", "val"]
    block = load_results(tmp_path / "clips.json")["sequence"]
    assert block == answer["results"]["sequence"]
    assert block["clips"] == CLINIC_SPLITS["test"] * CLIPS_PER_GRASP and block["filter"]["chosen_on"] == "val"
    assert set(block["untracked"]) == set(SCORES) == set(block["tracked"])
    # 4 mm of white noise per axis: tracking chosen on val smooths it on test
    assert block["filter"]["settings"] is not None
    assert block["tracked"]["acceleration_error_mm_per_frame2"] < block["untracked"]["acceleration_error_mm_per_frame2"]
    assert block["tracked"]["jitter_mm_per_s3"] < block["untracked"]["jitter_mm_per_s3"]
    assert any(line.startswith("test tracking: 1-euro") for line in lines)
    assert "acceleration_error_mm_per_frame2, untracked -> tracked" in answer["table"]


def test_eval_on_the_val_split_of_clips_tunes_on_itself(exported, tiny_clips, tmp_path, monkeypatch):
    ckpt, _ = exported
    calls = []
    monkeypatch.setattr(EV, "predict_split", _noisy_truth(calls))
    answer = EV.run_eval(EV.EvalOptions(ckpt, tiny_clips, split="val", out=tmp_path / "val.json", latency=False,
                                        interval_resamples=200), log=lambda *_: None)
    assert calls == ["val"]
    assert answer["results"]["sequence"]["filter"]["chosen_on"] == "val"


def test_a_dataset_of_single_frames_has_no_sequence_block(exported, tiny_dataset, tmp_path):
    ckpt, _ = exported
    results = EV.run_eval(EV.EvalOptions(ckpt, tiny_dataset, out=tmp_path / "frames.json", latency=False,
                                         interval_resamples=100), log=lambda *_: None)["results"]
    assert "sequence" not in results
    with pytest.raises(KeyError):
        load_results(tmp_path / "frames.json")["sequence"]


def test_the_tracked_fits_carry_the_probe_within_a_clip_across_batches_and_start_afresh_at_each_clip():
    """predict_split with the frames' clips: the fits run frame by frame, each frame started at the pose the frame
    before left (across the network's batches), none at a clip's first frame; a model without fits tracks with
    the filter alone (its tracked prediction is the network's)."""
    import torch

    from hupbench.core import keypoints as kp
    from hupbench.evaluation.prediction import NetworkOutput, predict_split

    class Frames(torch.utils.data.Dataset):
        split = "val"

        def __len__(self):
            return 7

        def __getitem__(self, i):
            return {"image": torch.full((4, 2, 2), float(i)), "keypoints_2d": torch.zeros(kp.NUM_KEYPOINTS, 2),
                    "keypoints_3d": torch.zeros(kp.NUM_KEYPOINTS, 3)}

    class Net:
        format, fits = "fake", True

        def __init__(self):
            self.starts = []

        def network(self, images):
            frame = images[:, 0, 0, 0].double().numpy()[:, None, None]
            return NetworkOutput(np.zeros((len(frame), kp.NUM_KEYPOINTS, 2)) + frame,
                                 np.zeros((len(frame), kp.NUM_KEYPOINTS, 3)) + frame)

        def after_network(self, images, output):
            return output.points2d, output.points3d

        def predict(self, images):
            return self.after_network(images.numpy(), self.network(images))

        def track_fits(self, images, output, probe_start):
            frame = float(images[0, 0, 0, 0])
            self.starts.append(None if probe_start is None else float(probe_start[0, 0, 0]))
            return output.points2d, output.points3d + 1.0, np.full((1, 4, 4), frame)

    net = Net()
    clips = np.array([5, 5, 5, 9, 9, 9, 9])
    out = predict_split(net, Frames(), 2, clips=clips)
    assert net.starts == [None, 0.0, 1.0, None, 3.0, 4.0, 5.0]
    np.testing.assert_array_equal(out.tracked3d, out.points3d + 1.0)
    assert out.tracked_fits_ms is not None and out.tracked_fits_ms >= 0
    net.fits = False
    plain = predict_split(net, Frames(), 3, clips=clips)
    np.testing.assert_array_equal(plain.tracked3d, plain.points3d)
    assert plain.tracked_fits_ms is None
    assert predict_split(net, Frames(), 3).tracked3d is None

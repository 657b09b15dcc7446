"""A model's predictions over a dataset split: the one loop that eval and the diagnosis scripts share.

:class:`EvalModel` opens a checkpoint or an exported ONNX model behind one interface (a checkpoint runs through
:class:`hupbench.inference.export.ContractModule`, the wrapper the ONNX export uses, so both formats predict the
same quantities); :func:`predict_split` runs it over a split's frames as :class:`hupbench.data.HUPDataset` reads
them at the model's input, with the fits after the network (:mod:`hupbench.fits`) where the model asks for them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from hupbench.core.errors import BadValueError, RunFailedError
from hupbench.fits import after_network, fits, model_fit_settings, track_fits
from hupbench.inference.runtime import load_onnx_model, run_onnx_outputs, split_model_images
from hupbench.input_geometry import INPUT_MODALITIES

__all__ = ["EvalModel", "NetworkOutput", "SplitPrediction", "evenly_spaced", "onnx_network_output", "predict_split",
           "split_reader"]


class NetworkOutput(NamedTuple):
    """What a model's network gives for a batch, float64 numpy: ``points2d`` (B, 29, 2) normalised, ``points3d``
    (B, 29, 3) metres (camera of ``K_input``), and for a model with a segmentation head each input pixel's class
    ``segmentation`` (B, S, S) int64 (:data:`hupbench.core.contract.SEGMENT_CLASSES`), else None."""

    points2d: np.ndarray
    points3d: np.ndarray
    segmentation: np.ndarray | None = None


class EvalModel:
    """The model under evaluation, in either format: its name, sizes, camera, a batch predictor.

    Attributes:
        path: the model file. format: "pytorch" (a checkpoint) or "onnx".
        payload: the checkpoint's record (:meth:`hupbench.checkpoint.Checkpoint.record`), None for ONNX.
        module: the checkpoint's :class:`hupbench.inference.export.ContractModule`, None for ONNX.
        onnx: the :class:`hupbench.inference.runtime.OnnxModel`, None for a checkpoint.
        model_config: the architecture's saved config. input_size: S, pixels. input_modalities: "rgb" or
            "rgb+depth". K_input: (3, 3) float64 intrinsics of the model input, pixels (the camera of the 3D
            output). run_name: the training run's name as a run name (:func:`hupbench.provenance.default_run_name`).
        fit_probe: the probe the fits know (:class:`hupbench.fits.known_probe.FitProbe`: an ONNX file's, a
            checkpoint's training dataset's, :func:`hupbench.inference.export.trained_fit_probe`); None: the default
            procedural probe (a file without one, a model without fits).
    """

    def __init__(self, path: Path) -> None:
        from hupbench.checkpoint import load_model
        from hupbench.inference.export import check_keypoint_count, contract_model, trained_fit_probe
        from hupbench.provenance import default_run_name

        self.path = Path(path)
        if self.path.suffix.lower() == ".onnx":
            self.format, self.payload, self.module = "onnx", None, None
            self.onnx = load_onnx_model(self.path, torch.get_num_threads())
            check_keypoint_count(len(self.onnx.keypoint_names), str(path))
            if not self.onnx.model_config:  # eval rebuilds the architecture to count its parameters and FLOPs
                raise BadValueError(f"{path} lacks metadata hupbench.model_config, which eval needs for the model's "
                                    "cost")
            self.model_config, self.input_size = self.onnx.model_config, self.onnx.input_size
            self.input_modalities = self.onnx.input_modalities
            self.K_input = self.onnx.K_input
            self.run_name = default_run_name(self.onnx.run_name, self.path)
            self.fit_probe, self.fit_settings = self.onnx.fit_probe, self.onnx.fit_settings
            return
        model, payload = load_model(self.path)
        self.format, self.payload, self.onnx = "pytorch", payload, None
        # channels_last, as training runs: the same outputs, and at batch 1 1.64x onnxruntime's time against 2.24x in
        # the default layout (benchmarks/latency.py on paper_hupnet_seg_cpu, 2-core AMD EPYC; README "The leaderboard")
        self.module = contract_model(model, payload, str(path)).to(memory_format=torch.channels_last)
        self.model_config = dict(payload["model_config"])
        self.input_size = self.module.input_size
        self.input_modalities = self.module.input_modalities
        self.K_input = np.asarray(payload["K_input"], dtype=np.float64)
        self.run_name = default_run_name((payload.get("config") or {}).get("run_name"), self.path)
        self.fit_probe = trained_fit_probe(payload)
        #: (probe, hand) the settings the model's fits run with, read once (:func:`hupbench.fits.model_fit_settings`)
        self.fit_settings = model_fit_settings(self.model_config)

    @property
    def fits(self) -> bool:
        """Whether the model's config asks for a fit after the network (:func:`hupbench.fits.fits`)."""
        return bool(fits(self.model_config))

    @property
    def channels(self) -> int:
        """C, channels of the model images (3 RGB, 4 with depth)."""
        return INPUT_MODALITIES[self.input_modalities]

    def after_network(self, images: np.ndarray, outputs: NetworkOutput) -> tuple[np.ndarray, np.ndarray]:
        """What runs on the network's outputs for (B, C, S, S) model images: the fits to the depth input the model
        asks for (:func:`hupbench.fits.after_network`, reading its segmentation where it has one), else nothing;
        (points2d, points3d) float64."""
        return after_network(self.model_config, outputs.points2d, outputs.points3d, images, self.K_input,
                             *self.fit_settings, fitted=self.fit_probe, segmentation=outputs.segmentation)

    def track_fits(self, images: np.ndarray, outputs: NetworkOutput, probe_start: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """:meth:`after_network` on frames of a clip, the probe's pose carried from the frame before
        (:func:`hupbench.fits.track_fits`): (points2d, points3d, the next frame's ``probe_start``)."""
        return track_fits(self.model_config, outputs.points2d, outputs.points3d, images, self.K_input, probe_start,
                          *self.fit_settings, fitted=self.fit_probe, segmentation=outputs.segmentation)

    def network(self, images: torch.Tensor) -> NetworkOutput:
        """(B, C, S, S) float32 model images -> the network's :class:`NetworkOutput`, without the fits."""
        if self.module is None:
            return onnx_network_output(self.onnx, images.numpy())
        with torch.inference_mode():
            out = dict(zip(self.module.outputs, self.module(images.contiguous(memory_format=torch.channels_last))))
        return _network_output({name: value.numpy() for name, value in out.items()})

    def predict(self, images: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`network`'s output, and the fits to the depth input after it where the model asks for them."""
        return self.after_network(images.numpy(), self.network(images))


def onnx_network_output(model, images: np.ndarray) -> NetworkOutput:
    """The :class:`NetworkOutput` of an :class:`hupbench.inference.runtime.OnnxModel` on (B, C, S, S) float32 model
    images."""
    return _network_output(run_onnx_outputs(model, *split_model_images(images)))


def _network_output(out: dict[str, np.ndarray]) -> NetworkOutput:
    segmentation = out.get("segmentation")
    return NetworkOutput(out["points2d"].astype(np.float64), out["points3d"].astype(np.float64),
                         None if segmentation is None else segmentation.astype(np.int64))


@dataclass(frozen=True)
class SplitPrediction:
    """Predictions and labels of frames of one split, in the order of ``rows``.

    Attributes:
        rows: (F,) int64 indices of the frames in the split's reader.
        points2d: (F, 29, 2) float64, normalised input coordinates; points3d: (F, 29, 3) float64, metres,
            OpenCV camera frame of the model's ``K_input``: the predictions.
        labels2d, labels3d: the same of the labels, as the reader gives them at the model input.
        images: the (B, C, S, S) float32 model images of each batch, in order, when asked for; else None.
        seconds: wall time of the pass.
        segmentation: with the images of the network alone (``with_fits`` False), a segmenting model's (F, S, S)
            int64 classes of each input pixel (what its fits read, :class:`NetworkOutput`); else None.
        tracked2d, tracked3d: given the frames' clips, the predictions with the fits tracking each clip frame by frame
            (:meth:`EvalModel.track_fits`; the network's output for a model without fits); else None.
        tracked_fits_ms: the median time of the tracked fits per frame, ms; None without clips or fits.
    """

    rows: np.ndarray
    points2d: np.ndarray
    points3d: np.ndarray
    labels2d: np.ndarray
    labels3d: np.ndarray
    images: list[np.ndarray] | None
    seconds: float
    segmentation: np.ndarray | None = None
    tracked2d: np.ndarray | None = None
    tracked3d: np.ndarray | None = None
    tracked_fits_ms: float | None = None


def split_reader(dataset: Path, split: str, net: EvalModel, depth_sensor: str = "dataset"):
    """The :class:`hupbench.data.HUPDataset` of a split at the model's input size and modalities, a depth-reading
    model reading ``depth_sensor``'s depth (``data.reader.depth_sensor``)."""
    from hupbench.data import HUPDataset, ReaderConfig

    return HUPDataset(dataset, split, ReaderConfig(input_size=net.input_size, input_modalities=net.input_modalities,
                                                   depth_sensor=depth_sensor))


def evenly_spaced(total: int, frames: int) -> np.ndarray:
    """(F,) int64 indices of ``frames`` frames spread evenly over ``total`` (all of them for 0 or >= total)."""
    if not frames or frames >= total:
        return np.arange(total)
    return np.linspace(0, total - 1, frames).round().astype(np.int64)


def predict_split(net: EvalModel, reader, batch_size: int, rows: Sequence[int] | None = None, with_fits: bool = True,
                  keep_images: bool = False, progress: bool = False,
                  log: Callable[[str], None] | None = None, clips: np.ndarray | None = None) -> SplitPrediction:
    """Run a model over frames of a split, batched, in order.

    Args:
        net: the model. reader: the split's reader (:func:`split_reader`). batch_size: frames per forward pass.
        rows: indices of the frames to run (default: all, in order).
        with_fits: run the fits after the network where the model asks for them (eval); False: the network alone.
        keep_images: keep each batch's model images (and a segmenting model's segmentation) in the result (for
            fits run afterwards).
        progress: a progress bar on a terminal. log: receives one line with the pass's time, when given.
        clips: (F,) the clip of each frame of ``rows`` (a split of clips, whose frames follow each other in order):
            the fits also run tracking each clip (:attr:`SplitPrediction.tracked3d`).

    Returns:
        :class:`SplitPrediction`.

    Raises:
        RunFailedError: the model's output is NaN or inf on some frame.
    """
    from tqdm import tqdm

    rows = np.arange(len(reader)) if rows is None else np.asarray(rows, dtype=np.int64)
    frames = torch.utils.data.Subset(reader, rows.tolist())
    loader = torch.utils.data.DataLoader(frames, batch_size=batch_size, shuffle=False, num_workers=0)
    pred2d, pred3d, gt2d, gt3d, images, segmentation = [], [], [], [], [], []
    tracked2d, tracked3d, fit_seconds, probe_start, clip_before = [], [], [], None, None
    track = clips is not None and net.fits
    start = time.perf_counter()
    for batch in tqdm(loader, unit="batch", desc=f"predict {reader.split}", dynamic_ncols=True, leave=False,
                      disable=None if progress else True):  # None: only on a terminal
        if track:   # the network's output kept for the tracked fits
            output = net.network(batch["image"])
            seg = None if with_fits else output.segmentation
            p2, p3 = net.after_network(batch["image"].numpy(), output) if with_fits else output[:2]
        elif with_fits:
            (p2, p3), seg = net.predict(batch["image"]), None
        else:
            p2, p3, seg = net.network(batch["image"])
        if track:   # frame by frame, the probe's pose carried within a clip
            for i, frame in enumerate(batch["image"].numpy()):
                clip = clips[len(fit_seconds)]
                if clip != clip_before:
                    probe_start, clip_before = None, clip
                begun = time.perf_counter()
                t2, t3, probe_start = net.track_fits(frame[None], NetworkOutput(*(
                    None if v is None else v[i:i + 1] for v in output)), probe_start)
                fit_seconds.append(time.perf_counter() - begun)
                tracked2d.append(t2)
                tracked3d.append(t3)
        pred2d.append(p2)
        pred3d.append(p3)
        gt2d.append(batch["keypoints_2d"].double().numpy())
        gt3d.append(batch["keypoints_3d"].double().numpy())
        if keep_images:
            images.append(batch["image"].numpy())
            if seg is not None:
                segmentation.append(seg)
    pred2d, pred3d, gt2d, gt3d = (np.concatenate(a) for a in (pred2d, pred3d, gt2d, gt3d))
    seconds = time.perf_counter() - start
    if log is not None:
        log(f"ran {net.format} model on {len(rows)} {reader.split} frames in {seconds:.1f} s")
    bad = ~(np.isfinite(pred3d).all(axis=(1, 2)) & np.isfinite(pred2d).all(axis=(1, 2)))
    if bad.any():
        raise RunFailedError(f"the model's output is NaN or inf on {int(bad.sum())} of {len(bad)} frames")
    if clips is not None and not track:   # a model without fits: its tracking is the filter's alone
        tracked2d, tracked3d = [pred2d], [pred3d]
    return SplitPrediction(rows, pred2d, pred3d, gt2d, gt3d, images if keep_images else None, seconds,
                           np.concatenate(segmentation) if segmentation else None,
                           np.concatenate(tracked2d) if clips is not None else None,
                           np.concatenate(tracked3d) if clips is not None else None,
                           1e3 * float(np.median(fit_seconds)) if track else None)

"""The input pipeline: a split's frames and labels at the model's input, from JPEG files or a frame cache,
augmented per batch on the training device.

Modules: ``reader`` (the manifest, the annotations, one frame decoded and resized, the labels in the
input image), ``cache`` (a split's frames decoded once into a memory map, keyed by the files it read),
``augment`` (rotation and colour jitter of a batch; frames to model images), ``loaders`` (the ``data``
config node, :class:`DataConfig`, and a training run's loaders; ``data.pipeline`` picks only the source of
uint8 frames).

May import: the shared core (``hupbench.core``: the dataset contract, camera, io, input checks, errors),
``hupbench.input_geometry``, torch, kornia, OpenCV, numpy. Never ``hupbench.training``,
``hupbench.evaluation``, ``hupbench.inference``, the verbs or the CLI.
"""

from hupbench.data.augment import BatchAugment, model_images
from hupbench.data.cache import open_frame_cache
from hupbench.data.loaders import DataConfig, FrameBatches, Placement, TrainData, setup_data
from hupbench.data.reader import HUPDataset, ReaderConfig, input_labels, read_manifest, read_rgb

__all__ = ["BatchAugment", "DataConfig", "FrameBatches", "HUPDataset", "Placement", "ReaderConfig", "TrainData",
           "input_labels", "model_images", "open_frame_cache", "read_manifest", "read_rgb", "setup_data"]

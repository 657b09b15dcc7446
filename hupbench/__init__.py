"""hupbench: the CLI, the dataset reader, training, evaluation, ONNX export and inference, the leaderboard.

May import: ``datagen`` (the dataset contract, and the generator for the verbs that make data),
``models``, torch (not on the inference path: ``predict`` and the model-file contract import no
torch), numpy, OpenCV, onnx, onnxruntime, Hydra. Nothing in ``datagen`` or ``models`` imports it.
"""

__version__ = "0.1.0"

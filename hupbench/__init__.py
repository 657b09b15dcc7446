"""hupbench: CLI, dataset reader, training, metrics, evaluation, ONNX export and inference, leaderboard."""

__version__ = "0.1.0"

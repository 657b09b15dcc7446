"""hupbench: the CLI, the dataset reader, training, evaluation, ONNX export and inference, the leaderboard.

Subpackages, in the order a model is made and used: ``training`` (the loop and its pieces),
``evaluation`` (eval, results, leaderboard), ``inference`` (ONNX export, torch-free predict), ``verbs``
(generate, verify, grasps, quickstart as functions of their config). Top-level modules shared by
them: ``cli`` (the command), ``errors`` (one-line errors), ``config`` (Hydra composition),
``provenance`` (git commit, versions, hardware), ``data`` (the dataset reader over the contract),
``checkpoint`` and ``metrics``.

May import: ``datagen`` (the dataset contract, and the generator for the verbs that make data),
``models``, torch (not on the inference path: ``inference.predict`` imports no torch), numpy,
OpenCV, onnx, onnxruntime, Hydra. Nothing in ``datagen`` or ``models`` imports it.
"""

__version__ = "0.1.0"

"""hupbench: the CLI, the dataset reader, training, evaluation, ONNX export and inference, the leaderboard.

Installed beside them: ``hupbench.core`` (the shared core), ``hupbench.datagen`` (the generator) and
``hupbench.models``. Subpackages, in the order a model is made and used: ``data`` (the dataset reader over
the contract), ``training`` (the loop and its pieces), ``evaluation`` (eval, results, leaderboard),
``inference`` (ONNX export, torch-free predict), ``verbs`` (generate, verify, grasps, quickstart as
functions of their config). Top-level modules shared by them: ``cli`` (the command), ``error_lines``
(one-line errors), ``config`` (Hydra composition), ``provenance`` (git commit, versions, hardware),
``input_geometry``, ``checkpoint`` and ``metrics``.

May import: ``core``, ``datagen`` (the generator, for the verbs that make data), ``models``, torch (not on
the inference path: ``inference.predict`` imports no torch and no generator module), numpy, OpenCV, onnx,
onnxruntime, Hydra. Nothing in ``core``, ``datagen`` or ``models`` imports it.
"""

__version__ = "0.1.0"

"""Inference: the exported model file and predictions on new images.

Owns: the ONNX export with its metadata contract and parity check (``export``: needs torch; the
contract's schema version and key prefix in ``model_file``, shared with ``predict``), and the
torch-free path from an image file to 2D and 3D keypoints (``predict``, ``images``: reading and
checking user images, ``overlay``: drawing the prediction).

May import: ``models`` and ``hupbench`` top-level modules (``export`` only: it traces a checkpoint),
``datagen`` shared modules and ``datagen.render.draw``, numpy, OpenCV, onnx, onnxruntime. Never
``hupbench.training``, ``hupbench.evaluation`` or ``hupbench.verbs``; ``predict``, ``images``,
``overlay`` and ``model_file`` never import torch.
"""

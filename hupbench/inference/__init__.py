"""Inference: the exported model file and predictions on new images.

Owns: the model-file contract (``model_file``: the ONNX metadata's one writer and one reader, the
check of the graph's declared input and outputs, and ``InputGeometry``, the pad-and-resize from an
image to the model input as one 3 x 3 map), the ONNX export with its parity check (``export``: needs
torch), and the torch-free path from an image file to 2D and 3D keypoints (``predict``, ``images``: reading and
checking user images, ``overlay``: drawing the prediction).

May import: ``models`` and ``hupbench`` top-level modules (``export`` only: it traces a checkpoint),
``datagen`` shared modules and ``datagen.render.draw``, numpy, OpenCV, onnx, onnxruntime. Never
``hupbench.training``, ``hupbench.evaluation`` or ``hupbench.verbs``; ``predict``, ``images``,
``overlay`` and ``model_file`` never import torch.
"""

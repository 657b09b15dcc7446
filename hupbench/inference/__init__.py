"""Inference: the exported model file and predictions on new images.

Owns: the model-file contract (``model_file``: the ONNX metadata's one writer and one reader, and the
check of the graph's declared input and outputs), the one ONNX runtime (``runtime``: opening, checking
and running an exported file, for eval, export's parity check and predict), the ONNX export with its
parity check (``export``: needs torch), and the torch-free path from an image file to 2D and 3D keypoints
(``predict``, ``images``: reading and checking user images, ``video``: reading a user's video frame by frame and
writing its overlay video, ``overlay``: drawing the prediction), and the
temporal filter that carries keypoints from frame to frame of a video (``tracking``).

May import: ``models`` and ``hupbench`` top-level modules (``export`` only: it traces a checkpoint),
``hupbench.input_geometry``, ``hupbench.fits`` (what runs after the network), ``datagen`` shared modules and ``hupbench.core.draw``, numpy, OpenCV, onnx,
onnxruntime. Never ``hupbench.training``, ``hupbench.evaluation`` or ``hupbench.verbs``; ``predict``,
``runtime``, ``images``, ``video``, ``overlay``, ``model_file`` and ``tracking`` never import torch.
"""

"""The shared core: what the generator, the models, training, evaluation and the torch-free predict all use.

Modules: ``errors`` (the one user-error class and its kinds), ``io`` (atomic writes, locks, the image
encoder), ``input_checks`` (the one vocabulary of input checks), ``keypoints`` (the names, order and skeleton of
the 29 keypoints), ``camera`` (intrinsics and projection), ``geometry`` (rotations and transforms, numpy),
``rotations_torch`` (the same in torch), ``tolerances`` (every tolerance in one place), ``processes``
(worker counts and Ctrl-C in workers), ``contract`` (the dataset on disk, numpy only), ``probe_symmetry``
(the probe's half turn, symmetry group and diameter), ``draw`` (2D drawing of keypoints and masks, OpenCV) and
``motion_metrics`` (speed, acceleration and jerk of tracks over time, and the acceleration error).

May import: numpy, OpenCV and the standard library (``rotations_torch`` alone: torch;
``probe_symmetry.object_diameter_m`` and ``motion_metrics.time_derivatives``' smoothing: scipy). Never ``datagen``, ``models`` or the rest of ``hupbench``: they
import the core.
"""

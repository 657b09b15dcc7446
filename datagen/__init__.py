"""Everything that makes data: the hand, the probe, grasps, the camera sphere, the renderer, the dataset writer.

Subpackages, in the order data flows:
    ``assets``   the hand, probe, forearm and backgrounds, built here;
    ``grasps``   grasp synthesis: sampler, refinement, scores, selection;
    ``render``   scenes drawn by pyrender offscreen, and 2D drawing;
    ``dataset``  the on-disk contract, the viewpoint sphere, the writer, launchers and verify.
Shared modules at the top: ``keypoints`` (the one owner of keypoint names and order), ``geometry``
(rotations and transforms), ``rotations_torch``, ``mesh_distance`` (exact point-to-triangle-mesh
distances, free functions on ``(n, 3)`` arrays), ``camera`` (intrinsics and projection),
``tolerances`` (every tolerance of datagen), ``io`` (atomic writes, locks), ``processes``
(worker counts) and ``input_checks`` (whole numbers, finite numbers and shapes, one wording for
datagen and hupbench).

May import: numpy, scipy, torch, trimesh, pyrender, OpenCV and itself. Never ``models`` or
``hupbench`` (data flows one way: datagen -> dataset on disk -> hupbench).
"""

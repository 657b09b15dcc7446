"""Everything that makes data: the hand, the probe, grasps, the camera sphere, the renderer, the dataset writer.

Subpackages, in the order data flows:
    ``assets``   the hand, probe, forearm and backgrounds, built here;
    ``grasps``   grasp synthesis: sampler, refinement, scores, selection;
    ``render``   scenes drawn by pyrender offscreen, and 2D drawing;
    ``dataset``  the on-disk contract, the viewpoint sphere, the writer, launchers and verify.
At the top: ``mesh_distance`` (exact point-to-triangle-mesh distances, free functions on ``(n, 3)``
arrays). What the generator shares with the rest of hupbench (keypoints, cameras, rotations, tolerances,
atomic io, input checks, the dataset contract, 2D drawing) is the core, ``hupbench.core``.

May import: numpy, scipy, torch, trimesh, pyrender, OpenCV, ``hupbench.core`` and itself. Never ``models`` or
the rest of ``hupbench`` (data flows one way: datagen -> dataset on disk -> hupbench).
"""

"""What a frame shows, built here with no file from elsewhere: the hand, the probe, the forearm, the backgrounds.

Owns: the procedural right hand (``hand``: kinematics and the posable model; ``hand_anatomy``:
measurements, joint limits, pose parametrisation; ``hand_mesh``: its skinned surface), the probe
(``probe``: the facade and its signed distance; ``probe_shape``: its surface; ``probe_marker``: the
tracking marker), the forearm (``arm``) and the backgrounds (``backgrounds``,
``background_scenes``).

May import: numpy, scipy, torch, trimesh, OpenCV and the shared modules at the top of
``datagen`` (keypoints, geometry, mesh_distance, rotations_torch, camera, tolerances, io). Never ``hupbench.datagen.render``,
``hupbench.datagen.dataset``, ``hupbench.datagen.grasps``, ``models`` or ``hupbench``.
"""

"""Rendering: scenes of the assets drawn by pyrender offscreen, and 2D drawing.

Owns: the OpenGL platform choice and pyrender's import without X11 (``gl``), the renderer
(``renderer``: RGB, metric depth and labels in one or two passes), the scene of a grasp (``scene``:
hand, forearm and probe as mesh parts), 2D drawing (``draw``: keypoints, skeletons, depth and label
colours, contact sheets; numpy and OpenCV only, used by the torch-free inference path) and the
preview sheet of a hand-set grasp (``preview``).

May import: ``hupbench.datagen.assets``, the shared modules at the top of ``datagen``, the dataset contract's
constants (``hupbench.datagen.dataset.contract``: modalities, label values), pyrender, OpenCV. Never
``hupbench.datagen.grasps``, ``models`` or ``hupbench``.
"""

"""Rendering: scenes of the assets drawn by pyrender offscreen.

Owns: the OpenGL platform choice and pyrender's import without X11 (``gl``), the renderer
(``renderer``: RGB, metric depth and labels in one or two passes), the scene of a grasp (``scene``:
hand, forearm and probe as mesh parts) and the preview sheet of a hand-set grasp (``preview``). 2D
drawing is the core's (``hupbench.core.draw``).

May import: ``hupbench.core``, ``hupbench.datagen.assets``, pyrender, OpenCV. Never ``hupbench.datagen.dataset``,
``hupbench.datagen.grasps``, ``models`` or the rest of ``hupbench``.
"""

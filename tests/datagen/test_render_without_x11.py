"""Offscreen rendering must not need the X11 client libraries.

A bare Debian box or a GPU server has no libX11 / libXrender / libXext unless something pulled them
in by accident. Each case runs in a fresh interpreter in which every lookup of an X11 library by
name fails (``ctypes.CDLL`` / ``ctypes.cdll.LoadLibrary`` raise OSError, ``ctypes.util.find_library``
returns None) and ``_tkinter`` (which links libtk and so libX11) cannot be imported, all before
anything else is imported; it then renders one frame with RGB, depth and labels through
:class:`datagen.render.Renderer` on the platform under test and reports what it saw.
"""

import json
import math
import os
import subprocess
import sys
import textwrap

import pytest

# the process that renders: the X11 block first, then the project's renderer
RENDER_WITHOUT_X11 = textwrap.dedent(
    r"""
    import ctypes, ctypes.util, importlib.abc, json, os, re, sys

    X11_NAME = re.compile(r"(^|/)(lib)?X[A-Za-z0-9]")  # X11, Xext, Xrender, libX11.so.6, libXrender.so.1, ...
    refused = []

    class NoX11Library(OSError):
        pass

    original_init = ctypes.CDLL.__init__

    def cdll_init(self, name, *args, **kwargs):
        if name is not None and X11_NAME.search(os.fspath(name)):
            refused.append(os.fspath(name))
            raise NoX11Library(f"{name}: cannot open shared object file (X11 blocked by the test)")
        original_init(self, name, *args, **kwargs)

    ctypes.CDLL.__init__ = cdll_init  # ctypes.cdll.LoadLibrary and PyDLL construct through it
    original_find = ctypes.util.find_library

    def find_library(name):
        if X11_NAME.search(name):
            refused.append(name)
            return None
        return original_find(name)

    ctypes.util.find_library = find_library

    class NoTk(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "_tkinter":
                refused.append(name)
                raise ImportError("_tkinter blocked by the test (libtk links libX11)")
            return None

    sys.meta_path.insert(0, NoTk())

    import numpy as np
    import trimesh

    from datagen.camera import Intrinsics, look_at
    from datagen.render import SEG_LABELS, MeshPart, RenderSettings, Renderer

    # a red 10 cm cube (probe) right of the optical axis, a 4 cm green ball (hand) left of it, 0.6 m away
    cube = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    cube.apply_translation([0.06, 0.0, 0.0])
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    ball.apply_translation([-0.06, 0.0, 0.0])
    with Renderer(Intrinsics(480.0, 480.0, 64.0, 64.0, 128, 128), platform=sys.argv[1]) as renderer:
        renderer.set_parts([MeshPart("probe", cube, SEG_LABELS["probe"], color=(1.0, 0.0, 0.0)),
                            MeshPart("hand", ball, SEG_LABELS["hand"], color=(0.0, 1.0, 0.0))])
        T_cam_world = look_at(np.array([0.0, 0.0, 0.65]), np.zeros(3), up_world=(0.0, 1.0, 0.0))
        out = renderer.render(T_cam_world, ("rgb", "depth", "seg"), settings=RenderSettings(ambient=1.0))
        platform = renderer.platform
    # the cube's face spans x in [0.01, 0.11] m at depth 0.6 m: columns 64 + 480 * x / 0.6 = [72, 152)
    # (clipped at 128); the ball's centre is at column 64 - 48 = 16
    print(json.dumps({
        "platform": platform,
        "refused": sorted(set(refused)),
        "shapes": {k: list(v.shape) for k, v in out.items()},
        "dtypes": {k: str(v.dtype) for k, v in out.items()},
        "cube_depth": float(out["depth"][64, 100]),
        "ball_depth": float(out["depth"][64, 16]),
        "background_depth": float(out["depth"][5, 64]),
        "cube_label": int(out["seg"][64, 100]),
        "ball_label": int(out["seg"][64, 16]),
        "labels": sorted(np.unique(out["seg"]).tolist()),
        "cube_rgb": out["rgb"][64, 100].tolist(),
        "ball_rgb": out["rgb"][64, 16].tolist(),
        "background_rgb": out["rgb"][5, 64].tolist(),
        "depth_seg_disagree": int(((out["depth"] > 0) != (out["seg"] > 0)).sum()), "seg_pixels": int((out["seg"] > 0).sum()),
        "label_pixels": {int(v): int((out["seg"] == v).sum()) for v in (1, 3)},
    }))
    """
)


@pytest.mark.parametrize("platform", ["egl", "osmesa"])
def test_renders_rgb_depth_and_labels_without_x11_libraries(platform):
    env = {k: v for k, v in os.environ.items() if k not in ("PYOPENGL_PLATFORM", "DISPLAY")}
    proc = subprocess.run([sys.executable, "-c", RENDER_WITHOUT_X11, platform], capture_output=True, text=True,
                          timeout=180, env=env)
    assert proc.returncode == 0, f"rendering with {platform} needed X11:\n{proc.stderr[-3000:]}"
    seen = json.loads(proc.stdout.strip().splitlines()[-1])
    assert seen["platform"] == platform
    assert seen["shapes"] == {"rgb": [128, 128, 3], "depth": [128, 128], "seg": [128, 128]}
    assert seen["dtypes"] == {"rgb": "uint8", "depth": "float32", "seg": "uint8"}
    # the cube's front face is 0.6 m from the camera; column 16 is the ray (-0.1 t, 0, t), which meets
    # the ball |p - (-0.06, 0, 0.65)| = 0.02 at 1.01 t^2 - 1.312 t + 0.4257 = 0
    assert seen["cube_depth"] == pytest.approx(0.6, abs=1e-3)
    ball_depth = (1.312 - math.sqrt(1.312**2 - 4 * 1.01 * 0.4257)) / (2 * 1.01)
    assert seen["ball_depth"] == pytest.approx(ball_depth, abs=1e-3)
    assert seen["background_depth"] == 0.0
    assert (seen["cube_label"], seen["ball_label"]) == (3, 1)
    assert seen["labels"] == [0, 1, 3]
    # the cube: its front face, columns 72..127 x rows 24..103 = 4,480 px, and its inner side face (x = 0.01 m,
    # 0.6 to 0.7 m deep: columns 70.9 to 72, rows 64 +- 34 to 40), about 85 px; the ball: a disc of radius
    # 480 * 0.02 / sqrt(0.65^2 - 0.02^2) = 14.78 px, 686 px
    assert seen["label_pixels"]["3"] == pytest.approx(4560, rel=0.01)
    assert seen["label_pixels"]["1"] == pytest.approx(math.pi * 14.78**2, rel=0.03)
    # depth from the (multisampled on EGL) colour pass and labels from the label pass agree but on edges
    assert seen["depth_seg_disagree"] <= 0.01 * seen["seg_pixels"]
    # lit by ambient light only, each part shows its own base colour; the background is white
    red, green = seen["cube_rgb"], seen["ball_rgb"]
    assert red[0] > 150 and red[1] < 60 and red[2] < 60, red
    assert green[1] > 150 and green[0] < 60 and green[2] < 60, green
    assert seen["background_rgb"] == [255, 255, 255]

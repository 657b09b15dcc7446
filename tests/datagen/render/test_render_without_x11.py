"""Offscreen rendering must not need the X11 client libraries.

A bare Debian box or a GPU server has no libX11 / libXrender / libXext unless something pulled them
in by accident. Each case runs in a fresh interpreter in which every lookup of an X11 library by
name fails (``ctypes.CDLL`` / ``ctypes.cdll.LoadLibrary`` raise OSError, ``ctypes.util.find_library``
returns None) and ``_tkinter`` (which links libtk and so libX11) cannot be imported, all before
anything else is imported; it then renders one frame with RGB, depth and labels through
:class:`hupbench.datagen.render.renderer.Renderer` on the platform under test and reports what it saw.

The slow test goes further where it can (root on Debian/Ubuntu): it really removes, in a private mount
namespace, the library files of every X11/GL/EGL package that install.sh's package list does not pull in,
and renders the same frame there, so install.sh's list is checked to be sufficient.
"""

import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest
from helpers import REPO, needs_osmesa

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

    from hupbench.core.camera import Intrinsics, look_at
    from hupbench.datagen.render.renderer import SEG_LABELS, MeshPart, RenderSettings, Renderer
    from hupbench.datagen.dataset.verify_images import mask_depth_mismatch_px

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
        "depth_seg_disagree_off_edges": mask_depth_mismatch_px(out["depth"], out["seg"]),
        "label_pixels": {int(v): int((out["seg"] == v).sum()) for v in (1, 3)},
    }))
    """
)


@pytest.mark.parametrize("platform", ["egl", pytest.param("osmesa", marks=needs_osmesa)])
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
    # depth from the (multisampled on EGL) colour pass and labels from the label pass agree but on edges (the
    # cube's edges run through pixel centres here, where the two passes' samples split either way)
    assert seen["depth_seg_disagree_off_edges"] == 0
    # lit by ambient light only, each part shows its own base colour; the background is white
    red, green = seen["cube_rgb"], seen["ball_rgb"]
    assert red[0] > 150 and red[1] < 60 and red[2] < 60, red
    assert green[1] > 150 and green[0] < 60 and green[2] < 60, green
    assert seen["background_rgb"] == [255, 255, 255]


#: Debian packages of X11 client libraries and GL/EGL stacks that a bare machine may lack
X11_AND_GL_PACKAGES = re.compile(
    r"^(libx11|libxau|libxcb|libxdmcp|libxext|libxfixes|libxft|libxi6|libxinerama|libxkbcommon-x11|libxmu|libxpm|"
    r"libxrandr|libxrender|libxshmfence|libxss|libxt6|libxtst|libxv1|libxxf86|libxaw|libxcomposite|libxcursor|"
    r"libxdamage|libtk|libglx|libgl1|libgles|libegl|libopengl|libosmesa|libglu|libglut|libglapi|libgbm|libwayland)"
)


def _install_sh_packages() -> list[str]:
    text = (REPO / "install.sh").read_text()
    match = re.search(r'^DEB_PACKAGES="([^"]+)"', text, flags=re.M)
    assert match, "install.sh no longer sets DEB_PACKAGES=\"...\""
    return match.group(1).split()


@pytest.mark.slow
@pytest.mark.parametrize("platform", ["egl", pytest.param("osmesa", marks=needs_osmesa)])
def test_install_sh_packages_are_enough_on_a_machine_without_the_others(tmp_path, platform):
    """A bare Debian box after install.sh, simulated: in a private mount namespace every library file of
    the X11, GL and EGL packages outside the dependency closure of install.sh's DEB_PACKAGES reads as empty
    (/dev/null bound over it) and the loader cache is rebuilt without them; then the frame of the test above
    is rendered there."""
    tools = ("unshare", "mount", "ldconfig", "dpkg-query", "apt-cache")
    if sys.platform != "linux" or os.geteuid() != 0 or not all(shutil.which(t) for t in tools):
        pytest.skip(f"needs root on Debian/Ubuntu with {', '.join(tools)}")
    wanted = _install_sh_packages()
    listed = subprocess.run(["dpkg-query", "-W", "-f=${Package} ${Status}\n"], capture_output=True, text=True,
                            check=True).stdout.splitlines()
    installed = {line.split()[0] for line in listed if line.endswith("install ok installed")}
    if not set(wanted) <= installed:
        pytest.skip(f"install.sh's packages are not all installed here: {sorted(set(wanted) - installed)}")
    closure_out = subprocess.run(
        ["apt-cache", "depends", "--recurse", "--no-recommends", "--no-suggests", "--no-conflicts", "--no-breaks",
         "--no-replaces", "--no-enhances", *wanted], capture_output=True, text=True, check=True).stdout
    closure = {line.strip() for line in closure_out.splitlines() if line and not line.startswith((" ", "<"))}
    assert set(wanted) <= closure, f"apt-cache gave no dependency closure: {sorted(closure)[:20]}"
    hidden_packages = sorted(p for p in installed if X11_AND_GL_PACKAGES.match(p) and p not in closure)
    lib_dir = Path("/usr/lib") / sysconfig.get_config_var("MULTIARCH")

    def libraries(packages):  # the shared-object files (symbolic links followed) of these packages
        files = subprocess.run(["dpkg", "-L", *packages], capture_output=True, text=True).stdout.splitlines()
        return {str(Path(f).resolve()) for f in files if f.startswith(f"{lib_dir}/") and ".so" in f
                and Path(f).resolve().is_file()}

    # a -dev package's libFOO.so link may point into a kept package: binding over it would hide that too
    hidden = sorted(libraries(hidden_packages) - libraries(sorted(closure & installed)))
    assert any("libXrender.so" in f for f in hidden) or "libxrender1" not in installed, hidden_packages
    script = tmp_path / "bare.sh"
    cache = tmp_path / "ld.so.cache"
    script.write_text("set -e\n" + "".join(f"mount --bind /dev/null {shlex.quote(f)}\n" for f in hidden)
                      + f"ldconfig -C {cache}\nmount --bind {cache} /etc/ld.so.cache\n"
                      + 'exec "$@"\n')
    env = {k: v for k, v in os.environ.items() if k not in ("PYOPENGL_PLATFORM", "DISPLAY")}
    lookup = ("import ctypes.util; print(' '.join(n for n in ('X11', 'Xext', 'Xrender') "
              "if ctypes.util.find_library(n) is None))")
    # the namespace really lacks libXrender (none of install.sh's packages pulls it in)
    missing = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", str(script), sys.executable, "-c",
                              lookup], capture_output=True, text=True, timeout=120, env=env)
    assert missing.returncode == 0 and "Xrender" in missing.stdout.split(), missing.stderr[-2000:]
    proc = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", str(script), sys.executable, "-c",
                           RENDER_WITHOUT_X11, platform], capture_output=True, text=True, timeout=180, env=env)
    assert proc.returncode == 0, (f"install.sh's packages {wanted} do not render with {platform} once "
                                  f"{hidden_packages} are gone:\n{proc.stderr[-3000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["platform"] == platform
    assert result["cube_depth"] == pytest.approx(0.6, abs=1e-3) and result["labels"] == [0, 1, 3]

"""Choosing the offscreen OpenGL platform before pyrender is imported.

PyOpenGL fixes its platform (EGL or OSMesa) at first import, so the choice is
made here, once per process, before anything imports ``OpenGL`` or
``pyrender``: EGL first (Mesa llvmpipe on a CPU machine, the vendor driver on
a GPU), OSMesa as the fallback. This module is also the one place that imports
pyrender (:func:`load_pyrender`): without its interactive viewer, which would
pull in pyglet's X11 window system, and with ``np.infty`` restored (removed in
numpy 2, still used by pyrender 0.1.45).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import types
import warnings

import numpy as np
from hupbench.core.errors import BadValueError, RunFailedError

PLATFORMS = ("egl", "osmesa")
#: what EGL rendering needs on Debian/Ubuntu (install.sh installs it): the GLVND EGL loader, Mesa's EGL
#: vendor library and its DRI drivers (llvmpipe on a CPU), and libOpenGL for GL without GLX/X11
EGL_PACKAGES_HINT = "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0"
_chosen: str | None = None
#: attribute of a pyrender mesh node giving its place in the draw order (lower first): where two
#: meshes meet at exactly the same depth (the hand and the forearm at the wrist) the first drawn keeps
#: the pixel (GL_LESS), and pyrender's own order differs between processes
#: (:func:`_patch_pyrender_draw_order`)
DRAW_RANK = "hupbench_draw_rank"


def _egl_works() -> bool:
    """Does an EGL device display initialise, with a GL library to draw with? Asked through
    ctypes, so PyOpenGL stays unimported.

    Mirrors what pyrender does: enumerate EGL devices (EGL_EXT_device_enumeration)
    and open a platform display on the first one; no window system is needed.
    """
    name = ctypes.util.find_library("EGL") or "libEGL.so.1"
    try:
        egl = ctypes.CDLL(name)
    except OSError:
        return False
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    query_addr = egl.eglGetProcAddress(b"eglQueryDevicesEXT")
    display_addr = egl.eglGetProcAddress(b"eglGetPlatformDisplayEXT")
    if not query_addr or not display_addr:
        return False
    query_devices = ctypes.CFUNCTYPE(
        ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p), ctypes.POINTER(ctypes.c_int)
    )(query_addr)
    get_display = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p)(display_addr)
    devices = (ctypes.c_void_p * 8)()
    count = ctypes.c_int(0)
    if not query_devices(8, devices, ctypes.byref(count)) or count.value < 1:
        return False
    egl_platform_device_ext = 0x313F
    display = get_display(egl_platform_device_ext, devices[0], None)
    if not display:
        return False
    egl.eglInitialize.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    egl.eglTerminate.argtypes = [ctypes.c_void_p]
    major, minor = ctypes.c_int(), ctypes.c_int()
    if not egl.eglInitialize(display, ctypes.byref(major), ctypes.byref(minor)):
        return False
    egl.eglTerminate(display)
    # PyOpenGL's EGL platform takes GL from libOpenGL (GLVND, no X11) or else libGL; without
    # either, pyrender fails later on an opaque AttributeError, so EGL counts as unavailable
    for gl_name, soname in (("OpenGL", "libOpenGL.so.0"), ("GL", "libGL.so.1")):
        try:
            ctypes.CDLL(ctypes.util.find_library(gl_name) or soname)
            return True
        except OSError:
            continue
    return False


def _osmesa_works() -> bool:
    name = ctypes.util.find_library("OSMesa") or "libOSMesa.so.8"
    try:
        ctypes.CDLL(name)
    except OSError:
        return False
    import importlib.metadata

    version = importlib.metadata.version("PyOpenGL")
    if tuple(int(x) for x in version.split(".")[:3]) < (3, 1, 7):
        raise RunFailedError(
            f"OSMesa rendering needs PyOpenGL >= 3.1.7, found {version} "
            "(pyrender pins 3.1.0 but works with newer): pip install 'PyOpenGL==3.1.10'"
        )
    return True


def configure(platform: str | None = None) -> str:
    """Select the offscreen GL platform for this process and return it.

    Args:
        platform: "egl", "osmesa", or None for automatic (the environment's
            ``PYOPENGL_PLATFORM`` if set, else EGL if it initialises, else
            OSMesa). A platform asked for by name that does not work is an
            error, not a silent fallback.

    Returns:
        The platform in use.
    """
    global _chosen
    if not hasattr(np, "infty"):
        np.infty = np.inf  # pyrender 0.1.45 uses the numpy 1 alias
    # the config node that names the platform (render.platform, sheet.platform) checked it
    assert platform is None or platform in PLATFORMS, platform
    requested = platform or os.environ.get("PYOPENGL_PLATFORM") or None
    if requested is not None and requested not in PLATFORMS:
        raise BadValueError(f"PYOPENGL_PLATFORM must be one of {PLATFORMS} for offscreen rendering, got {requested!r}")
    if _chosen is not None:
        if requested is not None and requested != _chosen:
            raise RunFailedError(
                f"this process already renders with {_chosen!r}; PyOpenGL cannot switch to {requested!r} "
                "(start a new process)"
            )
        return _chosen
    if "OpenGL" in sys.modules and os.environ.get("PYOPENGL_PLATFORM") not in PLATFORMS:
        raise RunFailedError("OpenGL was imported before hupbench.datagen.render.gl.configure(); import hupbench renderers first")
    if requested == "egl" and not _egl_works():
        raise RunFailedError(
            f"EGL was requested but does not work here (no EGL display initialises, or no libOpenGL/libGL): "
            f"{EGL_PACKAGES_HINT}"
        )
    if requested == "osmesa" and not _osmesa_works():
        raise RunFailedError("OSMesa was requested but libOSMesa is missing: apt-get install libosmesa6")
    if requested is None:
        if _egl_works():
            requested = "egl"
        elif _osmesa_works():
            requested = "osmesa"
            warnings.warn("EGL is not available; rendering with OSMesa (slower)", RuntimeWarning, stacklevel=2)
        else:
            raise RunFailedError(
                f"no offscreen OpenGL platform: install Mesa EGL ({EGL_PACKAGES_HINT}) "
                "or OSMesa (apt-get install libosmesa6)"
            )
    os.environ["PYOPENGL_PLATFORM"] = requested
    _chosen = requested
    return requested


class _OffscreenOnlyViewer:
    """Stands in for ``pyrender.Viewer``, which hupbench never opens (see :func:`load_pyrender`)."""

    def __init__(self, *args, **kwargs) -> None:
        raise RunFailedError(
            "pyrender's interactive Viewer is not loaded in a process that renders with hupbench: it needs "
            "pyglet's X11 window system; hupbench renders offscreen only (EGL or OSMesa)"
        )


def load_pyrender() -> types.ModuleType:
    """Import pyrender for offscreen rendering and return it. Call after :func:`configure`.

    ``import pyrender`` imports its interactive viewer, a ``pyglet.window.Window``
    subclass: pyglet's window module loads libX11, libXext and libXrender (and
    pyrender's viewer tries tkinter), none of which offscreen EGL or OSMesa
    rendering uses and which a bare Debian box or a GPU server does not have.
    A stand-in ``pyrender.viewer`` is registered before the import, so pyglet is
    never imported; pyglet's own headless mode is no substitute, because it still
    loads libGL (GLX, hence libX11) and needs EGL even when OSMesa renders.
    A pyrender the process had already imported is returned as it is.
    """
    assert _chosen is not None, "configure() chooses the platform before pyrender is imported"
    if "pyrender" not in sys.modules:
        viewer = types.ModuleType("pyrender.viewer", "hupbench stand-in for pyrender's X11 viewer (offscreen only)")
        viewer.Viewer = _OffscreenOnlyViewer
        sys.modules.setdefault("pyrender.viewer", viewer)
    import pyrender

    _patch_pyrender_egl()
    _patch_pyrender_draw_order()
    return pyrender


def _patch_pyrender_draw_order() -> None:
    """Draw meshes in a fixed order: pyrender's, then :data:`DRAW_RANK`, then the node name.

    pyrender 0.1.45 sorts the solid meshes by the distance of their node's origin from the camera
    (a stable sort) starting from ``Scene.mesh_nodes``, a set iterated in the order of the nodes'
    memory addresses. Meshes placed by their vertices (node pose = identity, as hupbench's) are all
    at one distance, so without a rank the winner of an exact depth tie would follow that address
    order. Nodes without a rank or a name keep pyrender's order among themselves.
    """
    from pyrender.renderer import Renderer as PyrenderRenderer

    if getattr(PyrenderRenderer, "_hupbench_draw_order", False):
        return
    original = PyrenderRenderer._sorted_mesh_nodes

    def _sorted_mesh_nodes(self, scene):
        nodes = original(self, scene)
        cam_loc = scene.get_pose(scene.main_camera_node)[:3, 3]
        # pyrender's own key (farthest first, solid before transparent), then the rank
        return sorted(nodes, key=lambda n: (bool(n.mesh.is_transparent),
                                            -np.linalg.norm(scene.get_pose(n)[:3, 3] - cam_loc),
                                            getattr(n, DRAW_RANK, float("inf")), n.name or ""))

    PyrenderRenderer._sorted_mesh_nodes = _sorted_mesh_nodes
    PyrenderRenderer._hupbench_draw_order = True


def _patch_pyrender_egl() -> None:
    """Make pyrender's EGL renderers independent of each other.

    pyrender's ``EGLPlatform.delete_context`` calls ``eglTerminate`` on the
    display, but an EGL device display is one handle per process: terminating
    it when one renderer closes breaks every other live renderer
    (EGL_BAD_DISPLAY). Here closing destroys only the renderer's own context;
    the display lives as long as the process.
    """
    if _chosen != "egl":
        return
    from pyrender.platforms import egl as pyrender_egl

    if getattr(pyrender_egl.EGLPlatform, "_hupbench_patched", False):
        return

    def delete_context(self):
        from OpenGL.EGL import eglDestroyContext

        if self._egl_display is not None and self._egl_context is not None:
            eglDestroyContext(self._egl_display, self._egl_context)
        self._egl_context = None
        self._egl_display = None

    pyrender_egl.EGLPlatform.delete_context = delete_context
    pyrender_egl.EGLPlatform._hupbench_patched = True

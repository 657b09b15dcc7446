"""Offscreen rendering of RGB, metric depth and segmentation labels with pyrender.

Only the modalities asked for are rendered: RGB and depth come from one
colour pass, segmentation (and depth, when RGB is not asked for) from one
flat-shaded label pass.

Convention:
    Camera poses are given as ``T_cam_world`` in OpenCV axes and converted
    to pyrender's OpenGL axes by :func:`hupbench.core.camera.swap_gl_cv_axes`.
    Pixels follow the dataset contract (:mod:`hupbench.core.contract`, "Convention"):
    a point projected by ``K`` to (u, v) lands in the pixel whose centre is (u, v).
    The colour pass shades with ``shaders/blinn_phong.frag`` (Lambert + Blinn-Phong
    under point lamps, ambient, emissive) by default; ``shading="pbr"`` keeps pyrender's
    physically based shader (about half the speed, a near-identical look: docs/rendering.md).
    Depth is the camera-frame z in metres (float32), 0 where no surface
    was hit. Labels: 0 background, 1 hand, 2 arm, 3 probe (``SEG_LABELS``), 4 the patient on the clinic track.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from hupbench.datagen.render import gl
from hupbench.core.camera import Intrinsics, swap_gl_cv_axes
from hupbench.core.contract import CLINIC_SEG_LABELS, MODALITIES, SEG_LABELS
from hupbench.core.geometry import invert_transform
from hupbench.core.errors import BadValueError

ZNEAR_M, ZFAR_M = 0.01, 20.0
#: the colour pass's fragment shader, in place of pyrender's mesh.frag (fed by pyrender's mesh.vert)
COLOUR_SHADER = Path(__file__).with_name("shaders") / "blinn_phong.frag"
SHADINGS = ("blinn_phong", "pbr")
#: GL puts pixel centres at half-integers from the image's corner; the contract puts them at integers
GL_PIXEL_CENTRE_OFFSET = 0.5


def check_modalities(modalities: Iterable[str], prefix: str = "") -> tuple[str, ...]:
    """The modalities asked for, in :data:`MODALITIES`' order; ``prefix`` starts the error line (the config key,
    e.g. ``"render.modalities: "``)."""
    if isinstance(modalities, str):
        modalities = (modalities,)
    modalities = tuple(modalities)
    unknown = [m for m in modalities if m not in MODALITIES]
    if not modalities or unknown:
        raise BadValueError(prefix + (f"unknown modality {unknown[0]!r}; choose from {MODALITIES}" if unknown else
                                      f"at least one modality must be asked for, from {MODALITIES}"))
    return tuple(m for m in MODALITIES if m in modalities)


@dataclass
class MeshPart:
    """One coloured piece of the scene.

    Attributes:
        name: identifier, e.g. "hand", "probe_lens".
        mesh: ``trimesh.Trimesh`` in the world frame, metres.
        label: segmentation label (a ``CLINIC_SEG_LABELS`` value); 0 (background) for scenery that has depth
            but is no object of the dataset, such as a room's walls.
        color: (3,) RGB in [0, 1].
        roughness: PBR roughness in [0, 1].
        smooth: interpolate vertex normals (False shows facets).
        emissive: (3,) RGB in [0, 1] the part gives off by itself, whatever the lights (e.g. a
            marker light); black by default.
    """

    name: str
    mesh: object
    label: int
    color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    roughness: float = 0.7
    metallic: float = 0.0
    smooth: bool = True
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        assert self.label in CLINIC_SEG_LABELS.values(), (self.name, self.label)
        for name in ("color", "emissive"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            assert value.shape == (3,) and np.all((value >= 0) & (value <= 1)), (self.name, name, value)


@dataclass
class PointLight:
    """A point lamp.

    Attributes:
        position_world: (3,) float, metres.
        color: (3,) RGB in [0, 1].
        intensity: pyrender point-light intensity (candela).
    """

    position_world: Sequence[float]
    color: Sequence[float] = (1.0, 1.0, 1.0)
    intensity: float = 2.0

    def __post_init__(self) -> None:
        assert np.shape(self.position_world) == (3,) and np.all(np.isfinite(self.position_world)), self.position_world
        assert np.isfinite(self.intensity) and self.intensity >= 0, self.intensity


@dataclass
class RenderSettings:
    """Per-render appearance that is not part of the geometry."""

    background_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ambient: float = 0.35
    lights: list[PointLight] = field(default_factory=list)


def _colour_shader_cache(pyrender):
    """pyrender's shader cache with :data:`COLOUR_SHADER` as the colour pass's fragment shader."""

    class ColourShaderCache(pyrender.shader_program.ShaderProgramCache):
        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
            if fragment_shader == "mesh.frag":
                fragment_shader = str(COLOUR_SHADER)  # an absolute path: joined to the shader folder, it wins
            return super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)

    return ColourShaderCache()


class Renderer:
    """A reusable offscreen renderer for one image size.

    Build it once per process (the GL context is the expensive part), set the
    scene's parts, then render as many camera poses as needed.

    Args:
        intrinsics: camera intrinsics and image size.
        platform: "egl", "osmesa" or None for automatic (see :mod:`hupbench.datagen.render.gl`).
        shading: the colour pass's shader, one of ``SHADINGS``: "blinn_phong" (ours) or "pbr"
            (pyrender's own).
    """

    def __init__(self, intrinsics: Intrinsics, platform: str | None = None, shading: str = "blinn_phong") -> None:
        assert shading in SHADINGS, shading
        self.platform = gl.configure(platform)
        pyrender = gl.load_pyrender()  # offscreen only: never pyglet's X11 window system
        self._pyrender = pyrender
        self.intrinsics = intrinsics
        self._renderer = pyrender.OffscreenRenderer(intrinsics.width, intrinsics.height)
        self.shading = shading
        if shading == "blinn_phong":
            self._renderer._renderer._program_cache = _colour_shader_cache(pyrender)
        self._scene = pyrender.Scene(bg_color=[1.0, 1.0, 1.0, 1.0], ambient_light=[0.35] * 3)
        camera = pyrender.IntrinsicsCamera(
            intrinsics.fx, intrinsics.fy, intrinsics.cx + GL_PIXEL_CENTRE_OFFSET,
            intrinsics.cy + GL_PIXEL_CENTRE_OFFSET, znear=ZNEAR_M, zfar=ZFAR_M
        )
        self._camera_node = self._scene.add(camera, pose=np.eye(4))
        self._part_nodes: dict[str, object] = {}
        self._labels: dict[object, tuple[int, int, int]] = {}
        self._smooth: dict[str, bool] = {}
        self._light_nodes: list[object] = []

    def set_parts(self, parts: Sequence[MeshPart]) -> None:
        """Replace the scene's meshes.

        Parts are drawn in the order given: where two parts meet at exactly the same depth, the
        earlier one keeps the pixel (its label and colour), in every process.
        """
        pyrender = self._pyrender
        names = [p.name for p in parts]
        assert len(set(names)) == len(names), names
        for node in self._part_nodes.values():
            self._scene.remove_node(node)
        self._part_nodes.clear()
        self._labels.clear()
        self._smooth.clear()
        for rank, part in enumerate(parts):
            material = pyrender.MetallicRoughnessMaterial(
                baseColorFactor=[*part.color, 1.0], roughnessFactor=part.roughness, metallicFactor=part.metallic,
                # pyrender's own shader adds the emissive factor squared, ours adds it once
                emissiveFactor=list(np.sqrt(part.emissive) if self.shading == "pbr" else part.emissive)
            )
            mesh = pyrender.Mesh.from_trimesh(part.mesh, material=material, smooth=part.smooth)
            node = self._scene.add(mesh, name=part.name)
            setattr(node, gl.DRAW_RANK, rank)
            self._part_nodes[part.name] = node
            self._labels[node] = (part.label,) * 3
            self._smooth[part.name] = part.smooth

    def set_part_mesh(self, name: str, mesh) -> None:
        """Replace one part's mesh (a hand whose fingers move, frame by frame), keeping its material, label and
        drawing rank.

        Args:
            name: the part's name. mesh: a ``trimesh.Trimesh``, world frame.
        """
        old = self._part_nodes[name]
        primitive = old.mesh.primitives[0]
        node = self._scene.add(self._pyrender.Mesh.from_trimesh(mesh, material=primitive.material,
                                                                smooth=self._smooth[name]), name=name)
        setattr(node, gl.DRAW_RANK, getattr(old, gl.DRAW_RANK))
        self._scene.remove_node(old)
        self._part_nodes[name] = node
        self._labels[node] = self._labels.pop(old)

    def move_part(self, name: str, T_world_given: np.ndarray) -> None:
        """Move a part rigidly without re-uploading its mesh (a patient under a moving probe, frame by frame).

        Args:
            name: the part's name.
            T_world_given: (4, 4) float, rigid: where the coordinates its mesh was given in (``MeshPart.mesh``,
                world frame at :meth:`set_parts`) now lie in the world; the identity puts it back.
        """
        T = np.asarray(T_world_given, dtype=np.float64)
        assert T.shape == (4, 4) and np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]), T
        self._scene.set_pose(self._part_nodes[name], T)

    def set_color(self, name: str, color: Sequence[float]) -> None:
        """Change a part's base colour without re-uploading its mesh."""
        for primitive in self._part_nodes[name].mesh.primitives:
            primitive.material.baseColorFactor = np.array([*color, 1.0])

    def render(self, T_cam_world: np.ndarray, modalities: Iterable[str] = MODALITIES,
               settings: RenderSettings | None = None, alpha: bool = False) -> dict[str, np.ndarray]:
        """Render the current parts from one camera.

        Args:
            T_cam_world: (4, 4) float, world -> OpenCV camera.
            modalities: any of "rgb", "depth", "seg".
            settings: background, ambient light and lamps; defaults to a white
                background, ambient light and one lamp at the camera.
            alpha: return "rgb" as (H, W, 4) RGBA with alpha 0 on the background,
                for compositing over a photograph.

        Returns:
            dict with the requested keys: "rgb" (H, W, 3) uint8; "depth"
            (H, W) float32 metres, 0 = background; "seg" (H, W) uint8 labels.
        """
        pyrender = self._pyrender
        assert set(modalities) <= set(MODALITIES), modalities
        assert np.shape(T_cam_world) == (4, 4), np.shape(T_cam_world)
        assert self._part_nodes, "set_parts() before render()"
        T_world_cam_gl = swap_gl_cv_axes(invert_transform(T_cam_world))
        self._scene.set_pose(self._camera_node, T_world_cam_gl)
        settings = settings or RenderSettings(lights=[PointLight(T_world_cam_gl[:3, 3], intensity=0.5)])
        self._apply_lights(settings)
        # pyrender writes the background colour's alpha into RGBA output: make it 0 to composite
        self._scene.bg_color = np.array([*settings.background_rgb, 0.0 if alpha else 1.0])

        out: dict[str, np.ndarray] = {}
        depth = None
        if "rgb" in modalities:
            flags = pyrender.RenderFlags.RGBA if alpha else pyrender.RenderFlags.NONE
            color, depth = self._renderer.render(self._scene, flags=flags)
            if alpha and color.shape[-1] == 3:
                # OSMesa has no framebuffer objects and pyrender reads its colour buffer as RGB only:
                # without multisampling, coverage is exactly where the depth buffer was written
                color = np.concatenate([color, np.where(depth > 0, 255, 0).astype(np.uint8)[..., None]], axis=-1)
            out["rgb"] = np.ascontiguousarray(color if alpha else color[..., :3])
        if "seg" in modalities:
            seg, seg_depth = self._renderer.render(
                self._scene, flags=pyrender.RenderFlags.SEG, seg_node_map=self._labels
            )
            out["seg"] = np.ascontiguousarray(seg[..., 0])
            depth = seg_depth if depth is None else depth
        if "depth" in modalities:
            if depth is None:
                depth = self._renderer.render(self._scene, flags=pyrender.RenderFlags.DEPTH_ONLY)
            out["depth"] = np.asarray(depth, dtype=np.float32)
        return out

    def _apply_lights(self, settings: RenderSettings) -> None:
        pyrender = self._pyrender
        self._scene.bg_color = np.array([*settings.background_rgb, 1.0])
        self._scene.ambient_light = np.array([settings.ambient] * 3)
        for node in self._light_nodes:
            self._scene.remove_node(node)
        self._light_nodes = []
        for light in settings.lights:
            pose = np.eye(4)
            pose[:3, 3] = np.asarray(light.position_world, dtype=np.float64)
            node = self._scene.add(pyrender.PointLight(color=np.asarray(light.color), intensity=light.intensity), pose=pose)
            self._light_nodes.append(node)

    def close(self) -> None:
        """Release the GL context."""
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""Headless software renderer of a face surface: z-buffer, shading, texture, supersampling.

The renderer draws the skin (textured by the mesh's canonical uv) together with the
inner parts (eyeballs, mouth cavity, teeth) as one triangle list: triangle ids ``< M``
are skin triangles, ids ``>= M`` are inner triangles ``id - M``. Skin triangles are culled
when back-facing; inner parts are drawn two-sided.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from synth.render.camera import (
    Camera,
    HeadPose,
    apply_pose,
    default_camera,
    pose_matrix,
    project_posed,
)
from synth.render.raster import _normals_kernel, _raster_kernel, _shade_kernel
from synth.render.shading import FLAT_COLOURS, SKIN, SPECULAR, Light, eye_texture

__all__ = ["Renderer", "RenderResult", "Surface"]


@dataclass(frozen=True, eq=False)
class Surface:
    """A minimal mesh for the renderer (a FaceMesh works too: same attribute names).

    Parameters
    ----------
    vertices : (N, 3) rest positions (cm).
    triangles : (M, 3) int, counter-clockwise seen from outside.
    uv : (N, 2) texture coordinates in [0, 1] (u right, v down).
    inner_vertices, inner_triangles, inner_material, inner_uv : optional inner parts.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    inner_vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    inner_triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))
    inner_material: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    inner_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


@dataclass(eq=False)
class RenderResult:
    """One rendered frame and the buffers the ground truth is made from.

    Attributes
    ----------
    image : (H, W, 3) uint8 RGB, or (H, W) uint8 grey
    depth : (H, W) float64, distance from the camera plane in cm (inf on the background)
    triangle_id : (H, W) int32, visible triangle of the combined list (-1 = background)
    barycentric : (H, W, 3) float64, barycentric coordinates of the visible point in its
        3-D triangle (perspective-correct)
    mask : (H, W) bool, any part of the face (skin, eyes, mouth)
    skin_mask : (H, W) bool, skin only
    xy : (N + P, 2) projected vertices (skin then inner), px
    vertex_depth : (N + P,) their depth, cm
    world : (N + P, 3) posed vertex positions, cm (camera space)
    camera : Camera
    pose : HeadPose
    """

    image: np.ndarray
    depth: np.ndarray
    triangle_id: np.ndarray
    barycentric: np.ndarray
    mask: np.ndarray
    skin_mask: np.ndarray
    xy: np.ndarray
    vertex_depth: np.ndarray
    world: np.ndarray
    camera: Camera
    pose: HeadPose


def _background(width: int, height: int, colour) -> np.ndarray:
    """A smooth vertical gradient (static, so its true flow is zero)."""
    c = np.asarray(colour, dtype=np.float64)
    t = np.linspace(0.0, 1.0, height)[:, None, None]
    img = c[None, None, :] * (1.08 - 0.16 * t)
    return np.ascontiguousarray(np.broadcast_to(img, (height, width, 3)), dtype=np.float32)


class Renderer:
    """Render a mesh (skin + inner parts) with a camera, head pose, light and texture.

    Parameters
    ----------
    mesh : FaceMesh or Surface
        Topology, uv and inner parts (``triangles``, ``uv``, optional ``inner_*``).
    texture : (Ht, Wt, 3) array, optional
        Skin albedo in uv space (float in [0, 1] or uint8). Default: flat skin tone.
    camera : Camera, optional
        Default :func:`default_camera` (256 x 256, orthographic).
    light : Light, optional
    supersample : int
        Render at ``supersample`` times the size and area-average down (anti-aliasing).
        The ground-truth buffers are always at the output size.
    grey : bool
        Return single-channel images.
    eye_tex : (h, w, 3) array, optional
        Texture of the eyeballs (default :func:`synth.render.shading.eye_texture`).
    flat_colours : (K, 3) array, optional
        Albedo of the flat-coloured inner materials by material id (default
        :data:`synth.render.shading.FLAT_COLOURS`: mouth cavity and teeth).
    background : tuple of 3 floats, or (H, W, 3) array
        Background colour (RGB in [0, 1]) drawn as a soft vertical gradient, or a
        background image of the camera's size (uint8, or float in [0, 1]), e.g. the scene
        of a photograph; a supersampled frame repeats its pixels, so that the background
        comes back unchanged where nothing covers it.

    Examples
    --------
    >>> surf = Surface(vertices=np.array([[-5.0, -5, 0], [5, -5, 0], [0, 5, 0]]),
    ...                triangles=np.array([[0, 1, 2]]), uv=np.zeros((3, 2)))
    >>> res = Renderer(surf).render(surf.vertices)
    >>> res.image.shape, bool(res.mask[128, 128])
    ((256, 256, 3), True)
    """

    def __init__(self, mesh, *, texture=None, camera: Camera | None = None,
                 light: Light | None = None, supersample: int = 1, grey: bool = False,
                 eye_tex=None, flat_colours=None, background=(0.42, 0.45, 0.50)):
        tris = np.asarray(mesh.triangles, dtype=np.int32)
        if tris.ndim != 2 or tris.shape[1] != 3:
            raise ValueError(f"mesh.triangles must have shape (M, 3), got {tris.shape}")
        uv = np.asarray(mesh.uv, dtype=np.float64)
        self.n_skin = int(uv.shape[0])
        if tris.size and tris.max() >= self.n_skin:
            raise ValueError("mesh.triangles index vertices beyond mesh.uv")
        inner_v = np.asarray(getattr(mesh, "inner_vertices", np.zeros((0, 3))), np.float64)
        inner_t = np.asarray(getattr(mesh, "inner_triangles", np.zeros((0, 3))), np.int32)
        inner_m = np.asarray(getattr(mesh, "inner_material", np.zeros(0)), np.int8)
        inner_uv = np.asarray(getattr(mesh, "inner_uv", np.zeros((0, 2))), np.float64)
        if inner_t.size == 0:
            inner_t = inner_t.reshape(0, 3)
            inner_m = inner_m.reshape(0)
        if inner_uv.size == 0:
            inner_uv = np.zeros((inner_v.shape[0], 2))
        if inner_m.shape[0] != inner_t.shape[0]:
            raise ValueError("mesh.inner_material must have one entry per inner triangle")
        self.n_inner = int(inner_v.shape[0])
        self.n_skin_tris = int(tris.shape[0])
        self.triangles = np.ascontiguousarray(
            np.concatenate([tris, inner_t + self.n_skin]).astype(np.int32))
        self.material = np.ascontiguousarray(
            np.concatenate([np.zeros(len(tris), np.int8), inner_m]).astype(np.int8))
        self.cull = np.ascontiguousarray(self.material == SKIN)
        self.uv = np.ascontiguousarray(np.concatenate([uv, inner_uv]))
        self.mesh = mesh
        self.camera = camera if camera is not None else default_camera()
        if not isinstance(self.camera, Camera):
            raise ValueError("camera must be a synth.render.Camera")
        self.light = light if light is not None else Light()
        if int(supersample) != supersample or supersample < 1 or supersample > 8:
            raise ValueError(f"supersample={supersample} must be an integer in 1..8")
        self.supersample = int(supersample)
        self.grey = bool(grey)
        fc = np.asarray(FLAT_COLOURS if flat_colours is None else flat_colours, np.float64)
        if fc.shape != FLAT_COLOURS.shape:
            raise ValueError(f"flat_colours must have shape {FLAT_COLOURS.shape}, got "
                             f"{fc.shape}")
        self.flat_colours = np.ascontiguousarray(fc)
        self._bg_image = None
        self._bg_cache: dict = {}
        self.set_background(background)
        if texture is None:
            texture = np.full((4, 4, 3), (0.78, 0.60, 0.50))
        self.set_texture(texture)
        et = eye_texture() if eye_tex is None else np.asarray(eye_tex)
        self.eye_tex = np.ascontiguousarray(
            et.astype(np.float32) / (255.0 if et.dtype == np.uint8 else 1.0))
        self._uv_area = None

    def set_background(self, background) -> None:
        """Replace the background: an RGB colour in [0, 1] (a soft vertical gradient) or an
        image of the camera's size (uint8, or float in [0, 1])."""
        if np.ndim(background) == 3:
            bg = np.asarray(background)
            if bg.shape[2] != 3 or bg.shape[:2] != (self.camera.height, self.camera.width):
                raise ValueError(f"background image must have shape ({self.camera.height}, "
                                 f"{self.camera.width}, 3), got {bg.shape}")
            self._bg_image = np.ascontiguousarray(
                bg.astype(np.float32) / (255.0 if bg.dtype == np.uint8 else 1.0))
            self.background = tuple(float(v) for v in self._bg_image.mean(axis=(0, 1)))
        else:
            self._bg_image = None
            self.background = tuple(float(v) for v in background)
        self._bg_cache = {}

    # ---------------------------------------------------------------- texture
    def set_texture(self, texture) -> None:
        """Replace the skin texture (builds its mip pyramid)."""
        tex = np.asarray(texture)
        if tex.ndim != 3 or tex.shape[2] != 3:
            raise ValueError(f"texture must have shape (H, W, 3), got {tex.shape}")
        tex = tex.astype(np.float32) / (255.0 if tex.dtype == np.uint8 else 1.0)
        levels = [np.ascontiguousarray(tex)]
        while min(levels[-1].shape[:2]) >= 8:
            levels.append(np.ascontiguousarray(cv2.pyrDown(levels[-1])))
        self._mips = levels

    def _mip_level(self, xy: np.ndarray) -> int:
        """Pick the pyramid level at which one texel ~ one pixel (global, from areas)."""
        if len(self._mips) == 1 or self.n_skin_tris == 0:
            return 0
        tris = self.triangles[: self.n_skin_tris]
        if self._uv_area is None:
            uv = self.uv
            a = uv[tris[:, 1]] - uv[tris[:, 0]]
            b = uv[tris[:, 2]] - uv[tris[:, 0]]
            self._uv_area = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        p = xy[tris]
        a = p[:, 1] - p[:, 0]
        b = p[:, 2] - p[:, 0]
        area = -(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])   # front faces positive
        front = area > 0
        screen = area[front].sum()
        if screen <= 0:
            return 0
        th, tw = self._mips[0].shape[:2]
        texels = self._uv_area[front].sum() * th * tw
        rho = math.sqrt(texels / screen)
        return int(min(len(self._mips) - 1, max(0, math.floor(math.log2(max(rho, 1e-9))))))

    # ---------------------------------------------------------------- geometry
    def _vertices(self, vertices, inner_vertices) -> np.ndarray:
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != (self.n_skin, 3):
            raise ValueError(f"vertices must have shape ({self.n_skin}, 3), got {v.shape}")
        if self.n_inner:
            if inner_vertices is None:
                inner_vertices = self.mesh.inner_vertices
            iv = np.asarray(inner_vertices, dtype=np.float64)
            if iv.shape != (self.n_inner, 3):
                raise ValueError(f"inner_vertices must have shape ({self.n_inner}, 3), "
                                 f"got {iv.shape}")
            v = np.concatenate([v, iv])
        return v

    def project(self, vertices, inner_vertices=None, pose: HeadPose | None = None,
                camera: Camera | None = None):
        """Posed world positions, image xy and depth of all vertices (skin then inner)."""
        cam = camera or self.camera
        pose = pose or HeadPose()
        v = self._vertices(vertices, inner_vertices)
        world = apply_pose(v, pose)
        xy, depth = project_posed(world, cam)
        return world, xy, depth

    def _buffers(self, xy, depth, cam):
        zbuf = np.full((cam.height, cam.width), np.inf)
        tri_id = np.full((cam.height, cam.width), -1, dtype=np.int32)
        bary = np.empty((cam.height, cam.width, 3))     # only read where tri_id >= 0
        _raster_kernel(xy, depth, self.triangles, self.cull, cam.perspective, zbuf, tri_id,
                       bary)
        return zbuf, tri_id, bary

    def _background_image(self, cam: Camera) -> np.ndarray:
        """Float RGB background of ``cam``'s size (the image, repeated when supersampled)."""
        img = self._bg_image
        if img is None:
            return _background(cam.width, cam.height, self.background)
        h, w = img.shape[:2]
        if (cam.height, cam.width) == (h, w):
            return img
        if cam.height % h or cam.width % w or cam.height // h != cam.width // w:
            raise ValueError(f"camera {cam.width}x{cam.height} is not a whole multiple of "
                             f"the background image's {w}x{h}")
        k = cam.height // h
        return np.ascontiguousarray(np.repeat(np.repeat(img, k, axis=0), k, axis=1))

    def _shade(self, tri_id, bary, world, xy, cam, light: Light, normals, *,
               as_uint8: bool = False) -> np.ndarray:
        key = (cam.width, cam.height, as_uint8)
        bg = self._bg_cache.get(key)
        if bg is None:
            bg = self._background_image(cam)
            if as_uint8:
                bg = np.clip(bg * 255.0 + 0.5, 0, 255).astype(np.uint8)
            self._bg_cache[key] = bg
        image = bg.copy()
        scale, offset, top = (255.0, 0.5, 255.0) if as_uint8 else (1.0, 0.0, np.inf)
        tex = self._mips[self._mip_level(xy)]
        eye_pos = np.array([cam.look_at[0], cam.look_at[1], cam.look_at[2] + cam.distance])
        _shade_kernel(tri_id, bary, self.triangles, self.material, self.uv, normals, world,
                      tex, self.eye_tex, self.flat_colours, light.unit_direction,
                      np.asarray(light.colour, dtype=np.float64), float(light.ambient),
                      SPECULAR * light.specular_scale, float(light.shininess),
                      cam.perspective, eye_pos, image, scale, offset, top)
        return image

    # ---------------------------------------------------------------- render
    def render(self, vertices, inner_vertices=None, *, pose: HeadPose | None = None,
               light: Light | None = None, shade: bool = True) -> RenderResult:
        """Render one frame.

        Parameters
        ----------
        vertices : (N, 3) array_like
            Current skin vertex positions (cm, model space).
        inner_vertices : (P, 3) array_like, optional
            Current inner-part positions (default: the mesh's rest inner vertices).
        pose : HeadPose, optional
        light : Light, optional
            Overrides the renderer's light for this frame (illumination changes).
        shade : bool
            False skips the image (buffers only; ``image`` is None), for ground truth.

        Returns
        -------
        RenderResult
        """
        cam = self.camera
        pose = pose or HeadPose()
        light = light or self.light
        world, xy, depth = self.project(vertices, inner_vertices, pose, cam)
        zbuf, tri_id, bary = self._buffers(xy, depth, cam)
        image = None
        if shade:
            normals = np.empty_like(world)
            _normals_kernel(world, self.triangles, normals)
            if self.supersample > 1:
                k = self.supersample
                cam_k = cam.scaled(k)
                # supersampled image coordinates: pixel centres scale about -0.5
                xy_k = (xy + 0.5) * k - 0.5
                _, tri_k, bary_k = self._buffers(xy_k, depth, cam_k)
                big = self._shade(tri_k, bary_k, world, xy_k, cam_k, light, normals)
                img = cv2.resize(big, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
                if self.grey:
                    img = img @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
                image = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
            else:
                image = self._shade(tri_id, bary, world, xy, cam, light, normals,
                                    as_uint8=True)
                if self.grey:
                    image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        mask = tri_id >= 0
        skin_mask = mask & (tri_id < self.n_skin_tris)
        return RenderResult(image=image, depth=zbuf, triangle_id=tri_id, barycentric=bary,
                            mask=mask, skin_mask=skin_mask, xy=xy, vertex_depth=depth,
                            world=world, camera=cam, pose=pose)

    def rotation(self, pose: HeadPose) -> np.ndarray:
        """Rotation matrix of ``pose`` (model to camera space)."""
        return pose_matrix(pose)

"""A face model's look taken from a photograph of the face it was fitted to.

The photograph is the skin texture: a vertex's texture coordinate is where its rest position
projects into the photograph, so that the rest frame reproduces the photograph pixel for
pixel and every expression moves the subject's own skin.

The photograph already holds the light it was taken in. The texture is therefore the
photograph divided by the model's own shading at rest under a reference light
(``photo / S0``); rendered under that light, the rest frame gives the photograph back, and
when the face moves the shading follows the surface normals (a bulging cheek brightens
where it turns toward the light, a wrinkle darkens): relighting by ratio. Highlights are in
the photograph, so none is added.

What the photograph cannot show is filled in:

- the eyeballs are textured from the photograph's own eyes, projected like the skin, so the
  lids move over them;
- the mouth cavity and teeth are the mesh's flat-coloured inner parts, seen when the jaw
  opens, at the photograph's exposure (the median brightness of its face against the
  procedural faces'; teeth somewhat brighter than the skin);
- the background is the photograph with the face region (and anything beyond the
  photograph's edges) filled in from around it, seen where the face moves away from where it
  was. Hair, ears and neck are in it, so when the head moves the whole background follows
  the head's motion in the image (the similarity that best maps the rest head onto the
  moved one, :meth:`PhotoAppearance.scene_motion`); the ground-truth flow of the background
  is that similarity's;
- skin beyond the photograph's edges (a forehead the frame cut off) takes the photograph
  mirrored at the edge.

:func:`photo_appearance` builds a :class:`PhotoAppearance` from a photograph, the cameras and
the fitted mesh; :func:`synth.render.sequence.synthesize` renders it with ``appearance=``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from synth.render.camera import Camera, HeadPose, apply_pose, project
from synth.render.raster import _normals_kernel
from synth.render.renderer import Renderer, Surface
from synth.render.shading import FLAT_COLOURS, Light

__all__ = ["PhotoAppearance", "photo_appearance", "background_flow", "fill_hole"]

#: Ring (px) of the photograph kept around the face when the background is inpainted: the
#: face's anti-aliased outline blends into the photograph itself, not into the fill.
_KEEP_RING_PX = 3
#: Margin (a fraction of the photograph's larger side) by which the photograph is mirrored
#: beyond its edges for the texture.
_MIRROR_MARGIN = 0.25


@dataclass(frozen=True, eq=False)
class PhotoAppearance:
    """Texture, cameras and background of a face model made from a photograph.

    Attributes
    ----------
    texture : (Ht, Wt, 3) float32
        The photograph divided by the rest shading (RGB, may exceed 1).
    uv : (N, 2) float64
        Texture coordinates of the skin vertices (u right, v down, in [0, 1]).
    inner_uv : (P, 2) float64
        Texture coordinates of the inner vertices (the eyeballs use them).
    camera : Camera
        The output camera (orthographic).
    pose : HeadPose
        Pose of the rest head in that camera (the photograph's in-plane roll).
    background : (H, W, 3) uint8
        The output-size scene behind the head.
    light : Light
        The reference light the texture was divided by (no specular).
    flat_colours : (K, 3) float64
        Albedo of the mouth cavity and teeth (rows by material id).
    source : str
        Where the photograph came from (for the metadata).
    """

    texture: np.ndarray
    uv: np.ndarray
    inner_uv: np.ndarray
    camera: Camera
    pose: HeadPose
    background: np.ndarray
    light: Light
    flat_colours: np.ndarray = field(default_factory=lambda: FLAT_COLOURS.copy())
    source: str = ""

    def surface(self, mesh) -> Surface:
        """``mesh`` with this appearance's texture coordinates."""
        return Surface(vertices=np.asarray(mesh.vertices), triangles=mesh.triangles,
                       uv=self.uv, inner_vertices=mesh.inner_vertices,
                       inner_triangles=mesh.inner_triangles,
                       inner_material=mesh.inner_material, inner_uv=self.inner_uv)

    def renderer(self, mesh, *, supersample: int = 2, grey: bool = False) -> Renderer:
        """A :class:`Renderer` of ``mesh`` with this appearance."""
        return Renderer(self.surface(mesh), texture=self.texture, eye_tex=self.texture,
                        camera=self.camera, light=self.light, supersample=supersample,
                        grey=grey, flat_colours=self.flat_colours,
                        background=self.background)

    def head_pose(self, motion: HeadPose | None = None) -> HeadPose:
        """The head pose that moves the rest head by ``motion`` (about ``motion.centre``).

        At zero motion it is :attr:`pose` itself, so the rest frame stays on the photograph.
        """
        if motion is None:
            return self.pose
        c = np.asarray(motion.centre, dtype=np.float64)
        rest_c = apply_pose(c[None], self.pose)[0]
        shift = rest_c - c + np.asarray(motion.translation, dtype=np.float64)
        return HeadPose(roll=self.pose.roll + motion.roll, yaw=self.pose.yaw + motion.yaw,
                        pitch=self.pose.pitch + motion.pitch,
                        translation=tuple(float(v) for v in shift), centre=motion.centre)

    def scene_motion(self, vertices, pose: HeadPose) -> np.ndarray:
        """2x3 similarity of output pixels that best carries the rest head (``vertices``
        under :attr:`pose`) onto the head under ``pose`` (least squares over the vertices)."""
        a = project(vertices, self.camera, self.pose)[0]
        b = project(vertices, self.camera, pose)[0]
        return _similarity(a, b)

    def scene(self, motion: np.ndarray) -> np.ndarray:
        """The background moved by the 2x3 ``motion`` (:meth:`scene_motion`)."""
        if np.allclose(motion, [[1, 0, 0], [0, 1, 0]]):
            return self.background
        return cv2.warpAffine(self.background, np.asarray(motion, np.float64),
                              (self.camera.width, self.camera.height),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def light_for(self, light: Light) -> Light:
        """``light`` without its highlights (the photograph holds them)."""
        return replace(light, specular_scale=0.0)


def _similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """2x3 least-squares similarity (scale, rotation, translation) taking points a to b."""
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    pa, pb = a - ma, b - mb
    za = pa[:, 0] + 1j * pa[:, 1]
    zb = pb[:, 0] + 1j * pb[:, 1]
    den = float(np.vdot(za, za).real)
    k = np.vdot(za, zb) / den if den > 0 else 1.0 + 0j
    R = np.array([[k.real, -k.imag], [k.imag, k.real]])
    return np.c_[R, mb - R @ ma]


def background_flow(motion_t: np.ndarray, motion_t1: np.ndarray, width: int, height: int
                    ) -> np.ndarray:
    """Flow (H, W, 2) of a background moved by ``motion_t`` at frame t and ``motion_t1`` at
    t+1 (2x3 similarities of the rest scene, :meth:`PhotoAppearance.scene_motion`)."""
    A0 = np.vstack([motion_t, [0.0, 0.0, 1.0]])
    A1 = np.vstack([motion_t1, [0.0, 0.0, 1.0]])
    M = (A1 @ np.linalg.inv(A0))[:2]
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    fx = M[0, 0] * x + M[0, 1] * y + M[0, 2] - x
    fy = M[1, 0] * x + M[1, 1] * y + M[1, 2] - y
    return np.stack([fx, fy], axis=-1).astype(np.float32)


def _check_photo(photo) -> np.ndarray:
    img = np.asarray(photo)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"photo must be an (H, W, 3) uint8 RGB image, got "
                         f"{img.dtype} {img.shape}")
    return img


def _rest_shading(surface: Surface, vertices, inner_vertices, camera: Camera,
                  pose: HeadPose, light: Light) -> tuple[np.ndarray, np.ndarray]:
    """Shading of a white surface at rest (float, (H, W)) and where the face is."""
    white = np.ones((4, 4, 3), np.float32)
    r = Renderer(surface, texture=white, eye_tex=white, camera=camera, light=light,
                 background=(0.0, 0.0, 0.0))
    world, xy, depth = r.project(vertices, inner_vertices, pose, camera)
    _, tri_id, bary = r._buffers(xy, depth, camera)
    normals = np.empty_like(world)
    _normals_kernel(world, r.triangles, normals)
    shade = r._shade(tri_id, bary, world, xy, camera, light, normals)
    return shade[..., 0].astype(np.float32), tri_id >= 0


def _fill_outside(values: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """``values`` with every pixel outside ``inside`` set to its nearest inside value."""
    from scipy.ndimage import distance_transform_edt

    if inside.all() or not inside.any():
        return values
    _, (iy, ix) = distance_transform_edt(~inside, return_indices=True)
    return values[iy, ix]


def _photo_to_output(photo_camera: Camera, camera: Camera) -> np.ndarray:
    """2x3 affine map of photograph pixels to output pixels (both orthographic)."""
    k = camera.scale / photo_camera.scale
    (pcx, pcy), (ocx, ocy) = photo_camera.centre, camera.centre
    dx = camera.scale * (photo_camera.look_at[0] - camera.look_at[0])
    dy = -camera.scale * (photo_camera.look_at[1] - camera.look_at[1])
    return np.array([[k, 0.0, ocx - k * pcx + dx], [0.0, k, ocy - k * pcy + dy]])


def photo_appearance(mesh, photo, photo_camera: Camera, *, pose: HeadPose | None = None,
                     camera: Camera | None = None, vertices=None, inner_vertices=None,
                     light: Light | None = None, source: str = "") -> PhotoAppearance:
    """The look of ``mesh`` (fitted to ``photo``) taken from the photograph.

    Parameters
    ----------
    mesh : FaceMesh
        The mesh fitted to the face in the photograph (its rest positions project onto
        the face through ``photo_camera`` and ``pose``).
    photo : (H, W, 3) uint8
        The photograph (RGB).
    photo_camera : Camera
        Orthographic camera of the photograph's size that places the mesh on the face.
    pose : HeadPose, optional
        The head's pose in the photograph (in-plane roll; default identity).
    camera : Camera, optional
        Orthographic output camera (another size or crop of the same view); default
        ``photo_camera``.
    vertices, inner_vertices : array_like, optional
        Rest positions of the skin and inner parts (default the mesh's own).
    light : Light, optional
        Reference light (default :class:`Light`); renders under it reproduce the
        photograph at rest.
    source : str
        Where the photograph came from.

    Returns
    -------
    PhotoAppearance

    Examples
    --------
    >>> from synth.render import default_camera
    >>> surf = Surface(vertices=np.array([[-5.0, -8, 0], [5, -8, 0], [0, 5, 0]]),
    ...                triangles=np.array([[0, 1, 2]]), uv=np.zeros((3, 2)))
    >>> photo = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    >>> look = photo_appearance(surf, photo, default_camera(64, 64))
    >>> rest = look.renderer(surf, supersample=1).render(surf.vertices)
    >>> int(np.abs(rest.image.astype(int) - photo).max())   # the photograph comes back
    0
    """
    img = _check_photo(photo)
    if not isinstance(photo_camera, Camera) or photo_camera.perspective:
        raise ValueError("photo_camera must be an orthographic synth.render.Camera")
    if (photo_camera.height, photo_camera.width) != img.shape[:2]:
        raise ValueError(f"photo_camera is {photo_camera.width}x{photo_camera.height}, the "
                         f"photo {img.shape[1]}x{img.shape[0]}")
    camera = photo_camera if camera is None else camera
    if not isinstance(camera, Camera) or camera.perspective:
        raise ValueError("a photographed face renders through an orthographic camera; "
                         "camera must be an orthographic synth.render.Camera")
    pose = HeadPose(centre=(0.0, 0.0, 0.0)) if pose is None else pose
    light = replace(light if light is not None else Light(), specular_scale=0.0)
    v = np.asarray(mesh.vertices if vertices is None else vertices, dtype=np.float64)
    iv = np.asarray(mesh.inner_vertices if inner_vertices is None else inner_vertices,
                    dtype=np.float64).reshape(-1, 3)
    H, W = img.shape[:2]
    # the photograph mirrored beyond its edges, so that skin or scene the frame cut off
    # (a forehead above the top edge) gets plausible texture instead of smeared edge pixels
    pad = int(math.ceil(_MIRROR_MARGIN * max(H, W)))
    padded = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_REFLECT_101)
    padded_camera = replace(photo_camera, width=W + 2 * pad, height=H + 2 * pad)
    size = np.array([W + 2 * pad, H + 2 * pad], dtype=np.float64)
    uv = (project(v, padded_camera, pose)[0] + 0.5) / size
    inner_uv = ((project(iv, padded_camera, pose)[0] + 0.5) / size if len(iv)
                else np.zeros((0, 2)))
    look = PhotoAppearance(texture=np.zeros((1, 1, 3), np.float32), uv=uv, inner_uv=inner_uv,
                           camera=camera, pose=pose, background=np.zeros((1, 1, 3), np.uint8),
                           light=light, source=str(source))
    surface = look.surface(mesh)
    shade, face = _rest_shading(surface, v, iv, padded_camera, pose, light)
    shade = _fill_outside(np.maximum(shade, 1e-3), face)
    texture = padded.astype(np.float32) / 255.0 / shade[..., None]
    # the scene behind the head, in the output camera: the photograph with the face
    # (less an outline ring) and whatever lies beyond the photograph's edges filled in
    M = _photo_to_output(photo_camera, camera)
    out_size = (camera.width, camera.height)
    scene = cv2.warpAffine(img, M, out_size, flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
    beyond = cv2.warpAffine(np.ones((H, W), np.uint8), M, out_size, flags=cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0) == 0
    out_face = Renderer(surface, camera=camera).render(v, iv, pose=pose, shade=False).mask
    ring = max(1, int(math.ceil(_KEEP_RING_PX * max(1.0, camera.scale / photo_camera.scale))))
    hole = cv2.erode(out_face.astype(np.uint8), np.ones((2 * ring + 1,) * 2, np.uint8)) > 0
    if (hole | beyond).any():
        scene = fill_hole(scene, hole | beyond)
    inside = face[pad:pad + H, pad:pad + W]
    return replace(look, texture=np.ascontiguousarray(texture), background=scene,
                   flat_colours=_inner_colours(img, inside))


#: Luminance of the procedural faces' skin, the exposure the flat colours are made for.
_PROCEDURAL_SKIN_LUMA = 0.72
#: Teeth are brighter than skin: their brightness relative to the face's median.
_TEETH_OVER_SKIN = 1.4


def _inner_colours(photo: np.ndarray, face: np.ndarray) -> np.ndarray:
    """Flat colours of the mouth cavity and teeth at the photograph's exposure."""
    luma = cv2.cvtColor(photo, cv2.COLOR_RGB2GRAY)[face]
    gain = float(np.clip(np.median(luma) / 255.0 / _PROCEDURAL_SKIN_LUMA, 0.3, 1.2)
                 if luma.size else 1.0)
    out = FLAT_COLOURS.copy()
    out[2] *= gain
    out[3] *= min(1.0, gain * _TEETH_OVER_SKIN)
    return out


def fill_hole(image: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """``image`` with the pixels under ``hole`` filled smoothly from around it (push-pull:
    the known pixels are averaged down a Gaussian pyramid until the hole closes, then the
    coarse averages are blended back up), so that a large hole gets the soft colours of
    its surroundings rather than the streaks of a diffusion inpainting.

    Examples
    --------
    >>> img = np.zeros((32, 32, 3), np.uint8); img[:, 16:] = 200
    >>> hole = np.zeros((32, 32), bool); hole[8:24, 8:24] = True
    >>> out = fill_hole(img, hole)
    >>> int(out[16, 9, 0]) < 100 < int(out[16, 22, 0]), (out[~hole] == img[~hole]).all()
    (True, np.True_)
    """
    hole = np.asarray(hole, dtype=bool)
    if not hole.any() or hole.all():
        return image.copy()
    known = (~hole).astype(np.float32)
    levels = [(image.astype(np.float32) * known[..., None], known)]
    while levels[-1][1].min() <= 0 and min(levels[-1][1].shape) > 2:
        iw, w = levels[-1]
        levels.append((cv2.pyrDown(iw), cv2.pyrDown(w)))
    iw, w = levels[-1]
    fill = iw / np.maximum(w, 1e-6)[..., None]
    for iw, w in reversed(levels[:-1]):
        up = cv2.pyrUp(fill, dstsize=(w.shape[1], w.shape[0]))
        alpha = np.clip(w, 0.0, 1.0)[..., None]
        fill = alpha * (iw / np.maximum(w, 1e-6)[..., None]) + (1.0 - alpha) * up
    out = image.copy()
    out[hole] = np.clip(fill[hole] + 0.5, 0, 255).astype(image.dtype)
    return out

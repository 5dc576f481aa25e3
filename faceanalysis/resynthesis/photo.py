"""Photo-real synthetic faces: the face model fitted to a photograph and textured with it.

:func:`photo_face` makes a :class:`PhotoFace` from a frontal, neutral photograph:

1. the landmark tracker (MediaPipe's face mesh holding the contours,
   :class:`trackers.AnchoredTracker`) finds the face, its head frame and its 11 fiducials;
2. the face model is deformed to the face (Kähler 001, ch. 8;
   :func:`~faceanalysis.resynthesis.personalize.fit_to_points`): the 11 fiducials, the eye
   corners, nose tip, subnasale and the lips' vermilion centres of the face mesh
   (:data:`MESH_LANDMARKS`) drive a 3-D radial-basis warp of the whole structure;
3. the photograph becomes the model's skin (:func:`synth.render.appearance.photo_appearance`):
   projected onto the fitted mesh, divided by the model's rest shading so that the rest
   frame is the photograph and expressions are relit by ratio, with the eyeballs textured
   from the photograph's eyes, a dark mouth cavity and teeth behind the lips, and the
   photograph with the face inpainted behind the head.

:func:`synthesize_face` renders any contraction script on it with the same exact ground truth
as the procedural faces (:func:`synth.render.sequence.synthesize`), and :func:`render_face`
writes it like ``faceanalysis synth``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from faceanalysis.io.table import FIDUCIALS
from faceanalysis.resynthesis.framing import Framing, framing_from_head, head_reference
from faceanalysis.resynthesis.personalize import _read_frame, fit_to_points

log = logging.getLogger(__name__)

__all__ = ["MESH_LANDMARKS", "OPTIONAL_FIDUCIALS", "PhotoFace", "photo_face", "synthesize_face",
           "render_face"]

#: Model landmarks (:data:`synth.face_mesh.LANDMARK_NAMES`) placed on the face-mesh point of
#: the landmark tracker (MediaPipe's 468-point topology) when a photograph is fitted,
#: beside the 11 fiducials: the eye corners (so the eyelids open over the photographed
#: eyes), the nose tip and subnasale, and the centres of the lips' vermilion borders (so
#: the lips part where the photographed mouth does). ``_l`` is the subject's left.
MESH_LANDMARKS: dict[str, int] = {
    "eye_inner_l": 362, "eye_outer_l": 263, "eye_inner_r": 133, "eye_outer_r": 33,
    "nose_tip": 1, "subnasale": 2, "lip_upper_centre": 0, "lip_lower_centre": 17,
}

#: Fiducials a photograph may lack, and the fit then goes without. The top of the nasolabial
#: furrow often shows no edge on a neutral face and the tracker marks its contour lost (the
#: subnasale, nose tip and mouth corners around it still hold the warp). The chin boss has
#: no outline on some chins and its contour may be lost too; the lips' and mouth corners'
#: points then place the fitted chin (on IMM people 21-26 fitted without their tracked chin,
#: 1.4-6.5 px from it, where the chin lies 34-41 px below the mouth).
OPTIONAL_FIDUCIALS: frozenset[str] = frozenset({"furrow_top_l", "furrow_top_r", "chin"})


@dataclass(eq=False)
class PhotoFace:
    """The face model fitted to a photograph, with the photograph's look.

    Attributes
    ----------
    model : synth.model.FaceModel
        The fitted model (animatable).
    appearance : synth.render.appearance.PhotoAppearance
        Texture, output camera, pose and background.
    photo : (H, W, 3) uint8
        The photograph (RGB).
    framing : Framing
        Model-to-photograph similarity.
    landmark_error_px : dict
        Landmark name -> distance (photograph px) between the fitted model's landmark and
        the tracked point it was fitted to.
    source : str
        The photograph's path.
    """

    model: object
    appearance: object
    photo: np.ndarray
    framing: Framing
    landmark_error_px: dict = field(default_factory=dict)
    source: str = ""

    def report(self) -> dict:
        """What the fit did, for ``meta.json``."""
        err = np.array(list(self.landmark_error_px.values()), float)
        return {"photo": self.source, "photo_size": [int(self.photo.shape[1]),
                                                     int(self.photo.shape[0])],
                "landmarks": sorted(self.landmark_error_px),
                "landmark_error_px": {"mean": float(err.mean()) if err.size else None,
                                      "max": float(err.max()) if err.size else None}}


def _tracked_points(path: Path) -> tuple[np.ndarray, dict]:
    """Head frame and named image points of the face in the photograph at ``path``."""
    from faceanalysis.tracking import track

    tracks = track(path, end=1, tracker="landmarks")
    if len(tracks) == 0 or not tracks.success[0] or tracks.landmarks[0] is None:
        raise ValueError(f"{path}: no face found in the photograph")
    fid = tracks.fiducials[0]
    missing = [n for n, p in zip(FIDUCIALS, fid) if not np.isfinite(p).all()]
    required = [n for n in missing if n not in OPTIONAL_FIDUCIALS]
    if required:
        raise ValueError(f"{path}: the face's {', '.join(required)} could not be placed")
    if missing:
        log.warning("%s: the face's %s could not be placed (no edge there on the neutral "
                    "face?); fitted without", path, ", ".join(missing))
    points = {n: fid[i] for i, n in enumerate(FIDUCIALS) if n not in missing}
    mesh = np.asarray(tracks.landmarks[0], dtype=float)
    points.update({name: mesh[i, :2] for name, i in MESH_LANDMARKS.items()})
    return np.asarray(tracks.heads[0], dtype=float), points


def _output_camera(size, photo_camera, pose, fill: float):
    """The orthographic camera that frames the fitted face at ``size`` like the
    procedural faces (:func:`synth.render.default_camera`), from the same view."""
    from dataclasses import replace

    from synth.render.camera import DEFAULT_LOOK_AT, apply_pose, default_camera

    w, h = (size, size) if np.isscalar(size) else size
    base = default_camera(int(w), int(h), fill=fill)
    look = apply_pose(np.array([DEFAULT_LOOK_AT], float), pose)[0]
    return replace(photo_camera, width=base.width, height=base.height, scale=base.scale,
                   focal=base.scale * photo_camera.distance,
                   look_at=(float(look[0]), float(look[1]), float(photo_camera.look_at[2])))


def photo_face(photo, *, size=None, model=None, fill: float = 0.75,
               kernel: str = "linear") -> PhotoFace:
    """Fit the face model to a frontal, neutral photograph and take its look.

    Parameters
    ----------
    photo : path-like
        An image file (png, jpg, tif, bmp, webp) with one face, frontal, at rest.
    size : int or (width, height), optional
        Output size: the face is framed like the procedural faces (the hairline-to-chin
        height fills ``fill`` of the image, centred). Default: the photograph itself, at
        its own size and framing.
    model : FaceModel, optional
        The model to fit (default :meth:`synth.model.FaceModel.default`).
    fill : float
        Fraction of the output height the face fills, with ``size``.
    kernel : {'linear', 'gaussian'}
        Radial basis of the warp.

    Returns
    -------
    PhotoFace

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not an image, no face found, or the face cannot be fitted.
    """
    from faceanalysis.io.video import IMAGE_SUFFIXES
    from synth.render.appearance import photo_appearance

    path = Path(photo)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such photograph")
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        raise ValueError(f"{path}: not a photograph; give an image file "
                         f"({', '.join(IMAGE_SUFFIXES)})")
    if not 0 < fill <= 2:
        raise ValueError(f"fill={fill} must be in (0, 2]")
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    image = _read_frame(path, 0)
    head, points = _tracked_points(path)
    origin_cm, scale_cm = head_reference(model.mesh)
    framing = framing_from_head(head, origin_cm, scale_cm)
    personal, _ = fit_to_points(model, framing, points, kernel=kernel)
    personal.reset()
    personal.set_contractions(None)
    rest = np.asarray(personal.equilibrate(), dtype=np.float64)
    inner = np.asarray(personal.inner_vertices(), dtype=np.float64)
    lm = personal.landmark_positions()
    err = {n: float(np.hypot(*(framing.apply(np.asarray(lm[n], float)[None])[0] - p)))
           for n, p in points.items()}
    H, W = image.shape[:2]
    photo_camera, pose = framing.camera_pose(W, H)
    camera = None if size is None else _output_camera(size, photo_camera, pose, fill)
    look = photo_appearance(personal.mesh, image, photo_camera, pose=pose, camera=camera,
                            vertices=rest, inner_vertices=inner, source=str(path))
    return PhotoFace(model=personal, appearance=look, photo=image, framing=framing,
                     landmark_error_px=err, source=str(path))


def synthesize_face(face, **kwargs):
    """Render a contraction script on a photographed face, with exact ground truth.

    Parameters
    ----------
    face : PhotoFace or path-like
        A :class:`PhotoFace`, or a photograph to fit (:func:`photo_face`; ``size`` and
        ``fill`` are passed to it).
    **kwargs
        :func:`synth.render.sequence.synthesize` options (``expression``, ``au``,
        ``contractions``, ``frames``, ``head_motion``, ``illumination``, ``noise``, ...).

    Returns
    -------
    synth.render.SyntheticSequence
        Its ``meta["identity"]["photo"]`` says how the face was fitted.
    """
    from synth.render.sequence import synthesize

    if not isinstance(face, PhotoFace):
        face = photo_face(face, size=kwargs.pop("size", None), fill=kwargs.pop("fill", 0.75))
    elif "fill" in kwargs:
        raise ValueError("fill frames a photograph when it is fitted; this face is fitted "
                         "already (give photo_face(..., fill=) instead)")
    face.model.reset()
    seq = synthesize(model=face.model, appearance=face.appearance, **kwargs)
    seq.meta["identity"]["photo"] = face.report()
    return seq


def render_face(face, out_dir, *, overwrite: bool = False, flow_dtype: str = "float32",
                **kwargs) -> dict:
    """:func:`synthesize_face` written to ``out_dir`` like ``faceanalysis synth``
    (``video.mp4``, ``truth.csv``, ``flow.npz``, ``meta.json``)."""
    from synth.files import prepare_output_dir
    from synth.render.sequence import write_sequence

    out = prepare_output_dir(out_dir, overwrite=overwrite)   # fail before the long render
    seq = synthesize_face(face, **kwargs)
    return write_sequence(seq, out, overwrite=overwrite, flow_dtype=flow_dtype)

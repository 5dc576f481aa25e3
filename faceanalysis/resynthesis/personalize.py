"""The face model deformed to the analysed subject's neutral frame (Kähler 001, ch. 8;
:mod:`synth.personalize`), textured with that frame."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from faceanalysis.io.outputs import CONTRACTIONS_CSV
from faceanalysis.io.table import FIDUCIALS
from faceanalysis.resynthesis.framing import Framing, framing_from_head, head_reference
from faceanalysis.resynthesis.series import Series, load_series, series_from_table

log = logging.getLogger(__name__)

#: fewest of the 11 fiducials the neutral frame must show for the landmark warp: a contour
#: lost there (a furrow, a brow under hair) leaves its point to the model, but the warp
#: must still span the face
MIN_FIDUCIALS = 8


# ----------------------------------------------------------------------------- subject
@dataclass
class SubjectInfo:
    """A personalised model and how it was made.

    Attributes
    ----------
    model : FaceModel
        The warped model.
    warp : synth.personalize.LandmarkWarp
    framing : Framing
        Model-to-image similarity of the subject's neutral frame (input pixels).
    image : (H, W, 3) uint8 RGB
        The neutral frame (the texture).
    fiducials : (11, 2)
        Neutral fiducials (input px); NaN for one not seen there.
    neutral_frame : int
    reference : tuple
        ``(origin_cm, scale_cm)`` of the generic model's head frame.
    """

    model: object
    warp: object
    framing: Framing
    image: np.ndarray
    fiducials: np.ndarray
    neutral_frame: int
    reference: tuple
    source: str = ""
    head: np.ndarray | None = None

    def uv(self) -> tuple[np.ndarray, np.ndarray]:
        """Texture coordinates of the skin and inner vertices in the neutral frame."""
        H, W = self.image.shape[:2]
        mesh = self.model.mesh
        skin = self.framing.apply(np.asarray(mesh.vertices))
        inner = self.framing.apply(np.asarray(mesh.inner_vertices)) \
            if len(mesh.inner_vertices) else np.zeros((0, 2))
        size = np.array([W, H], float)
        return (skin + 0.5) / size, (inner + 0.5) / size


def _read_frame(path: Path, index: int) -> np.ndarray:
    """Frame ``index`` of a video (RGB uint8)."""
    import cv2

    from faceanalysis.io.frames import to_bgr_uint8
    from faceanalysis.io.video import open_video

    with open_video(path, start=int(index), end=int(index) + 1) as src:
        for frame in src:
            if frame.ok:
                return cv2.cvtColor(to_bgr_uint8(frame.image), cv2.COLOR_BGR2RGB)
    raise ValueError(f"{path}: frame {index} could not be read")


def personalize(subject, *, model=None, kernel: str = "linear") -> SubjectInfo:
    """Warp ``model`` (the generic face by default) to the subject's neutral frame.

    Parameters
    ----------
    subject : Analysis, path of an analysis folder, or path of a video
        A video is analysed first (its first frame is the neutral one).
    model : FaceModel, optional
    kernel : {'linear', 'gaussian'}
        Radial basis of the warp (:func:`synth.personalize.fit_landmark_warp`).

    Returns
    -------
    SubjectInfo

    Raises
    ------
    ValueError
        The subject has no tracked fiducials or head frame, its video cannot be found, or
        the landmarks fold the warp.
    """
    series, video = subject_series(subject)
    return personalize_series(series, video, model=model, kernel=kernel)


def personalize_series(series: Series, video, *, model=None, kernel: str = "linear"
                        ) -> SubjectInfo:
    if series.fiducials is None or series.heads is None:
        raise ValueError("the subject's table has no fiducials or head frame columns")
    if model is None:
        from synth.model import FaceModel

        model = FaceModel.default()
    k = series.neutral_row
    fid = series.fiducials[k]
    seen = np.isfinite(fid).all(axis=1)
    if seen.sum() < MIN_FIDUCIALS:
        raise ValueError(f"the subject's neutral frame {series.frames[k]} has {int(seen.sum())} "
                         f"of its {len(FIDUCIALS)} fiducials (the warp needs "
                         f"{MIN_FIDUCIALS}): give another --neutral frame to the analysis")
    if not seen.all():
        # a contour lost on the neutral frame: the warp carries the model's own point there
        log.info("personalisation: %s not seen on the neutral frame %d; the warp carries the "
                 "face model's own", ", ".join(np.array(FIDUCIALS)[~seen]),
                 int(series.frames[k]))
    if video is None or not Path(video).exists():
        raise ValueError(f"the subject's video {video} cannot be found (needed for the "
                         "texture); pass the video itself as the subject")
    origin_cm, scale_cm = head_reference(model.mesh)
    framing = framing_from_head(series.heads[k], origin_cm, scale_cm)
    points = {name: xy for name, xy, ok in zip(FIDUCIALS, fid, seen) if ok}
    personal, warp = fit_to_points(model, framing, points, kernel=kernel)
    image = _read_frame(Path(video), int(series.frames[k]))
    return SubjectInfo(model=personal, warp=warp, framing=framing, image=image,
                       fiducials=fid, neutral_frame=int(series.frames[k]),
                       reference=(origin_cm, scale_cm), source=str(video),
                       head=np.array(series.heads[k], dtype=float))


def fit_to_points(model, framing: Framing, points: dict, *, kernel: str = "linear"):
    """Warp ``model`` so that its named landmarks land on image ``points`` (Kähler 001, ch. 8).

    Parameters
    ----------
    model : FaceModel
    framing : Framing
        Model-to-image similarity of the image (from its head frame).
    points : dict
        Landmark name (:meth:`synth.model.FaceModel.landmark_positions`) -> image (x, y).
    kernel : {'linear', 'gaussian'}

    Returns
    -------
    (FaceModel, synth.personalize.LandmarkWarp)

    Raises
    ------
    ValueError
        A name the model does not have, or no warp down to an affine one gives a valid
        model.
    """
    from synth.personalize import personalize_in_plane

    lm = model.landmark_positions()
    unknown = sorted(set(points) - set(lm))
    if unknown:
        raise ValueError(f"the model has no landmark {unknown[0]!r}; it has "
                         f"{', '.join(sorted(lm))}")
    names = list(points)
    src = np.array([lm[n] for n in names], dtype=float)
    xy = framing.invert(np.array([points[n] for n in names], dtype=float))
    try:
        personal, warp, blend = personalize_in_plane(model, src, xy, kernel=kernel)
    except ValueError as exc:
        raise ValueError("the subject's neutral landmarks cannot be fitted by the face model "
                         f"(every warp, down to an affine one, failed: {exc})") from None
    if blend < 1.0:
        log.warning("personalisation: the model follows the subject's landmarks at %.0f%% "
                    "only (see the landmark error in the report)", 100 * blend)
    return personal, warp


def subject_series(subject) -> tuple[Series, Path | None]:
    from faceanalysis.analysis.pipeline import Analysis, analyze

    if isinstance(subject, Analysis):
        s = series_from_table(subject.table, "subject", subject.metadata)
        return s, s.input_path
    path = Path(subject)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such subject video or analysis folder")
    if path.is_dir() and (path / CONTRACTIONS_CSV).is_file():
        s = load_series(path)
        return s, s.input_path
    log.info("analysing the subject's first frame in %s", path)
    a = analyze(path, end=1)
    return series_from_table(a.table, str(path), a.metadata), path


def personal_model(folder: str | Path, model):
    """The face model personalised to the subject of the analysis in ``folder``
    (:func:`personalize`, the 3-D landmark warp), or None with a warning when that is not
    possible (the video cannot be found, a bad warp): callers then warp in 2-D instead."""
    try:
        return personalize(folder, model=model).model
    except (ValueError, FileNotFoundError) as exc:
        log.warning("personalised model not available (%s); warping the generic "
                    "resynthesis in 2-D instead", exc)
        return None

"""Is the neutral frame at rest? The checks of the neutral frame, their warnings, and the one
frame they offer instead.

Every value is measured from the neutral frame. Four things on it bias every value and are
told: a coarsely coded picture (an encoder's first pictures; measured by the pipeline,
``blocky``), raised brows, an open mouth and a widened one, as in a smile
(:mod:`faceanalysis.estimation.neutral_check`). Where one warns, all offer the same frame
instead, the nearest that passes every check (:func:`check_neutral`), which
``analyze(neutral="auto")`` moves the neutral frame to.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from faceanalysis.io.video import is_photographs

log = logging.getLogger(__name__)

__all__ = ["NeutralCheck", "check_neutral", "mouth_measures"]


@dataclass(frozen=True)
class NeutralCheck:
    """What the checks of one neutral frame found.

    Attributes
    ----------
    row : int
        The neutral frame's row in the tracks.
    blockiness : float or None
        Its blockiness over the next two seconds' (None: not measured).
    coarse : bool
        Coarsely coded (checked for a neutral frame not given).
    clean : int or None
        The first frame coded like the rest, where ``coarse``.
    shares : dict
        Per frontalis, the share of frames whose free fit reads it below the neutral
        frame (:func:`~faceanalysis.estimation.neutral_check.below_neutral`).
    lowest : int or None
        The row where the brows read lowest.
    lips_apart : float or None
        The lips' gap over the clip's closed level
        (:func:`~faceanalysis.estimation.neutral_check.open_mouth`).
    closed : int or None
        The row nearest the neutral frame with the lips closed.
    mouth_wider : float or None
        The mouth corners' distance over the clip's rest level
        (:func:`~faceanalysis.estimation.neutral_check.wide_mouth`).
    advice : tuple (frame, str) or None
        The frame nearest the neutral frame that passes every check, and what it passes.
    """

    row: int
    blockiness: float | None = None
    coarse: bool = False
    clean: int | None = None
    shares: dict = field(default_factory=dict)
    lowest: int | None = None
    lips_apart: float | None = None
    closed: int | None = None
    mouth_wider: float | None = None
    advice: tuple[int, str] | None = None

    @property
    def raised(self) -> list[str]:
        """The frontalis controls read raised on the neutral frame."""
        from faceanalysis.estimation.neutral_check import BELOW_SHARE

        return [c for c, s in self.shares.items() if s >= BELOW_SHARE]

    @property
    def mouth_open(self) -> bool:
        from faceanalysis.estimation.neutral_check import MOUTH_OPEN

        return self.lips_apart is not None and self.lips_apart > MOUTH_OPEN

    @property
    def mouth_wide(self) -> bool:
        from faceanalysis.estimation.neutral_check import MOUTH_WIDE

        return self.mouth_wider is not None and self.mouth_wider > MOUTH_WIDE

    @property
    def reasons(self) -> list[str]:
        """What the checks found on the neutral frame (empty: nothing)."""
        return ([r for r, found in (("coarsely coded", self.coarse),
                                    ("brows raised", bool(self.raised)),
                                    ("mouth open", self.mouth_open),
                                    ("mouth widened", self.mouth_wide)) if found])

    def calibration(self) -> dict:
        """The ``calibration`` entries of ``analysis.json``."""
        return {
            "neutral_blockiness": None if self.blockiness is None else round(self.blockiness, 3),
            "below_neutral": {c: round(s, 3) for c, s in self.shares.items()},
            "neutral_lips_apart": None if self.lips_apart is None else round(self.lips_apart, 4),
            "neutral_mouth_wider": (None if self.mouth_wider is None
                                    else round(self.mouth_wider, 4)),
            "offered_neutral": (self.advice[0] if self.advice is not None and self.reasons
                                else None),
        }

    def warn(self, video, tracks, *, how: str) -> None:
        """Log a warning for each finding; ``how`` the neutral frame was picked
        (``"default"``, ``"given"``, ``"chosen"``)."""
        from faceanalysis.estimation.neutral_check import BELOW

        frame = int(tracks.frames[self.row])
        if self.coarse:
            log.warning("%s: the neutral frame %d is a coarsely coded picture (its 8-px code "
                        "blocks show %.2f times as much as in the next two seconds, as in an "
                        "encoder's first pictures): every value is measured from it and "
                        "biased by it; %s", video, frame, self.blockiness,
                        self._offer() if self.advice is not None else
                        "give a later frame where the face is at rest (--neutral N)"
                        if self.clean is None else
                        f"if the face is at rest there, frame {self.clean}, the first coded "
                        f"like the rest, is a better neutral frame (--neutral {self.clean})")
        raised = self.raised
        if raised:
            lowest = int(tracks.frames[self.lowest])
            one = len(raised) == 1
            log.warning("%s: the brows may be raised on the %s neutral frame %d: on %.0f %% "
                        "of the tracked frames %s read%s more than %.2f of %s range below "
                        "it, so %s measured from raised brows, not from rest, and read%s "
                        "short; %s", video, how, frame,
                        100 * max(self.shares[c] for c in raised), ", ".join(raised),
                        "s" if one else "", BELOW, "its" if one else "their",
                        "it is" if one else "they are", "s" if one else "",
                        self._offer() if self.advice is not None else
                        f"frame {lowest}, where the brows read lowest, may be nearer rest "
                        f"(--neutral {lowest})")
        if self.mouth_open:
            closed = None if self.closed is None else int(tracks.frames[self.closed])
            log.warning("%s: the mouth is open on the %s neutral frame %d (its lips %.2f "
                        "inter-ocular distances farther apart than on the clip's closed "
                        "frames): the lower face is measured from an open mouth, not from "
                        "rest; %s", video, how, frame, self.lips_apart,
                        self._offer() if self.advice is not None else
                        "give a frame where the face is at rest (--neutral N)"
                        if closed is None else
                        f"frame {closed}, where the lips are closed, may be nearer rest "
                        f"(--neutral {closed})")

        if self.mouth_wide:
            log.warning("%s: the mouth is widened on the %s neutral frame %d (its corners "
                        "%.2f inter-ocular distances farther apart than on the clip's rest "
                        "frames, as in a smile): the lower face is measured from it, not "
                        "from rest, and a later smile reads short; %s", video, how, frame,
                        self.mouth_wider,
                        self._offer() if self.advice is not None else
                        "give a frame where the face is at rest (--neutral N)")

    def _offer(self) -> str:
        frame, passes = self.advice
        return f"frame {frame}, {passes}, may be nearer rest (--neutral {frame})"


def mouth_measures(tracks) -> np.ndarray | None:
    """Each frame's lip gap and mouth width, shape (T, 2)
    (:func:`~trackers.landmark_contours.lip_gap`,
    :func:`~trackers.landmark_contours.mouth_width`; NaN where lost); None without the face
    mesh or for photographs."""
    from trackers.landmark_contours import lip_gap, mouth_width

    if is_photographs(tracks.input) or tracks.landmarks is None:
        return None
    out = np.full((len(tracks.success), 2), np.nan)
    rows = [t for t, (m, ok) in enumerate(zip(tracks.landmarks, tracks.success))
            if ok and m is not None]
    if rows:
        p = np.stack([np.asarray(tracks.landmarks[t], dtype=float)[:, :2] for t in rows])
        out[rows] = np.c_[lip_gap(p), mouth_width(p)]
    return out


def check_neutral(est, tracks, k: int, *, blocky=None, coarse: bool = False,
                  mouth=None) -> NeutralCheck:
    """Check the neutral frame (row ``k``) of ``tracks`` as estimated by ``est``.

    Parameters
    ----------
    est : Estimate
        The estimate against row ``k`` (its displacements, response and fit weights).
    tracks : Tracks
    k : int
    blocky : tuple (float, int or None), optional
        The neutral frame's blockiness over the next two seconds' and the first frame
        coded like them (``pipeline._blocky_neutral``); None where not measured.
    coarse : bool
        Whether ``blocky`` makes it a coarsely coded picture.
    mouth : ndarray, shape (T, 2), optional
        :func:`mouth_measures`; None: the mouth is not checked.

    Returns
    -------
    NeutralCheck
        Photographs are not checked for the brows or the mouth, nor offered a frame.
        The offer: the frame nearest row ``k`` with the brows down
        (:func:`~faceanalysis.estimation.neutral_check.brows_down`), the lips closed and
        the mouth not widened (:func:`~faceanalysis.estimation.neutral_check.closed_lips`,
        :func:`~faceanalysis.estimation.neutral_check.narrow_mouth`, where ``mouth``) and,
        where ``coarse``, no earlier than the first frame coded like the rest (frames
        past the second the blockiness was measured over are taken as coded like it).
    """
    from faceanalysis.estimation.neutral_check import (
        MOUTH_WIDER,
        below_neutral,
        brows_down,
        closed_lips,
        free_fit,
        narrow_mouth,
        nearest,
        open_mouth,
        wide_mouth,
    )

    check = {"row": k, "coarse": coarse}
    if blocky is not None:
        check["blockiness"], check["clean"] = blocky[0], blocky[1] if coarse else None
    if is_photographs(tracks.input):
        return NeutralCheck(**check)
    # one free fit for both the check of the brows and the offer's
    fit = free_fit(est.displacements, est.response, weights=est.fit_options.get("weights"))
    check["shares"], check["lowest"] = below_neutral(est.displacements, est.response, fit=fit)
    if mouth is not None:
        check["lips_apart"], check["closed"] = open_mouth(mouth[:, 0], k)
        check["mouth_wider"] = wide_mouth(mouth[:, 1], k)
    allowed = brows_down(est.displacements, est.response, fit=fit)
    allowed &= np.asarray(tracks.success, bool)
    passes = "with the brows down"
    if mouth is not None:
        gaps, widths = mouth[:, 0], mouth[:, 1]
        # a grimace or a smile can close the lips: the mouth's width tells them
        closed, narrow = closed_lips(gaps), narrow_mouth(widths)
        allowed &= closed & narrow
        if closed[k] and narrow[k]:
            # the neutral frame's mouth is at rest: not traded for a wider one (a clip
            # without rest, whose levels are its expressions')
            allowed &= widths <= widths[k] + MOUTH_WIDER / 2
        passes += " and the mouth closed, not widened"
    if coarse:
        first = int(tracks.frames[k])
        clean = (blocky[1] if blocky[1] is not None
                 else first + 1 + round(float(tracks.input.get("fps") or 0)))
        allowed &= np.asarray(tracks.frames) >= clean
        passes = "coded like the rest, " + passes
    allowed[k] = False
    row = nearest(allowed, k)
    if row is not None:
        check["advice"] = (int(tracks.frames[row]), passes)
    return NeutralCheck(**check)

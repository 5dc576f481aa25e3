"""Track the nine facial contours through a sequence (004 V-C).

Each frame's contours start from the previous frame's equilibrium and slide downhill
in the new potential until the root-mean-square node displacement in a step falls
below ``tol`` pixels (equilibrium by a movement threshold, never a fixed number of
iterations; ``max_iter`` is only a safety cap). On the first frame the largest
node displacement must fall below ``tol``. All nine
contours form one :class:`~trackers.snakes.ContourSystem`, separated by
``a_i = b_i = 0``, whose matrix is factored once for the whole sequence.

Per frame and per contour the tracker reports a quality:

* ``depth``: mean depth ``-P`` of the potential under the nodes, relative to the
  depth on the first frame (1 = as well anchored as at the start);
* ``stretch``: contour length relative to the first frame (and, where the head frame is
  given, to the head's size: a face that comes nearer the camera does not stretch);
* ``shape``: change of shape since the first frame (similarity-invariant residual
  over the length);
* ``lost``: depth below ``lost_depth`` (divided by how much larger a given head frame is
  than the first: an edge seen larger is spread over more pixels, its gradient shallower),
  stretch outside ``stretch_range``, shape change above ``max_shape_change``, or nodes that
  left the image. A lost contour
  is re-initialised from the layout (moved with the head frame) and relaxed again
  within the same frame; it stays flagged lost only if that fails too.

Ends. A free end of a contour on a dark line creeps inward, to where the ravine
stops deepening, which leaves it short of the feature's true end by about
``2 * sigma``. For contours whose ends are fiducials (brows, furrows, upper lip)
the tracker therefore relocates each end, after relaxation, on the feature's end:
it samples the potential along the contour's end tangent and puts the end where
the ravine has risen to half its depth (the end of a blurred line), then inset by
the line's half-width measured across it (so the end lies on the centre line,
e.g. the centre of a round-capped eyebrow stroke), and redistributes the nodes
evenly. Where the ravine runs on past the line's end (the furrows' tops run into the
shading beside the nose, where the ravine of the face model's renders ran on up to
6 px) the end is instead the half-level point of the strongest step of the grey
level along the line, inset by the half-width (``ends='line'``, see
:func:`~trackers.contour_ends.refine_end`). This is recorded in
``LayoutContour.ends`` and can be switched off.

Image forces act along the contour normal only (``Contour.normal_forces``): along
an uneven ravine (a tapering eyebrow) the tangential part of eq. 12 would slide the
nodes toward its deepest spot and, rest lengths being viscoelastic, shrink the contour.

Image-force strength. ``strength='auto'`` (default) keeps the paper's parameters for
tension, rigidity, viscoelasticity and damping, and sets each contour's ``p`` on
the first frame so that a node descends its ravine at a fixed fraction
(``descent_rate``) of the remaining distance per step (from the ravine's measured
curvature). The paper's ``p = 0.001`` was tuned for its own ~1-pixel filter;
``strength='paper'`` uses that value scaled to each contour's ``sigma`` with
:func:`~trackers.snakes.paper_equivalent_strength`, and a float sets ``p`` directly.
"""

from __future__ import annotations

import numpy as np

from trackers.anchors import similarity_from_pairs
from trackers.contour_ends import (
    _CORNER_FAN,
    _move_end_nb,
    _refine_end_nb,
    _steady_end,
    _trim_start_nb,
)
from trackers.contour_fields import ContourFields
from trackers.fiducials import HeadFrame, apex_fraction, brow_axis_frame, fiducials
from trackers.head_motion import FeatureAnchors
from trackers.head_search import HeadFrameSearch, _apply_similarity, _ContourHead
from trackers.layout import CONTOUR_NAMES, FaceLayout, detect_layout
from trackers.mouth import mouth_corners
from trackers.polyline import resample_polyline
from trackers.quality import ContourQuality, TrackResult, _polyline_length, _shape_change
from trackers.sampling import sample_or_nan
from trackers.snake_types import Contour, SnakeParams
from trackers.snakes import ContourSystem, paper_equivalent_strength

#: Default arc-length fraction (from the inner end) of ``brow_mid_*`` along an eyebrow
#: contour (see :class:`Tracker`, ``brow_mid``).
BROW_MID_FRACTION = 0.556

#: The eyebrows' valley potential is taken at this multiple of their layout ``sigma``
#: while they relax (see :class:`Tracker`, ``brow_band``).
BROW_BAND = 1.5

__all__ = ["BROW_BAND", "BROW_MID_FRACTION", "REINIT_EVERY", "Tracker"]


#: A contour lost on many consecutive frames is re-placed at least this often (frames).
REINIT_EVERY = 16


def _retry_now(streak: int) -> bool:
    """Re-place a contour lost for ``streak`` consecutive frames now? On the 1st, 2nd,
    4th, 8th... lost frame, then every :data:`REINIT_EVERY` frames."""
    if streak <= 0:
        return False
    if streak <= REINIT_EVERY:
        return streak & (streak - 1) == 0
    return streak % REINIT_EVERY == 0


def _off_feature(ref, P, ox, oy) -> bool:
    """Whether the first node of ``ref`` lies off the ravine its contour follows: the
    potential there is less than a quarter as deep as the median along the contour."""
    v = sample_or_nan(P, ref, (ox, oy))
    mid = np.nanmedian(v)
    return bool(mid < 0 and np.isfinite(v[0]) and v[0] > 0.25 * mid)


class Tracker(HeadFrameSearch, ContourFields):
    """Track a :class:`~trackers.layout.FaceLayout` through frames.

    Parameters
    ----------
    layout : FaceLayout
        Contours placed on the first frame to be tracked.
    params : SnakeParams, optional
        Tension, rigidity, viscoelasticity, damping (004 V-E values by default).
    strength : 'auto', 'paper' or float
        Image-force strength (see the module docstring).
    descent_rate : float
        Fraction of the distance to the ravine bottom covered per step with
        ``strength='auto'``.
    tol : float
        Movement threshold that defines equilibrium: root-mean-square node
        displacement in a step, pixels.
    max_iter : int
        Safety cap on steps per frame.
    first_max_iter : int
        Cap on the first frame, where the contours move farthest.
    lost_depth : float
        Relative depth under which a contour is lost.
    stretch_range : (float, float)
        Relative lengths outside which a contour is lost.
    refine_ends : bool
        Relocate ends on feature ends for the contours whose layout asks for it.
    max_step : float
        Cap on a node's move per step, pixels (a guard against a too strong image
        force; it does not change equilibria).
    max_shape_change : float
        Largest change of shape (see :class:`~trackers.quality.ContourQuality`) before
        a contour is lost.
    brow_mid : float or 'apex'
        Where ``brow_mid_*`` sits along each eyebrow contour, as an arc-length
        fraction from the inner end (default :data:`BROW_MID_FRACTION` = 0.556).
        One definition for everyone: the brow's centre is the top of its arch,
        where the frontalis major lifts it; the face model puts its ``brow_mid``
        landmark there (the apex of the brow curve, about midway between the ends
        along the face's surface), which on its renders lies at 0.556 +- 0.01 of the
        brow's *image* arc length (five identities; the outer brow turns away from
        the camera and is foreshortened). Finding that apex on every face instead
        ('apex': a parabola fitted to the contour on the first frame, its fraction
        kept afterwards) is ill-conditioned on a flat arch: on the model's renders
        it lands 1.6-3.5 px away (mean 2.5 px over six expression sequences,
        against 1.1 px for the fixed fraction). A fixed fraction also follows the
        same piece of brow whatever the expression does to the arch.
    channel_order : {'rgb', 'bgr'}
    mouth_corner : {'profile', 'ends'}
        'profile' (default): ``mouth_corner_*`` are the lateral ends of the dark
        mouth line or cavity found by :func:`~trackers.mouth.mouth_corners` around the upper-lip
        contour (with the mouth open the contour follows a border of the cavity and
        its ends fall short of the corners); where no clear end is found the last
        corner is kept, moved with the head frame. 'ends': the contour's ends (004).
        'snap': the contour's ends, each moved onto the end of the dark region that
        'profile' finds when that lies within ``corner_reach`` of it (for contours
        whose ends are held by landmarks: the image refines them where it shows the
        corner, and cannot pull them onto another feature).
    corner_reach : float
        With ``mouth_corner='snap'``: the farthest a corner is moved from the
        contour's end, as a fraction of the first frame's mouth width.
    corner_follow, corner_cap : float
        With ``mouth_corner='snap'``: a corner farther than ``corner_reach`` from the
        contour's end is still taken when it lies within ``corner_follow`` of the last
        frame's corner and within ``corner_cap`` of the end (fractions of the mouth
        width); ``corner_follow=0`` (default) turns this off.
    redetect : bool
        When three or more contours have been lost for three frames in a row, detect
        the face again (:func:`~trackers.layout.detect_layout`, at most every
        ``redetect_interval`` frames) and place all contours from it; kept only if
        fewer contours are lost afterwards. The head frame stays the irises' or the
        features' when they give it on that frame; otherwise it is the first frame's
        moved by the similarity between the two detections' eyes
        (``extra['head_source'] == 'detection'``).
    redetect_interval : int
        Least number of frames between two detections; doubled (up to 16 times)
        after each detection that finds no face or does not help.
    springs : float or dict name -> float or per-node array, optional
        Stiffness of the springs that pull each contour's nodes toward the target
        curves given to :meth:`track` (``Contour.spring``; relative to the damping
        ``gamma/dt`` = 0.5 of each step). Without targets the springs hold the nodes
        where they were last placed; None or 0 (default): free snakes, as in 004.
    replace_lost : collection of str, optional
        The contours re-placed when they are lost (each re-placement costs a second
        relaxation of the frame); all by default. One left out stays where it is,
        reported lost, until it finds its feature again.
    end_hold : float
        Hysteresis, in each contour's sigma, on where along its line a relocated end
        lies, for contours with springs: the end keeps its last place along the line
        (carried by its spring target) while the end found lies within ``end_hold``
        sigma of it, or none is found; across the line it follows the image. A line
        that fades out has no sharp end, and the one found depends on where the search
        starts. 0 (default) relocates the ends afresh on every frame.
    brow_band : float
        Scale of the eyebrows' valley potential while they relax, as a multiple of
        their layout ``sigma`` (default :data:`BROW_BAND`); their ends are still
        found on the potential at ``sigma``. At the scale ``s`` a dark band narrower
        than ``2 sqrt(3) s`` (about 3.5 s) has one ravine along its centre, one that
        wide a flat-bottomed one, and a wider one a ravine along each edge. Eyebrows
        are about that wide at the layout's ``sigma``, and widen as the frontalis
        stretches the skin: there the contour stays wherever it was pushed (on the
        face model's raised brows it lagged by up to a third of the rise, and held on
        as they fell) or rides one edge. At 1.5 ``sigma`` bands up to about 5
        ``sigma`` wide have one central ravine. 1 relaxes the brows at ``sigma``.
    head_anchor : {'auto', 'eyes', 'features', 'contours'}
        How the head frame follows the head after the first frame. The first frame's
        frame is always :func:`~trackers.fiducials.head_frame` of the contours (004:
        hairline and nose). 'contours' recomputes it from the contours on every
        frame, as 004 does; but expressions move the hairline and the nostrils (in
        the face model the frontalis lifts the hairline ~2 mm in surprise, the
        nostrils move ~3 mm), so that frame moves with the expression and biases
        every fiducial displacement measured in it, and a contour that slides onto
        another feature (a hand) swings it. 'eyes' moves the first frame's frame by
        a similarity: scale and translation from the two irises
        (:class:`~trackers.anchors.IrisAnchors`; eyeballs sit in the skull),
        rotation from the turn of the line between the eyebrows' centroids (level
        under symmetric expressions; the irises' own line when a brow is lost). On
        frames where an iris is not found (closed eyes, occlusion) corner features
        on the eyes and nose take over (:class:`~trackers.head_motion.
        FeatureAnchors`, seeded on the last frame the irises gave; the irises are
        then looked for every :data:`~trackers.head_search.
        IRIS_RETRY_EVERY` frames); where those do not
        agree either, the contours' frame-to-frame motion is chained on to the last
        frame the irises or features gave. 'features': the features alone, from the
        first frame on. 'auto' (default): 'eyes' when the layout has eye centres and
        both irises are found on the first frame, else 'features' when it has eye
        centres, else 'contours'. ``TrackResult.extra['head_source']`` says which
        was used per frame ('eyes', 'features', 'contours' or 'detection').

    Examples
    --------
    >>> import numpy as np, cv2
    >>> from trackers.layout import layout_from_eyes
    >>> img = np.full((256, 256), 200, np.uint8)
    >>> lay = layout_from_eyes((96, 105), (159, 105), (256, 256))
    >>> for c in lay.contours.values():
    ...     _ = cv2.polylines(img, [np.round(c.points).astype(np.int32)], c.closed, 60, 3)
    >>> res = Tracker(lay).track(img)
    >>> sorted(res.fiducials)[:2], res.success
    (['brow_inner_l', 'brow_inner_r'], True)
    """

    def __init__(self, layout: FaceLayout, *, params: SnakeParams | None = None,
                 strength="auto", descent_rate: float = 0.3, tol: float = 0.01,
                 max_iter: int = 100, first_max_iter: int = 2000, lost_depth: float = 0.3,
                 stretch_range=(0.6, 1.6), refine_ends: bool = True,
                 max_step: float = 1.0, brow_mid=BROW_MID_FRACTION, max_shape_change: float = 0.15,
                 channel_order: str = "rgb", head_anchor: str = "auto",
                 mouth_corner: str = "profile", redetect: bool = True,
                 redetect_interval: int = 15, springs=None, corner_reach: float = 0.06,
                 corner_follow: float = 0.0, corner_cap: float = 0.2, replace_lost=None,
                 end_hold: float = 0.0, brow_band: float = BROW_BAND):
        if not isinstance(layout, FaceLayout):
            raise ValueError(f"layout must be a FaceLayout, got {type(layout).__name__}")
        if params is None:
            params = SnakeParams()
        ok = strength in ("auto", "paper") or (
            isinstance(strength, int | float | np.floating | np.integer)
            and not isinstance(strength, bool) and np.isfinite(strength) and strength > 0)
        if not ok:
            raise ValueError(f"strength must be 'auto', 'paper' or a positive number, got "
                             f"{strength!r}")
        if not 0 < descent_rate < 1.5:
            raise ValueError(f"descent_rate must be in (0, 1.5), got {descent_rate}")
        if not 0 <= lost_depth < 1:
            raise ValueError(f"lost_depth must be in [0, 1), got {lost_depth}")
        lo, hi = stretch_range
        if not 0 < lo < 1 < hi:
            raise ValueError(f"stretch_range must be (lo < 1 < hi), got {stretch_range}")
        if channel_order not in ("rgb", "bgr"):
            raise ValueError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
        if not (isinstance(brow_mid, str) and brow_mid == "apex") and not (
                isinstance(brow_mid, int | float) and 0.0 <= brow_mid <= 1.0):
            raise ValueError(f"brow_mid must be 'apex' or a fraction in [0, 1], got "
                             f"{brow_mid!r}")
        self.brow_mid = brow_mid
        if head_anchor not in ("auto", "eyes", "features", "contours"):
            raise ValueError(f"head_anchor must be 'auto', 'eyes', 'features' or 'contours', "
                             f"got {head_anchor!r}")
        if head_anchor in ("eyes", "features") and layout.eyes is None:
            raise ValueError(f"head_anchor={head_anchor!r} needs a layout with eye centres")
        self.head_anchor = head_anchor
        if mouth_corner not in ("profile", "ends", "snap"):
            raise ValueError(f"mouth_corner must be 'profile', 'ends' or 'snap', got "
                             f"{mouth_corner!r}")
        if not np.isfinite(corner_reach) or corner_reach <= 0:
            raise ValueError(f"corner_reach must be positive, got {corner_reach}")
        if not (np.isfinite(corner_follow) and corner_follow >= 0
                and np.isfinite(corner_cap) and corner_cap > 0):
            raise ValueError(f"corner_follow must be >= 0 and corner_cap positive, got "
                             f"{corner_follow} and {corner_cap}")
        self.mouth_corner_mode = mouth_corner
        self.corner_reach = float(corner_reach)
        self.corner_follow = float(corner_follow)
        self.corner_cap = float(corner_cap)
        self.mouth_width: float | None = None
        if int(redetect_interval) < 1:
            raise ValueError(f"redetect_interval must be >= 1, got {redetect_interval}")
        self.redetect = bool(redetect)
        self.redetect_interval = int(redetect_interval)
        self._failing = 0
        self._last_detect = 0
        self._redetect_wait = self.redetect_interval
        self._sim_cache: tuple | None = None
        # a head frame from elsewhere for this frame, where the irises are not found
        self._fallback_head: HeadFrame | None = None
        self._corners_head: dict[str, np.ndarray] = {}
        self._corner_misses: dict[str, int] = {}
        self.anchors = None
        self.features: FeatureAnchors | None = None
        self._feature_base: HeadFrame | None = None
        self._last_gray: np.ndarray | None = None
        self._last_gray_index = -1
        self._feature_index = -1
        self._feature_cache: tuple = (-1, None)
        # the contours' head frame (a _ContourHead) on the last frame whose head frame
        # came from elsewhere, and that head frame: where the contours' motion is
        # chained on from
        self._anchor_base: tuple[_ContourHead, HeadFrame] | None = None
        self._ref_brow_angle: float | None = None
        self._brows_lost = False
        self._head_contours_lost = False
        self._held = 0
        self.head_source = "contours"
        if not np.isfinite(max_shape_change) or max_shape_change <= 0:
            raise ValueError(f"max_shape_change must be positive, got {max_shape_change}")
        self.max_shape_change = float(max_shape_change)
        self.layout = layout
        self.params = params
        self.strength_mode = strength
        self.descent_rate = float(descent_rate)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.first_max_iter = int(first_max_iter)
        self.lost_depth = float(lost_depth)
        self.stretch_range = (float(lo), float(hi))
        names = tuple(layout.contours)
        if replace_lost is None:
            replace_lost = names
        unknown = sorted(set(replace_lost) - set(names))
        if unknown:
            raise ValueError(f"replace_lost names unknown contours {unknown}; choose from "
                             f"{', '.join(names)}")
        self.replace_lost = frozenset(replace_lost)
        self.refine_ends = bool(refine_ends)
        if not np.isfinite(end_hold) or end_hold < 0:
            raise ValueError(f"end_hold must be >= 0, got {end_hold}")
        self.end_hold = float(end_hold)
        # (contour, end) -> the last relocated end's offset from that end's spring target
        self._held_ends: dict[tuple[str, int], np.ndarray] = {}
        self.channel_order = channel_order
        self.names = list(CONTOUR_NAMES)
        self._lost_streak = dict.fromkeys(self.names, 0)
        if not np.isfinite(brow_band) or brow_band < 1:
            raise ValueError(f"brow_band must be >= 1, got {brow_band}")
        self.brow_band = float(brow_band)
        # the potentials the contours relax on, and (where they differ) those their
        # ends are found on
        self.end_specs = [(layout.contours[n].kind, float(layout.contours[n].sigma))
                          for n in self.names]
        self.specs = [(kind, sig * self.brow_band if n in ("brow_l", "brow_r") else sig)
                      for n, (kind, sig) in zip(self.names, self.end_specs)]
        self._end_only = [k for k, (a, b) in enumerate(zip(self.specs, self.end_specs))
                          if a != b]
        self._end_fields: dict[int, np.ndarray] = {}
        if springs is None or isinstance(springs, int | float):
            springs = dict.fromkeys(self.names, float(springs or 0.0))
        unknown = sorted(set(springs) - set(self.names))
        if unknown:
            raise ValueError(f"springs for unknown contours {unknown}; choose from "
                             f"{', '.join(self.names)}")
        if not all(np.all(np.isfinite(v)) and np.all(np.asarray(v) >= 0)
                   for v in springs.values()):
            raise ValueError(f"spring stiffnesses must be finite and >= 0, got {springs}")
        self.springs = {n: springs.get(n, 0.0) for n in self.names}
        contours = []
        for name, (_, sig) in zip(self.names, self.specs):
            c = layout.contours[name]
            p0 = paper_equivalent_strength(sig, params.p) if strength in ("auto", "paper") \
                else float(strength)
            contours.append(Contour(c.points, closed=c.closed, params=params, p=p0,
                                    field=len(contours), name=name, normal_forces=True,
                                    spring=self.springs[name]))
        self.system = ContourSystem(contours, params, max_step=max_step)
        self.sigma_max = max(sig for _, sig in self.specs)
        self.index = 0
        self.ref_depth: dict[str, float] = {}
        self.ref_length: dict[str, float] = {}
        self.ref_shape: dict[str, np.ndarray] = {}
        self.ref_head: HeadFrame | None = None
        self.brow_fraction: dict[str, float] | None = None
        self.last_head: HeadFrame | None = None
        self.frame_size = tuple(layout.image_size)
        self._clipped: set[int] = set()
        iod = layout.inter_eye
        self.motion_margin = max(6.0, 0.08 * iod) + 2.0 * self.sigma_max


    # ------------------------------------------------------------------ helpers

    def _refine(self, Ps, origins, gray, gorigin, settle=False):
        """Relocate the contours' ends on their features' ends (``LayoutContour.ends``).

        ``settle`` (True for every contour, or the names of some) marks contours just
        placed: their ends may be cut back farther than a frame's motion, and they
        start without held ends. With ``end_hold``, the end of a contour with spring
        targets keeps its last relocated place along the line (carried by its target)
        while the end found on this frame lies within ``end_hold`` sigma of it along the
        line, or none is found.
        """
        if not self.refine_ends:
            return
        X, st = self.system.X, self.system.starts
        anchor = self.system.anchor
        placed = set(self.names) if settle is True else set(settle or ())
        g = np.ascontiguousarray(gray, dtype=np.float32)
        gox, goy = float(gorigin[0]), float(gorigin[1])
        for k, name in enumerate(self.names):
            c = self.layout.contours[name]
            if c.ends == "free" or self.system.frozen[k]:
                continue
            fresh = name in placed
            hold = self.end_hold > 0 and np.any(self.springs[name])
            if hold and fresh:
                for end in (0, -1):
                    self._held_ends.pop((name, end), None)
            pts = X[st[k]:st[k + 1]]
            n = len(pts)
            new = pts
            P = np.ascontiguousarray(self._end_fields.get(k, Ps[k]), dtype=np.float32)
            ox, oy = origins[k]
            sigma = float(c.sigma)
            for end in (0, -1):
                mode = c.end_modes[0 if end == 0 else 1]
                if mode == "free":
                    continue
                # refine_end without its checks: same kernel, same arguments
                ref = np.ascontiguousarray(new if end == 0 else new[::-1])
                args = (P, float(ox), float(oy), sigma, mode == "centre", g, gox, goy, True,
                        _CORNER_FAN if mode == "corner" else 0.0, mode == "line")
                ok, x, y = _refine_end_nb(ref, *args)
                if (not ok and fresh and mode == "centre"
                        and _off_feature(ref, P, float(ox), float(oy))):
                    # a band just placed may overshoot its end (a mesh's brow running
                    # on past a thin brow's tail): the end's reference depth, taken
                    # 1-2.5 sigma inside, is then skin and no end is found. Search
                    # again from further inside
                    for cut in (2.5 * sigma, 5.0 * sigma):
                        inner = _trim_start_nb(ref, cut)
                        if len(inner) < 4:
                            break
                        ok, x, y = _refine_end_nb(inner, *args)
                        if ok:
                            break
                if ok:
                    x, y = _steady_end(ref, x, y, args, sigma, fresh)
                target = anchor[st[k] if end == 0 else st[k + 1] - 1]
                held = self._held_ends.get((name, end)) if hold else None
                if held is not None:
                    # where a feature fades out (a brow's tail into the temple) the end
                    # found along the line depends on where the search starts, and
                    # relocating it each frame cycled it by 4-8 px on a still face. The
                    # end's place along the line is held (carried by its target), its
                    # place across the line is the image's.
                    hx, hy = target + held
                    j = min(3, len(ref) - 1)
                    tx, ty = ref[0] - ref[j]
                    tn = max(np.hypot(tx, ty), 1e-9)
                    tx, ty = tx / tn, ty / tn
                    if ok:
                        along = (x - hx) * tx + (y - hy) * ty
                        if abs(along) <= self.end_hold * sigma:
                            x, y = x - along * tx, y - along * ty
                    else:
                        along = (hx - ref[0, 0]) * tx + (hy - ref[0, 1]) * ty
                        ok, x, y = True, ref[0, 0] + along * tx, ref[0, 1] + along * ty
                if not ok:
                    continue
                ref = _move_end_nb(ref, x, y, sigma, fresh)
                if ref.shape[0] == 0:
                    continue
                if hold:
                    self._held_ends[(name, end)] = np.array([x, y]) - target
                new = ref if end == 0 else ref[::-1]
            if new is not pts:
                self.system.set_contour(k, resample_polyline(new, n), reset_rest=True)

    def _n_nodes(self, k):
        sl = self.system.contour_slice(k)
        return sl.stop - sl.start

    def _set_targets(self, targets):
        """Resampled target curves (name -> (n, 2)) for the contours ``targets`` names."""
        out = {}
        W, H = self.frame_size
        for k, name in enumerate(self.names):
            curve = targets.get(name)
            if curve is None:
                continue
            curve = np.asarray(curve, float)
            n = self._n_nodes(k)
            if len(curve) != n:   # a curve of the contour's own nodes is taken as it is
                curve = resample_polyline(curve, n, closed=self.layout.contours[name].closed)
            pts = np.clip(curve, 0, [W - 1, H - 1])
            self.system.set_targets(k, pts)
            out[name] = pts
        return out

    def _snaps(self, c, end, prev, reach, scale) -> bool:
        """Whether the image's corner ``c`` replaces the contour's ``end`` (``'snap'``):
        when it lies within ``reach`` of the end, or when it follows the last frame's
        accepted corner (``prev``, within ``corner_follow`` of the mouth width) and
        stays within ``corner_cap`` of the end. The second rule keeps a corner that the
        image shows clearly while the landmarks drift from it (an opening mouth), and
        the cap bounds how far it can take the corner from them."""
        if c is None:
            return False
        d = float(np.hypot(*(c - end)))
        if d <= reach:
            return True
        return (prev is not None and d <= self.corner_cap * scale
                and float(np.hypot(*(c - prev))) <= self.corner_follow * scale)

    def _layout_points(self, k, head):
        """Layout contour ``k`` moved by the similarity between the first and this frame."""
        name = self.names[k]
        c = self.layout.contours[name]
        n = self._n_nodes(k)
        pts = resample_polyline(c.points, n, closed=c.closed)
        if self.ref_head is not None and head is not None:
            pts = head.to_image(self.ref_head.to_head(pts))
        W, H = self.frame_size
        return np.clip(pts, 0, [W - 1, H - 1])

    def _redetect(self, frame, n_lost, anchored=None):
        """Place all contours again from a new face detection (many contours lost for
        several frames: a turned head, a hand over the face). Kept only when fewer
        contours are lost afterwards; returns (quality, head, iterations) or None.
        ``anchored``: this frame's head frame when the irises or the features gave it;
        it is kept rather than replaced by the detection's."""
        # faces much smaller than the tracked one are not searched for (the Haar
        # cascade's cost is in its small scales); the contours' own relaxation then
        # fits the template, so the detector's grid refinement is skipped
        iod = self.layout.inter_eye
        if self.last_head is not None and self.ref_head is not None:
            iod *= self.last_head.scale / self.ref_head.scale
        try:
            new = detect_layout(frame, frame_index=self.index,
                                channel_order=self.channel_order, refine=True,
                                min_face=max(40, int(1.2 * iod)))
        except ValueError:
            self._redetect_wait = min(2 * self._redetect_wait, 16 * self.redetect_interval)
            return None
        if new.eyes is None or self.layout.eyes is None or self.ref_head is None:
            return None
        saved = [self.system.contour_points(k).copy() for k in range(len(self.names))]
        for k, name in enumerate(self.names):
            c = new.contours[name]
            n = self.system.contour_slice(k).stop - self.system.contour_slice(k).start
            self.system.set_contour(k, resample_polyline(c.points, n, closed=c.closed),
                                    reset_rest=True)
        Ps, origins, gray, gorigin = self._fields(frame)
        r = self.system.relax(potentials=Ps, origin=origins, tol=self.tol,
                              max_iter=self.max_iter, criterion="rms")
        self._refine(Ps, origins, gray, gorigin, settle=True)
        depths = self._depths(Ps, origins)
        quality = self._quality(depths, r.outside, set(self.names))
        if sum(q.lost for q in quality.values()) >= n_lost:
            for k, pts in enumerate(saved):
                self.system.set_contour(k, pts, reset_rest=True)
            # no better: try again later, less and less often
            self._redetect_wait = min(2 * self._redetect_wait, 16 * self.redetect_interval)
            return None
        self._redetect_wait = self.redetect_interval
        if anchored is not None:
            # the irises or features followed the head through whatever lost the
            # contours; two detections' eyes (Haar boxes, or where the face box puts
            # them) turned WolfgangLanger's frame by 5 and 3.5 degrees at frames 136
            # and 231, for the rest of the video
            head = anchored
        else:
            # the first frame's moved by the similarity between the eyes of the two
            # detections; the features are seeded again on this frame from it
            a, b = similarity_from_pairs(self.layout.eyes, new.eyes)
            head = _apply_similarity(self.ref_head, a, b)
            self.head_source = "detection"
            if self.anchors is not None:
                self._move_iris_search(head)
            self.features = None
            self._feature_cache = (self.index, head)
            self._keep_gray(frame)
        # the contours' later motion is chained on from here
        self._anchor_base = (_ContourHead(self.system, self.names), head)
        self._held = 0
        self._brows_lost = quality["brow_l"].lost or quality["brow_r"].lost
        self._head_contours_lost = quality["hairline"].lost or quality["nose_tip"].lost
        return quality, head, r.iterations

    def _quality(self, depths, outside, reinit=(), *, zoom: float = 1.0):
        """Each contour's :class:`ContourQuality`; ``zoom``: the head's size over the first
        frame's (the contours' lengths are taken relative to it)."""
        q = {}
        # a face seen larger spreads an edge over more pixels: its gradient at the
        # potentials' fixed scale falls up to as much (a sharp edge's keeps its depth)
        least = self.lost_depth / max(zoom, 1.0)
        X, st = self.system.X, self.system.starts
        for k, name in enumerate(self.names):
            pts = X[st[k]:st[k + 1]]
            closed = self.layout.contours[name].closed
            depth = depths[name] / max(self.ref_depth.get(name, depths[name]), 1e-9)
            length = _polyline_length(pts, closed)
            stretch = length / max(self.ref_length.get(name, length), 1e-9) / zoom
            shape = _shape_change(pts, self.ref_shape[name], closed) \
                if name in self.ref_shape else 0.0
            lost = (self.system.frozen[k] or not np.isfinite(pts).all()
                    or depth < least
                    or not self.stretch_range[0] <= stretch <= self.stretch_range[1]
                    or shape > self.max_shape_change
                    or bool(outside[k]) or k in self._clipped)
            q[name] = ContourQuality(float(depth), float(stretch), bool(lost), name in reinit,
                                     float(shape))
        return q

    # ------------------------------------------------------------------ public
    def rebase_references(self, frame, names) -> None:
        """Take the named contours' depth, length and shape on ``frame`` (where they
        are now) as the references their quality is judged against.

        For a contour re-placed after the first frame on a curve from elsewhere (a
        landmark model): the first frame's references describe where it was before,
        so its stretch and shape would be measured against another feature.
        """
        unknown = sorted(set(names) - set(self.names))
        if unknown:
            raise ValueError(f"unknown contours {unknown}; choose from {', '.join(self.names)}")
        if not names:
            return
        Ps, origins, _, _ = self._fields(frame)
        self._set_references(self._depths(Ps, origins), names)

    def _set_references(self, depths, names) -> None:
        """The named contours' depth, length and shape now are their references."""
        for k, name in enumerate(self.names):
            if name in names:
                pts = self.system.contour_points(k)
                self.ref_depth[name] = depths[name]
                self.ref_length[name] = _polyline_length(pts, self.layout.contours[name].closed)
                self.ref_shape[name] = pts

    def track(self, frame, *, targets=None, head=None, fallback_head=None,
              contrast: float = 1.0) -> TrackResult:
        """Relax the contours on ``frame`` (starting from the last equilibrium).

        Parameters
        ----------
        frame : ndarray
        targets : dict name -> (m, 2) array, optional
            Where this frame's springs pull (see ``springs``), e.g. curves from a
            landmark model, resampled to the contour's nodes unless they have as many;
            a contour lost on this frame is re-placed on its target instead of the
            layout, and the face is not detected again.
        head : HeadFrame, optional
            This frame's head frame when it is known from elsewhere (e.g. rigid
            landmarks); ignored on the first frame, whose head frame comes from the
            contours (004).
        fallback_head : HeadFrame, optional
            A head frame from elsewhere that stands in, on this frame, for the corner
            features and the contours' motion when the irises are not found.
        contrast : float, keyword-only
            Factor this frame's grey levels are multiplied by before the potentials are
            computed, e.g. the first frame's brightness of the face over this frame's: the
            image force, the edges' depths and the ends found are then those of the face
            under the first frame's light (they scale with the grey levels). Ignored on the
            first frame, which sets the references.

        Raises
        ------
        ValueError
            When the frame's size differs from the layout's or its pixels are bad
            (the message names the frame index).
        """
        first = self.index == 0
        if not (np.isfinite(contrast) and contrast > 0):
            raise ValueError(f"contrast must be a positive number, got {contrast!r}")
        self._contrast = 1.0 if first else float(contrast)
        self._fallback_head = None if first else fallback_head
        placed = self._set_targets(targets) if targets else {}
        given_head = None if first else head
        # how much larger the face is than on the first frame, where the head is known
        zoom = (given_head.scale / self.ref_head.scale
                if given_head is not None and self.ref_head is not None else 1.0)
        Ps, origins, gray, gorigin = self._fields(frame)
        cap = self.first_max_iter if first else self.max_iter

        def relax():
            # the first frame settles each contour strictly (its largest move): a
            # contour stops at its own equilibrium instead of creeping along its
            # feature until the slowest one stops, which made where it ended depend
            # on all the others. Later frames stop on the root-mean-square move,
            # which a few nodes creeping along a weak feature cannot hold up
            return self.system.relax(potentials=Ps, origin=origins, tol=self.tol,
                                     max_iter=cap, criterion="each" if first else "rms")

        res = relax()
        iters = res.iterations
        if first and self.strength_mode == "auto":
            self._auto_strength(Ps, origins)
            if self.system.outside_fields([P.shape for P in Ps], origins).any():
                # the first frame's long settling carried nodes out of their boxes,
                # where the next relaxation would refuse to start: new boxes
                Ps, origins, gray, gorigin = self._fields(frame)
            res = relax()
            iters += res.iterations
        self._refine(Ps, origins, gray, gorigin, settle=first)
        if first and self.refine_ends:
            # the first frame moves the ends farthest: settle and relocate once more
            # (on fields around the relocated contours)
            Ps, origins, gray, gorigin = self._fields(frame)
            iters += relax().iterations
            self._refine(Ps, origins, gray, gorigin, settle=True)
        outside = res.outside
        depths = self._depths(Ps, origins)
        if first:
            self._set_references(depths, self.names)
        quality = self._quality(depths, outside, zoom=zoom)
        self._brows_lost = quality["brow_l"].lost or quality["brow_r"].lost
        self._head_contours_lost = quality["hairline"].lost or quality["nose_tip"].lost
        if given_head is not None:
            head = given_head
            self.head_source = "given"
        else:
            head = self._head(frame, first)
        lost = [k for k, n in enumerate(self.names) if quality[n].lost]
        for n in self.names:
            self._lost_streak[n] = self._lost_streak[n] + 1 if quality[n].lost else 0
        # a contour lost frame after frame (the chin below the picture, a hand held over
        # the mouth) is re-placed on its 1st, 2nd, 4th, 8th... lost frame, at least every
        # REINIT_EVERY frames: each re-placement costs a second relaxation of all contours
        lost = [k for k in lost if self.names[k] in self.replace_lost
                and not self.system.frozen[k] and _retry_now(self._lost_streak[self.names[k]])]
        reinit = set()
        if lost and not first:
            # (a frozen contour is carried by the head, not lost)
            base = self.last_head if any(
                quality[n].lost and not self.system.frozen[self.names.index(n)]
                for n in ("hairline", "nose_tip")) else head
            for k in lost:
                pts = placed.get(self.names[k])
                if pts is None:
                    pts = self._layout_points(k, base)
                self.system.set_contour(k, pts, reset_rest=True)
                reinit.add(self.names[k])
            # the new positions need their own boxes
            Ps, origins, gray, gorigin = self._fields(frame)
            r3 = relax()
            iters += r3.iterations
            # the contours not re-placed were settled by this frame's first relaxation:
            # cutting their ends back as far as a new placement's would lose a furrow
            # cut short at its faint end on a still face
            self._refine(Ps, origins, gray, gorigin, settle=reinit)
            outside = r3.outside
            depths = self._depths(Ps, origins)
            quality = self._quality(depths, outside, reinit, zoom=zoom)
            self._brows_lost = quality["brow_l"].lost or quality["brow_r"].lost
            self._head_contours_lost = quality["hairline"].lost or quality["nose_tip"].lost
            head = given_head if given_head is not None else self._head(frame)
        if not first and not placed:
            n_lost = sum(q.lost for k, q in enumerate(quality.values())
                         if not self.system.frozen[k])
            self._failing = self._failing + 1 if n_lost >= 3 else 0
            if (self.redetect and self._failing >= 3
                    and self.index - self._last_detect >= self._redetect_wait):
                self._last_detect = self.index
                got = self._redetect(frame, n_lost, head if self.head_source in (
                    "eyes", "features") else None)
                if got is not None:
                    quality, head, more = got
                    iters += more
        if first and head is not None:
            self.ref_head = head
            self.brow_fraction = {}
            cont = {n: self.system.contour_points(k) for k, n in enumerate(self.names)}
            axis = brow_axis_frame(cont, head)
            for side in ("l", "r"):
                b = cont[f"brow_{side}"]
                if abs(head.to_head(b[:1])[0, 0]) > abs(head.to_head(b[-1:])[0, 0]):
                    b = b[::-1]
                self.brow_fraction[side] = apex_fraction(b, axis) \
                    if self.brow_mid == "apex" else float(self.brow_mid)
        if head is None:
            raise ValueError(f"frame {self.index}: no head frame could be computed")
        self.last_head = head
        contours = {n: self.system.contour_points(k) for k, n in enumerate(self.names)}
        fids = fiducials(contours, head, brow_mid_fraction=self.brow_fraction)
        snap = self.mouth_corner_mode == "snap"
        if self.mouth_corner_mode in ("profile", "snap") and not quality["upper_lip"].lost:
            lip = contours["upper_lip"]
            width = None
            if self.mouth_width is not None and self.ref_head is not None:
                width = self.mouth_width * head.scale / self.ref_head.scale
            ex = np.array(head.axes[0])
            names = ["mouth_corner_l" if (e - lip.mean(axis=0)) @ ex > 0 else "mouth_corner_r"
                     for e in (lip[0], lip[-1])]
            # a corner narrows the next search only while it is fresh: one carried on
            # for frames (a hand over the mouth) would hold the search at a height
            # where the mouth no longer is, and no corner would be found again
            previous = [None if self._corners_head.get(n) is None
                        or self._corner_misses.get(n, 0) > 1
                        else head.to_image(self._corners_head[n][None])[0] for n in names]
            corners = mouth_corners(gray, lip, origin=gorigin, width=width, previous=previous,
                                    sigma=0.5 * float(self.layout.contours["upper_lip"].sigma))
            reach = 0.25 * max(_polyline_length(lip), width or 0.0)
            if snap:
                reach = self.corner_reach * (width or _polyline_length(lip))
            scale = width or _polyline_length(lip)
            for c, e, name, prev in zip(corners, (lip[0], lip[-1]), names, previous):
                if snap and not self._snaps(c, e, prev, reach, scale):
                    if (c is None and prev is not None and self.corner_follow > 0
                            and np.hypot(*(prev - e)) <= self.corner_cap * scale):
                        # no clear corner this frame: the last one, moved with the head,
                        # for one frame (``previous`` holds only fresh corners)
                        self._corner_misses[name] = self._corner_misses.get(name, 0) + 1
                        fids[name] = (float(prev[0]), float(prev[1]))
                        continue
                    fids[name] = (float(e[0]), float(e[1]))   # the contour's end
                    self._corners_head.pop(name, None)
                    continue
                if not snap and (c is None or np.hypot(*(c - e)) > reach):
                    # no clear end of the mouth this frame (a highlight, a lip pressed
                    # on the teeth): keep the last corner, moved with the head (the
                    # contour's end can be far off: 35 px on a rendered AU 15)
                    self._corner_misses[name] = self._corner_misses.get(name, 0) + 1
                    last = self._corners_head.get(name)
                    if last is not None:
                        q = head.to_image(last[None])[0]
                        fids[name] = (float(q[0]), float(q[1]))
                    continue
                self._corner_misses[name] = 0
                fids[name] = (float(c[0]), float(c[1]))
                self._corners_head[name] = head.to_head(np.asarray(c, float)[None])[0]
            if first:
                self.mouth_width = float(np.hypot(*np.subtract(fids["mouth_corner_l"],
                                                               fids["mouth_corner_r"])))
        elif self.mouth_corner_mode == "profile":
            for name in ("mouth_corner_l", "mouth_corner_r"):
                self._corner_misses[name] = self._corner_misses.get(name, 0) + 1
        out = TrackResult(self.index, contours, quality, int(iters), bool(res.converged),
                          head, fids, {"head_source": self.head_source})
        self.index += 1
        return out

    def run(self, frames):
        """Generator of :class:`TrackResult` for an iterable of frames."""
        for frame in frames:
            yield self.track(frame)

"""The potentials the tracked contours lie in, and the image-force strength.

Each frame :class:`~trackers.tracking.Tracker` computes one potential per contour, in a
box around the contour (grown by the motion margin), from a grey crop of the frame;
the mean depth of a potential under a contour's nodes is its quality's ``depth``; and
with ``strength='auto'`` each contour's ``p`` is set on the first frame from the
curvature of the ravine it lies in (see the module docstring of
:mod:`trackers.tracking`, "Image-force strength"). :class:`ContourFields` holds these
tracker methods and their kernels.
"""

from __future__ import annotations

import numba
import numpy as np

from trackers.potentials import potentials_in_boxes, to_gray
from trackers.sampling import bilinear_nb as _bil
from trackers.sampling import sample_or_nan
from trackers.snakes import paper_equivalent_strength

__all__ = ["ContourFields"]

@numba.njit(cache=True, nogil=True, error_model="numpy")
def _mean_depth_nb(P, pts, ox, oy):
    total = 0.0
    cnt = 0
    for i in range(pts.shape[0]):
        v = _bil(P, pts[i, 0], pts[i, 1], ox, oy)
        if not np.isnan(v):             # nodes off the potential's box do not count
            total += v
            cnt += 1
    return -total / cnt if cnt else 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _boxes_nb(X, starts, m, X0, Y0, gw, gh, out):
    for k in range(starts.shape[0] - 1):
        xmin = np.inf
        ymin = np.inf
        xmax = -np.inf
        ymax = -np.inf
        for i in range(starts[k], starts[k + 1]):
            xmin = min(xmin, X[i, 0])
            xmax = max(xmax, X[i, 0])
            ymin = min(ymin, X[i, 1])
            ymax = max(ymax, X[i, 1])
        out[k, 0] = max(int(np.floor(xmin - m)) - X0, 0)
        out[k, 1] = max(int(np.floor(ymin - m)) - Y0, 0)
        out[k, 2] = min(int(np.ceil(xmax + m)) + 1 - X0, gw)
        out[k, 3] = min(int(np.ceil(ymax + m)) + 1 - Y0, gh)


def _sample_safe(P, pts, origin):
    return sample_or_nan(P, pts, origin)


class ContourFields:
    """The image side of :class:`~trackers.tracking.Tracker` (a mixin): the potential
    each contour lies in, the depth of the potential under its nodes, and the
    image-force strength calibrated from them on the first frame."""

    #: This frame's grey levels are multiplied by it before the potentials are computed
    #: (:meth:`~trackers.tracking.Tracker.track`'s ``contrast``).
    _contrast = 1.0

    def _fields(self, frame):
        """Per-contour potentials (each in a box around its contour) and their origins."""
        img = np.asarray(frame)
        if img.ndim < 2:
            raise ValueError(f"frame {self.index}: must be 2-D or 3-D, got shape {img.shape}")
        H, W = img.shape[:2]
        if self.frame_size != (W, H):
            raise ValueError(f"frame {self.index} is {W}x{H} but the layout was made for "
                             f"{self.frame_size[0]}x{self.frame_size[1]}")
        X = self.system.X
        frozen = self.system.frozen
        moving = ~frozen[self.system.node_contour] if frozen.any() else None
        # nodes pushed out of the frame (by the image force or a re-initialisation)
        # are put back on its border; their contour is reported lost this frame
        out = (X[:, 0] < 0) | (X[:, 1] < 0) | (X[:, 0] > W - 1) | (X[:, 1] > H - 1)
        if moving is not None:
            out &= moving            # a frozen contour is carried, not tracked
        self._clipped = set()
        if out.any():
            for k in np.unique(self.system.node_contour[out]):
                self._clipped.add(int(k))
            X[out] = np.clip(X[out], 0, [W - 1, H - 1])
        m = self.motion_margin
        live = X if moving is None else X[moving]
        lo = np.floor(live.min(0) - m).astype(int)
        hi = np.ceil(live.max(0) + m).astype(int) + 1
        pad = int(np.ceil(3 * self.sigma_max)) + 3
        X0, Y0 = max(lo[0] - pad, 0), max(lo[1] - pad, 0)
        X1, Y1 = min(hi[0] + pad, W), min(hi[1] + pad, H)
        try:
            gray = to_gray(img[Y0:Y1, X0:X1], channel_order=self.channel_order)
        except ValueError as exc:
            raise ValueError(f"frame {self.index}: {exc}") from None
        if self._contrast != 1.0:
            gray *= np.float32(self._contrast)
        gh, gw = gray.shape
        bx = np.empty((len(self.names), 4), np.int64)
        _boxes_nb(X, self.system.starts, float(m), int(X0), int(Y0), gw, gh, bx)
        boxes = [tuple(int(v) for v in b) for b in bx]
        origins = np.c_[bx[:, 0] + X0, bx[:, 1] + Y0].astype(np.float64)
        if moving is None:
            Ps = potentials_in_boxes(gray, self.specs, boxes)
        else:
            # a frozen contour reads no field: a 2x2 stand-in keeps one field per contour
            active = np.flatnonzero(~frozen)
            Ps = [np.zeros((2, 2), np.float32)] * len(self.names)
            for k, P in zip(active, potentials_in_boxes(
                    gray, [self.specs[k] for k in active], [boxes[k] for k in active])):
                Ps[k] = P
            origins[frozen] = 0.0
        # the potentials the ends are found on, in the same boxes, where they differ
        # from those the contours relax on (the free snakes' brows); ``_refine`` reads them
        ends = [k for k in self._end_only if not frozen[k]]
        self._end_fields = dict(zip(ends, potentials_in_boxes(
            gray, [self.end_specs[k] for k in ends], [boxes[k] for k in ends]))) \
            if ends else {}
        return Ps, origins, gray, (float(X0), float(Y0))

    def _depths(self, Ps, origins):
        out = {}
        X, st = self.system.X, self.system.starts
        for k, name in enumerate(self.names):
            if self.system.frozen[k]:
                out[name] = 0.0          # it lies in no field
                continue
            pts = X[st[k]:st[k + 1]]
            out[name] = float(_mean_depth_nb(Ps[k], pts, float(origins[k][0]),
                                             float(origins[k][1])))
        return out

    def _auto_strength(self, Ps, origins):
        gdt = self.params.gamma / self.params.dt
        for k in range(len(self.names)):
            pts = self.system.X[self.system.contour_slice(k)]
            P, origin = Ps[k], origins[k]
            tang = np.gradient(pts, axis=0)
            tang /= np.maximum(np.hypot(*tang.T), 1e-9)[:, None]
            nrm = np.c_[-tang[:, 1], tang[:, 0]]
            # the curvature at the bottom of the ravine each node lies in (down its
            # normal profile, at most 3 sigma): a contour that stopped on the
            # ravine's flank (the first relaxation stops each contour on its own
            # slow step) would measure a flatter curvature there and get a
            # strength that oscillates once it reaches the bottom
            sigma = self.specs[k][1]
            h = max(0.5 * sigma, 0.75)
            m = max(int(np.ceil(3.0 * sigma / h)), 1)
            t = np.arange(-m - 1, m + 2) * h
            prof = _sample_safe(P, (pts[:, None, :] + t[None, :, None] * nrm[:, None, :])
                                .reshape(-1, 2), origin).reshape(len(pts), len(t))
            rows = np.arange(len(pts))
            mid = np.full(len(pts), m + 1)
            vals = np.where(np.isfinite(prof), prof, np.inf)
            for _ in range(m):
                # down the profile to the bottom of the ravine the node lies in
                lo, hi = vals[rows, mid - 1], vals[rows, mid + 1]
                here = vals[rows, mid]
                step = np.where((lo < here) & (lo <= hi), -1, np.where(hi < here, 1, 0))
                step[(mid + step < 1) | (mid + step > 2 * m + 1)] = 0
                mid = mid + step
            curv = (prof[rows, mid + 1] + prof[rows, mid - 1] - 2 * prof[rows, mid]) / h**2
            curv = curv[np.isfinite(curv) & (curv > 0)]
            p_paper = paper_equivalent_strength(sigma, self.params.p)
            if len(curv) < 3:
                p = p_paper
            else:
                # the steep end of the distribution sets the rate: stability first
                p = self.descent_rate * gdt / float(np.percentile(curv, 90))
                p = float(np.clip(p, 0.1 * p_paper, 100 * p_paper))
            self.system.set_strength(k, p)

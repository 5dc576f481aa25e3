"""The round trip: render known contractions, analyse the video, resynthesise the estimate,
and measure how far each step moves the face."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from faceanalysis.io.table import FIDUCIALS
from faceanalysis.resynthesis.pipeline import resynthesize

log = logging.getLogger(__name__)


def round_trip(cases, *, frames: int = 30, size: int = 256, head_motion: float = 0.0,
               noise: float = 0.0, illumination: float = 0.0, personalised: bool = False,
               analysis_options: dict | None = None, workdir=None) -> pd.DataFrame:
    """Render known contractions, analyse, resynthesise; score the resynthesised fiducials.

    For every ``(identity, expression)``: the face of identity seed ``identity`` renders the
    expression (:func:`synth.render.synthesize`), the video is analysed
    (:func:`faceanalysis.analysis.pipeline.analyze` with ``analysis_options``, by default the
    snakes of 004 these rendered faces are drawn for), and the estimated series drives the same
    identity's model (or, with ``personalised``, the generic model warped onto the neutral
    frame) framed by the tracked head frames. The score is the distance between the
    resynthesised fiducials and the ground-truth projected fiducials.

    Returns
    -------
    DataFrame
        One row per case: ``identity``, ``expression``, ``frames``,
        ``fiducial_error_px`` (mean over frames and the visible fiducials),
        ``fiducial_error_max_px``, ``apex_error_px`` (mean at the frame of largest motion).
    """
    import tempfile

    from faceanalysis.analysis.pipeline import analyze
    from synth.face_shape import FaceShape
    from synth.model import FaceModel
    from synth.render.sequence import render_sequence

    options = ({"tracker": "snakes", "tracker_options": {"brow_mid": 0.556}}
               if analysis_options is None
               else dict(analysis_options))
    rows = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for identity, expression in cases:
            d = Path(tmp) / f"id{identity}_{expression}"
            kwargs = ({"expression": expression} if not str(expression)[:1].isdigit()
                      else {"au": expression})
            files = render_sequence(d, frames=frames, size=size, seed=int(identity),
                                    head_motion=head_motion, noise=noise,
                                    illumination=illumination, flow=False, **kwargs)
            truth = pd.read_csv(files["truth"])
            a = analyze(files["video"], **options)
            if personalised:
                res = resynthesize(a, subject=a, size=size, shading="wireframe")
            else:
                model = FaceModel.build(FaceShape.random(int(identity)))
                res = resynthesize(a, model=model, size=size, shading="wireframe",
                                   texture_seed=int(identity))
            err = []
            for st in res.states():
                row = truth.loc[truth["frame"] == st.frame]
                if row.empty or not a.table["success"].iloc[st.row]:
                    continue
                r = row.iloc[0]
                t = np.array([[r[f"fid_{n}_x"], r[f"fid_{n}_y"]] for n in FIDUCIALS])
                vis = np.array([bool(r.get(f"fid_{n}_visible", 1)) for n in FIDUCIALS])
                e = np.hypot(*(st.fiducials - t).T)
                err.append(np.where(vis, e, np.nan))
            err = np.array(err)
            truth_fid = np.stack([truth[[f"fid_{n}_x", f"fid_{n}_y"]].to_numpy(float)
                                  for n in FIDUCIALS], axis=1)
            motion = np.hypot(*(truth_fid - truth_fid[:1]).transpose(2, 0, 1)).mean(axis=1)
            apex = int(np.argmax(motion[: len(err)])) if len(err) else 0
            rows.append({"identity": int(identity), "expression": str(expression),
                         "frames": int(len(err)),
                         "fiducial_error_px": float(np.nanmean(err)) if len(err) else np.nan,
                         "fiducial_error_max_px": float(np.nanmax(err)) if len(err) else np.nan,
                         "apex_error_px": float(np.nanmean(err[apex])) if len(err) else np.nan,
                         "truth_motion_apex_px": float(motion[apex]),
                         **({"landmark_error_px": res.report["personalisation"]
                             ["landmark_error_px"]["mean"]}
                            if personalised and "personalisation" in res.report else {})})
    return pd.DataFrame(rows)

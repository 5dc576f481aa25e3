"""Make the README's picture from a demo run: ``python docs/make_images.py demo_out``.

Left: the apex frame of ``overlay.mp4``; right: ``contractions.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd


def main(demo: Path, out: Path) -> None:
    analysis = demo / "analysis"
    table = pd.read_csv(analysis / "contractions.csv")
    apex = int(table["jaw_rotation"].fillna(0).to_numpy().argmax())
    overlay = next(p for p in analysis.iterdir() if p.stem == "overlay")
    cap = cv2.VideoCapture(str(overlay))
    cap.set(cv2.CAP_PROP_POS_FRAMES, apex)
    ok, frame = cap.read()
    cap.release()
    if not ok:
        raise SystemExit(f"could not read frame {apex} of {overlay}")
    plot = cv2.imread(str(analysis / "contractions.png"))
    h = 600
    frame = cv2.resize(frame, (h * frame.shape[1] // frame.shape[0], h),
                       interpolation=cv2.INTER_CUBIC)
    plot = cv2.resize(plot, (h * plot.shape[1] // plot.shape[0], h),
                      interpolation=cv2.INTER_AREA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.hstack([frame, plot]))
    print(out)


if __name__ == "__main__":
    demo_dir = Path(sys.argv[1] if len(sys.argv) > 1 else "demo_out")
    main(demo_dir, Path(__file__).resolve().parent / "images" / "demo.png")

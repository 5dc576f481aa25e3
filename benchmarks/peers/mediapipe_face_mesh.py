"""Peer for ``bench_analyze``: MediaPipe's face mesh on the frames of one video.

Run by ``bench_analyze`` with whatever Python has MediaPipe (``MEDIAPIPE_PYTHON``, or
the benchmark's own interpreter when it can import it), since MediaPipe pins its own
OpenCV and protobuf and is best kept in a virtual environment of its own. It needs the
legacy ``mediapipe.solutions`` API, whose face-mesh models ship inside the wheel
(0.10.x; 0.10.14 was used): the newer Tasks API fetches its model from the network.

Decoding is excluded, as in the benchmark's "analysis" figure: all frames are decoded
first, then ``FaceMesh.process`` runs on each in order (video mode: landmarks are
tracked from frame to frame and the detector runs only when the face is lost), the
BGR to RGB conversion it needs included. Prints one JSON object: the median frames per
second over the repeats, each repeat's figure, the frames with a face found, the
MediaPipe version and the process CPU time per wall second (MediaPipe's XNNPACK may
use more than one thread).

Usage: ``python mediapipe_face_mesh.py VIDEO [--repeat N] [--end N]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("video")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--end", type=int, default=None, help="frames to use (default all)")
    args = ap.parse_args(argv)

    import cv2
    import mediapipe as mp

    if not hasattr(mp, "solutions"):
        print(f"mediapipe {mp.__version__} has no 'solutions' API (its face mesh model is "
              "not bundled); install mediapipe 0.10.x", file=sys.stderr)
        return 1
    cap = cv2.VideoCapture(args.video)
    frames = []
    while args.end is None or len(frames) < args.end:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    if not frames:
        print(f"{args.video}: no frames decoded", file=sys.stderr)
        return 1
    fps, found, cpu = [], 0, []
    # one untimed pass: graph set-up and XNNPACK's first-call costs
    for rep in range(args.repeat + 1):
        with mp.solutions.face_mesh.FaceMesh(static_image_mode=False, max_num_faces=1,
                                             refine_landmarks=False) as mesh:
            seen = 0
            c0, t0 = time.process_time(), time.perf_counter()
            for frame in frames:
                result = mesh.process(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
                seen += result.multi_face_landmarks is not None
            wall = time.perf_counter() - t0
            cpu_s = time.process_time() - c0
        if rep:
            fps.append(len(frames) / wall)
            cpu.append(cpu_s / wall)
            found = seen
    print(json.dumps({"fps": statistics.median(fps), "runs": fps, "frames": len(frames),
                      "found": found, "version": mp.__version__,
                      "cpu_per_wall": statistics.median(cpu)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Learned face landmarks: MediaPipe's face detector and 468-point face mesh; its palm detector
and 21-point hand landmarks, which tell a hand held over the face; its iris landmark model,
which traces the eyelids where the mesh does not follow them shut (:mod:`.eyes`).

Why these models: on a hand-annotated talking-face clip the mesh is within 0.033 of the
inter-ocular distance on average (MediaPipe's own pipeline, with its attention model, 0.036)
and finds every frame; mouth width over eye distance separates smiles from neutral faces for
40 of 40 people; its face-presence output flags 97 of 97 face-less frames. The models
(Apache-2.0) come from the publisher's ``mediapipe`` wheel on PyPI, pinned and checked by
sha256, and are cached per user on first use (:mod:`trackers.landmarks.models`).

Why these runtimes: LiteRT (``ai-edge-litert``, Google's runtime for these files) reads a
tracked frame's landmarks in about 2 ms; it is installed with the toolkit where it publishes
wheels (Linux x86-64 and ARM64, macOS on Apple silicon, Windows x86-64) and used when present
(``runtime='auto'``). Everywhere else OpenCV's ``cv2.dnn``, already a dependency, reads the
same files in about 3.3-4.4 ms.
"""

from trackers.landmarks.detection import FaceDetection, detect_faces
from trackers.landmarks.hands import HandTracker, PalmDetection, detect_palms, hand_landmarks
from trackers.landmarks.mesh import N_LANDMARKS, face_landmarks
from trackers.landmarks.models import ensure_models, model_dir, models_available
from trackers.landmarks.runtime import RUNTIMES, litert_available, load_network
from trackers.landmarks.tracker import Landmarks, LandmarkTracker

__all__ = ["FaceDetection", "detect_faces", "N_LANDMARKS", "face_landmarks", "ensure_models",
           "model_dir", "models_available", "RUNTIMES", "litert_available", "load_network",
           "LandmarkTracker", "Landmarks", "HandTracker", "PalmDetection", "detect_palms",
           "hand_landmarks"]

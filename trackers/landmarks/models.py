"""The MediaPipe model files: pinned, checked by sha256, cached per user.

The ``.tflite`` files (face detection at short and full range, face mesh, palm detection,
hand landmarks and the iris model's eye contours; and the wheel's licence, Apache-2.0) are
taken from the ``mediapipe`` wheel on PyPI, which is the publisher's own package; the project
never ships them. The first call of :func:`ensure_models` downloads that wheel with pip
(which honours the user's index and proxy settings) or, offline, extracts the files from a
local copy of it.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import subprocess
import sys
import tempfile
import uuid
import zipfile
from pathlib import Path

__all__ = ["MEDIAPIPE_VERSION", "WHEEL_NAME", "WHEEL_SHA256", "MODEL_FILES", "FACE_MODEL_FILES",
           "LICENSE_FILE",
           "model_dir", "ensure_models", "models_available"]

log = logging.getLogger(__name__)

MEDIAPIPE_VERSION = "0.10.21"
WHEEL_NAME = f"mediapipe-{MEDIAPIPE_VERSION}-cp311-cp311-manylinux_2_28_x86_64.whl"
WHEEL_SHA256 = "05dc4a9e593655a79558d05d6227d31018c2537a4bd3362b51e230cf22aecfe3"
#: name -> (path inside the wheel, sha256)
MODEL_FILES = {
    "face_detection": (
        "mediapipe/modules/face_detection/face_detection_short_range.tflite",
        "bbff11cebd1eb27a1e004cae0b0e63ec8c551cbf34a4451148b4908b8db3eca8"),
    # faces the short-range detector misses: farther than ~2 m, or under a tenth of a wide
    # frame (:func:`trackers.landmarks.detection.detect_faces`, ``model='full'``)
    "face_detection_full_range": (
        "mediapipe/modules/face_detection/face_detection_full_range_sparse.tflite",
        "2c3728e6da56f21e21a320433396fb06d40d9088f2247c05e5635a688d45dfe1"),
    "face_landmark": (
        "mediapipe/modules/face_landmark/face_landmark.tflite",
        "1055cb9d4a9ca8b8c688902a3a5194311138ba256bcc94e336d8373a5f30c814"),
    # a hand over the face (:mod:`trackers.landmarks.hands`)
    "palm_detection": (
        "mediapipe/modules/palm_detection/palm_detection_lite.tflite",
        "e9a4aaddf90dda56a87235303cf00e4c2d3fb28725f68fd88772997dac905c18"),
    "hand_landmark": (
        "mediapipe/modules/hand_landmark/hand_landmark_lite.tflite",
        "048edd3645c9bf7397d19a9f6e3a42957d6e414c9bea6598030a2e9b624156e6"),
    # the eyelids (:mod:`trackers.landmarks.eyes`)
    "iris_landmark": (
        "mediapipe/modules/iris_landmark/iris_landmark.tflite",
        "d1744d2a09c25f501d39eba4faff47e53ecca8852c5ce19bce8eeac39357521f"),
}
#: The files the face mesh's own results depend on (cache keys of what is derived from them).
FACE_MODEL_FILES = {k: MODEL_FILES[k] for k in ("face_detection", "face_landmark")}
LICENSE_FILE = (f"mediapipe-{MEDIAPIPE_VERSION}.dist-info/LICENSE",
                "8707eef0533987efc5b155d64761eeb6e20793f50b9bd1a68dad1cf4719d0ed8")
LICENSE_NAME = "LICENSE_mediapipe.txt"

_HOW_OFFLINE = ("install them offline with `faceanalysis models --wheel PATH` (or set "
                "FACEANALYSIS_MODEL_WHEEL to a local copy of " + WHEEL_NAME + "), or point "
                "FACEANALYSIS_MODELS to a folder that holds " + ", ".join(
                    Path(p).name for p, _ in MODEL_FILES.values())
                + "; or track without them (--tracker snakes, tracker='snakes')")
_verified: dict[Path, dict[str, Path]] = {}   # hashes are checked once per process and folder


def model_dir() -> Path:
    """The folder of the cached model files.

    ``$FACEANALYSIS_MODELS`` if set, else ``$XDG_CACHE_HOME/faceanalysis/models/mediapipe-V``,
    else ``~/.cache/faceanalysis/models/mediapipe-V``.
    """
    if os.environ.get("FACEANALYSIS_MODELS"):
        return Path(os.environ["FACEANALYSIS_MODELS"]).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache).expanduser() / "faceanalysis" / "models" / f"mediapipe-{MEDIAPIPE_VERSION}"


def _sha256(data_or_path) -> str:
    if isinstance(data_or_path, bytes):
        return hashlib.sha256(data_or_path).hexdigest()
    h = hashlib.sha256()
    with open(data_or_path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _targets(folder: Path) -> dict[str, tuple[str, str, Path]]:
    files = {k: (p, h, folder / Path(p).name) for k, (p, h) in MODEL_FILES.items()}
    files["license"] = (*LICENSE_FILE, folder / LICENSE_NAME)
    return files


def _cached(folder: Path) -> dict[str, Path] | None:
    files = _targets(folder)
    if all(dst.is_file() and _sha256(dst) == h for _, h, dst in files.values()):
        return {k: dst for k, (_, _, dst) in files.items() if k != "license"}
    return None


def models_available() -> bool:
    """Whether the model files are in :func:`model_dir` with the right hashes (no download)."""
    folder = model_dir()
    return folder in _verified or _cached(folder) is not None


def _write_atomic(path: Path, data: bytes) -> None:
    # os.open with mode 0o666 lets the user's umask decide the permissions (mkstemp gives 0o600);
    # os.replace makes a concurrent reader see the old file or the whole new one
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def _lock(folder: Path):
    """Serialise first installs of parallel workers (atomic writes alone would only waste work)."""
    try:
        import fcntl
    except ImportError:  # Windows: the atomic replace is enough
        yield
        return
    with open(folder / ".lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _extract(wheel: Path, folder: Path) -> None:
    try:
        zf = zipfile.ZipFile(wheel)
    except (OSError, zipfile.BadZipFile) as exc:
        raise RuntimeError(f"{wheel} is not a readable wheel ({exc}); {_HOW_OFFLINE}") from exc
    with zf:
        for inner, sha, dst in _targets(folder).values():
            try:
                data = zf.read(inner)
            except KeyError:
                raise RuntimeError(f"{wheel} holds no {inner}: it is not mediapipe "
                                   f"{MEDIAPIPE_VERSION}; {_HOW_OFFLINE}") from None
            if _sha256(data) != sha:
                raise RuntimeError(f"{inner} in {wheel} does not have the pinned sha256 {sha}: "
                                   f"not the mediapipe {MEDIAPIPE_VERSION} file; {_HOW_OFFLINE}")
            _write_atomic(dst, data)


def _download(tmp: str) -> Path:
    cmd = [sys.executable, "-m", "pip", "download", f"mediapipe=={MEDIAPIPE_VERSION}",
           "--no-deps", "--only-binary=:all:", "--platform", "manylinux_2_28_x86_64",
           "--python-version", "3.11", "--implementation", "cp", "--abi", "cp311",
           "--disable-pip-version-check", "-q", "-d", tmp]
    log.info("downloading the face models (mediapipe %s wheel, ~36 MB) into %s",
             MEDIAPIPE_VERSION, tmp)
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wheel = Path(tmp) / WHEEL_NAME
    if proc.returncode or not wheel.is_file():
        last = (proc.stderr.strip().splitlines() or ["no wheel"])[-1]
        raise RuntimeError(f"could not download mediapipe {MEDIAPIPE_VERSION} with pip ({last}); "
                           f"{_HOW_OFFLINE}")
    if _sha256(wheel) != WHEEL_SHA256:
        raise RuntimeError(f"the downloaded {WHEEL_NAME} does not have the pinned sha256 "
                           f"{WHEEL_SHA256}; {_HOW_OFFLINE}")
    return wheel


def ensure_models(*, wheel: str | os.PathLike | None = None,
                  download: bool = True) -> dict[str, Path]:
    """Paths of the model files, installing them into :func:`model_dir` first if needed.

    Parameters
    ----------
    wheel : path, optional
        A local copy of the mediapipe wheel to extract the files from (the offline install);
        default ``$FACEANALYSIS_MODEL_WHEEL`` if set. Any platform's wheel of the pinned
        version will do: only the model files' hashes are checked.
    download : bool
        Download the pinned wheel with pip when the files are missing and no wheel is given.

    Returns
    -------
    dict
        ``{"face_detection": Path, "face_detection_full_range": Path, "face_landmark": Path,
        "palm_detection": Path, "hand_landmark": Path, "iris_landmark": Path}``.

    Raises
    ------
    FileNotFoundError
        The files are missing and neither a wheel nor a download was allowed, or ``wheel``
        does not exist.
    RuntimeError
        The download failed, or a file does not have its pinned sha256.
    """
    folder = model_dir()
    if folder in _verified and all(p.is_file() for p in _verified[folder].values()):
        return dict(_verified[folder])
    wheel = wheel if wheel is not None else os.environ.get("FACEANALYSIS_MODEL_WHEEL") or None
    if wheel is None:
        paths = _cached(folder)
    else:   # an explicit wheel reinstalls, so that it also repairs
        paths = None
        wheel = Path(wheel).expanduser()
        if not wheel.is_file():
            raise FileNotFoundError(f"no wheel {wheel}; {_HOW_OFFLINE}")
    if paths is None:
        if wheel is None and not download:
            raise FileNotFoundError(f"the face models in {folder} are missing or corrupt; "
                                    f"{_HOW_OFFLINE}")
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RuntimeError(f"cannot create {folder} ({exc}); {_HOW_OFFLINE}") from exc
        with _lock(folder):
            paths = None if wheel is not None else _cached(folder)  # another worker did it
            if paths is None:
                if wheel is not None:
                    _extract(wheel, folder)
                else:
                    with tempfile.TemporaryDirectory(prefix="faceanalysis-wheel-") as tmp:
                        _extract(_download(tmp), folder)
                paths = _cached(folder)
        if paths is None:
            raise RuntimeError(f"the model files in {folder} do not have their pinned sha256 "
                               f"after installing them; {_HOW_OFFLINE}")
        log.info("face models installed in %s", folder)
    _verified[folder] = paths
    return dict(paths)

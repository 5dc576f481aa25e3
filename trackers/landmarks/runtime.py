"""Running a ``.tflite`` network: LiteRT (Google's runtime, a dependency where it publishes
wheels) or OpenCV's dnn module (everywhere, 1.6-2x slower).

Both take the same float32 NHWC input and return the outputs sorted by their tensor names,
so the callers do not depend on the runtime. Each network also lends a reusable input
array (``input_buffer``), laid out so that its runtime takes it without a copy: the
trackers fill it in place every frame instead of allocating a new batch.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

__all__ = ["RUNTIMES", "load_network", "litert_available"]

RUNTIMES = ("auto", "litert", "opencv")
_local = threading.local()  # networks are not thread-safe: one per thread


# what LiteRT prints to the process's stderr when it builds an interpreter: not news to a
# user, and a line in every CLI run's log
_LITERT_NOTICE = "INFO: Created TensorFlow Lite XNNPACK delegate for CPU."


def litert_available() -> bool:
    """Whether the ``ai-edge-litert`` package is installed."""
    return importlib.util.find_spec("ai_edge_litert") is not None


def check_runtime(runtime: str) -> str:
    """The concrete runtime for ``runtime`` ('auto' -> 'litert' when installed)."""
    if runtime not in RUNTIMES:
        raise ValueError(f"runtime={runtime!r} is not one of {', '.join(map(repr, RUNTIMES))}")
    if runtime == "auto":
        return "litert" if litert_available() else "opencv"
    if runtime == "litert" and not litert_available():
        raise ValueError("runtime='litert' needs the package ai-edge-litert, which is not "
                         "installed (it has no wheel for this platform?); use "
                         "runtime='opencv'")
    return runtime


class _OpenCVNet:
    def __init__(self, path: Path):
        import cv2

        kwargs = {}
        if int(cv2.__version__.split(".")[0]) >= 5:  # the new engine returns only one output
            kwargs["engine"] = cv2.dnn.ENGINE_CLASSIC
        self._net = cv2.dnn.readNetFromTFLite(str(path), **kwargs)
        self._names = sorted(self._net.getUnconnectedOutLayersNames())
        self._buffers: dict[tuple, np.ndarray] = {}

    def input_buffer(self, shape) -> np.ndarray:
        """A reusable float32 NHWC array of ``shape``: a view of an NCHW array, which
        :meth:`run` then hands to OpenCV as it is."""
        n, h, w, c = shape
        buf = self._buffers.get((n, h, w, c))
        if buf is None:
            buf = self._buffers[n, h, w, c] = np.empty((n, c, h, w), np.float32)
        return buf.transpose(0, 2, 3, 1)

    def run(self, x: np.ndarray) -> list[np.ndarray]:
        self._net.setInput(np.ascontiguousarray(x.transpose(0, 3, 1, 2), dtype=np.float32))
        return [np.asarray(o) for o in self._net.forward(self._names)]


class _LiteRTNet:
    def __init__(self, path: Path):
        from ai_edge_litert.interpreter import Interpreter

        # one thread: the toolkit parallelises over videos (Dask workers), not inside a frame
        self._it = Interpreter(model_path=str(path), num_threads=1)
        _without_notice(self._it.allocate_tensors)
        self._input = self._it.get_input_details()[0]["index"]
        out = sorted(self._it.get_output_details(), key=lambda d: d["name"])
        self._outputs = [d["index"] for d in out]
        self._buffers: dict[tuple, np.ndarray] = {}

    def input_buffer(self, shape) -> np.ndarray:
        """A reusable float32 NHWC array of ``shape`` (copied into the interpreter by
        :meth:`run`: a view of its own input tensor may not be held across ``invoke``)."""
        shape = tuple(shape)
        buf = self._buffers.get(shape)
        if buf is None:
            buf = self._buffers[shape] = np.empty(shape, np.float32)
        return buf

    def run(self, x: np.ndarray) -> list[np.ndarray]:
        self._it.set_tensor(self._input, np.ascontiguousarray(x, dtype=np.float32))
        self._it.invoke()
        return [self._it.get_tensor(i).copy() for i in self._outputs]


def _without_notice(fn):
    """``fn()``, with what it writes to the process's stderr (file descriptor 2) passed on
    except LiteRT's notice that it built its CPU delegate (C++ code: ``sys.stderr`` cannot
    catch it). What other threads write there meanwhile is passed on after the call."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):    # no stderr to catch
        return fn()
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            return fn()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            text = caught.read().decode(errors="replace")
            rest = "".join(line for line in text.splitlines(keepends=True)
                           if line.rstrip() != _LITERT_NOTICE)
            if rest:
                sys.stderr.write(rest)


def load_network(path: str | os.PathLike, *, runtime: str = "auto"):
    """Load a ``.tflite`` network.

    Parameters
    ----------
    path : path
        The model file.
    runtime : {'auto', 'litert', 'opencv'}
        'opencv': ``cv2.dnn.readNetFromTFLite``; 'litert': ``ai_edge_litert`` (installed
        with the toolkit where LiteRT publishes wheels: Linux x86-64 and ARM64, macOS on
        Apple silicon, Windows x86-64; 1.6-2 times faster); 'auto': LiteRT when
        installed, else OpenCV.

    Returns
    -------
    object
        With ``run(x) -> list[np.ndarray]``: ``x`` a float32 NHWC batch, the outputs sorted by
        tensor name; and ``input_buffer(shape) -> np.ndarray``: a float32 NHWC array of that
        shape that the network keeps, for callers that write each batch in place.
        Networks are shared per (file, runtime) within a thread, and so are their buffers.
    """
    runtime = check_runtime(runtime)
    cache = _local.__dict__.setdefault("nets", {})
    # a path already loaded in this thread is found without file-system calls (the
    # trackers ask for their networks on every frame)
    given = (os.fspath(path), runtime)
    net = cache.get(given)
    if net is not None:
        return net
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no model file {path}")
    key = (str(path.resolve()), runtime)
    if key not in cache:
        cache[key] = (_LiteRTNet if runtime == "litert" else _OpenCVNet)(path)
    cache[given] = cache[key]
    return cache[key]

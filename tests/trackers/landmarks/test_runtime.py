import numpy as np
import pytest

from trackers.landmarks import RUNTIMES, litert_available, load_network


def test_unknown_runtime_names_the_valid_ones(models):
    with pytest.raises(ValueError, match="'auto', 'litert', 'opencv'"):
        load_network(models["face_landmark"], runtime="tflite")


def test_missing_model_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_network(tmp_path / "none.tflite", runtime="opencv")


def test_outputs_come_in_name_order(models):
    net = load_network(models["face_detection"], runtime="opencv")
    scores, boxes = net.run(np.zeros((1, 128, 128, 3), np.float32))
    assert scores.size == 896 and boxes.size == 896 * 16


@pytest.mark.skipif(not litert_available(), reason="ai-edge-litert is not installed")
def test_litert_and_opencv_agree(models):
    x = np.random.default_rng(0).random((1, 192, 192, 3), dtype=np.float32)
    a, b = (load_network(models["face_landmark"], runtime=r).run(x) for r in RUNTIMES[1:])
    assert [o.size for o in a] == [o.size for o in b] == [1404, 1]
    for u, v in zip(a, b):
        np.testing.assert_allclose(u.ravel(), v.ravel(), atol=0.05 * max(1, np.abs(u).max()))


@pytest.mark.parametrize("runtime", [r for r in RUNTIMES[1:]
                                     if r != "litert" or litert_available()])
def test_input_buffer_runs_like_a_new_batch(models, runtime):
    net = load_network(models["face_landmark"], runtime=runtime)
    x = np.random.default_rng(1).random((1, 192, 192, 3), dtype=np.float32)
    expected = net.run(x.copy())
    buf = net.input_buffer(x.shape)
    assert buf.shape == x.shape and buf.dtype == np.float32
    buf[...] = x
    for got, want in zip(net.run(buf), expected):
        np.testing.assert_array_equal(got, want)
    assert np.shares_memory(net.input_buffer(x.shape), buf)   # reused, not reallocated


@pytest.mark.skipif(not litert_available(), reason="ai-edge-litert is not installed")
def test_a_litert_network_leaves_stderr_quiet(models):
    import subprocess
    import sys

    # a new process: LiteRT announces its CPU delegate once per process
    code = ("import sys; from trackers.landmarks.runtime import _LiteRTNet; "
            "_LiteRTNet(sys.argv[1]).run(__import__('numpy').zeros((1, 192, 192, 3), 'f4'))")
    run = subprocess.run([sys.executable, "-c", code, str(models["face_landmark"])],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stderr == ""


def test_only_litert_notice_is_kept_from_stderr(capfd):
    import os

    from trackers.landmarks.runtime import _LITERT_NOTICE, _without_notice

    def noisy():
        os.write(2, f"{_LITERT_NOTICE}\nsomething the user must see\n".encode())
        return 7

    assert _without_notice(noisy) == 7
    assert capfd.readouterr().err == "something the user must see\n"
    os.write(2, b"after\n")                 # stderr is the process's own again
    assert capfd.readouterr().err == "after\n"

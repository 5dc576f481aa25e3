"""Atomic video writer: channel orders, pixel types, codec fallback, atomicity."""

import os
import stat

import cv2
import numpy as np
import pytest

from synth.render import video
from synth.render.video import VideoWriter, to_uint8

W, H = 64, 48


def _first_frame(path):
    cap = cv2.VideoCapture(str(path))
    try:
        ok, frame = cap.read()
    finally:
        cap.release()
    assert ok
    return frame                                          # BGR, as OpenCV reads


def _count(path):
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def _bgr_mean(path):
    return _first_frame(path).reshape(-1, 3).mean(axis=0)


# -- channel order and pixel types -------------------------------------------------------

@pytest.mark.parametrize("name", ["c.mp4", "c.avi"])
def test_rgb_and_bgr_round_trip(tmp_path, name):
    rgb = np.full((H, W, 3), (200, 40, 90), np.uint8)
    with VideoWriter(tmp_path / "rgb" / name, 10, (W, H)) as a:        # rgb by default
        a.write(rgb)
    with VideoWriter(tmp_path / "bgr" / name, 10, (W, H), channel_order="bgr") as b:
        b.write(rgb[..., ::-1])
    expected = np.array([90, 40, 200])                    # what OpenCV reads back: BGR
    assert np.abs(_bgr_mean(a.path) - expected).max() < 12
    assert np.abs(_bgr_mean(b.path) - expected).max() < 12
    assert a.channel_order == "rgb" and b.channel_order == "bgr"


@pytest.mark.parametrize(("frame", "expected"), [
    (np.full((H, W, 3), (65535, 0, 32768), np.uint16), (128, 0, 255)),      # RGB -> BGR
    (np.full((H, W, 3), (1.0, 0.25, 0.0), np.float32), (0, 64, 255)),
    (np.full((H, W, 3), (2.0, -1.0, np.nan)), (0, 0, 255)),               # clipped, NaN 0
    (np.full((H, W, 4), (0, 255, 0, 7), np.uint8), (0, 255, 0)),            # alpha dropped
    (np.full((H, W), 0.5), (128, 128, 128)),                                # grey float
    (np.full((H, W, 2), (30000, 65535), np.uint16), (117, 117, 117)),       # grey + alpha
    (np.full((H, W, 1), True), (255, 255, 255)),
])
def test_pixel_types_are_converted(tmp_path, frame, expected):
    with VideoWriter(tmp_path / "t.avi", 10, (W, H)) as writer:
        writer.write(frame)
    assert np.abs(_bgr_mean(writer.path) - np.array(expected)).max() < 10


def test_to_uint8():
    assert to_uint8(np.array([[0, 257, 65535]], np.uint16)).tolist() == [[0, 1, 255]]
    assert to_uint8(np.array([[0.0, 0.5, 1.0]], np.float32)).tolist() == [[0, 128, 255]]
    assert to_uint8(np.array([[-128, 127]], np.int8)).tolist() == [[0, 255]]
    u8 = np.zeros((2, 2, 3), np.uint8)
    assert np.shares_memory(to_uint8(u8), u8)                          # no copy
    frame = np.full((2, 2, 4), 0.5)
    assert to_uint8(frame).shape == (2, 2, 3) and frame[0, 0, 3] == 0.5  # input untouched
    with pytest.raises(ValueError, match="shape"):
        to_uint8(np.zeros((2, 2, 5)))
    with pytest.raises(ValueError, match="pixel type"):
        to_uint8(np.zeros((2, 2), complex))


# -- atomicity ---------------------------------------------------------------------------

def test_exception_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError), VideoWriter(tmp_path / "o.mp4", 10, (W, H)) as writer:
        writer.write(np.zeros((H, W), np.uint8))
        assert len(list(tmp_path.iterdir())) == 1           # the hidden temporary file
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_interrupt_keeps_the_previous_result(tmp_path):
    out = tmp_path / "o.mp4"
    out.write_bytes(b"previous complete result")
    with pytest.raises(KeyboardInterrupt), VideoWriter(out, 10, (W, H)) as writer:
        writer.write(np.zeros((H, W), np.uint8))
        raise KeyboardInterrupt
    assert out.read_bytes() == b"previous complete result"
    assert list(tmp_path.iterdir()) == [out]


def test_close_returns_the_path_and_replaces_an_old_file(tmp_path):
    out = tmp_path / "o.mp4"
    out.write_bytes(b"old")
    writer = VideoWriter(out, 10, (W, H))
    for i in range(4):
        writer.write(np.full((H, W), 60 * i, np.uint8))
    assert out.read_bytes() == b"old"                                   # not yet
    assert writer.close() == out == writer.path and writer.n_written == 4
    assert writer.close() == out                                        # idempotent
    assert _count(out) == 4 and [p.name for p in tmp_path.iterdir()] == ["o.mp4"]
    with pytest.raises(ValueError, match="closed"):
        writer.write(np.zeros((H, W), np.uint8))


def test_abort_and_dropping_an_unclosed_writer_leave_nothing(tmp_path):
    writer = VideoWriter(tmp_path / "a.mp4", 10, (W, H))
    writer.write(np.zeros((H, W), np.uint8))
    writer.abort()
    writer.abort()
    with pytest.raises(ValueError, match="aborted"):
        writer.close()
    dropped = VideoWriter(tmp_path / "b.mp4", 10, (W, H))
    dropped.write(np.zeros((H, W), np.uint8))
    del dropped
    assert list(tmp_path.iterdir()) == []


def test_no_frame_or_a_wrong_size_is_refused(tmp_path):
    writer = VideoWriter(tmp_path / "o.mp4", 20, (W, H))
    with pytest.raises(ValueError, match=r"frame 0 is 10x12, expected 64x48"):
        writer.write(np.zeros((12, 10, 3), np.uint8))
    with pytest.raises(ValueError, match="no frames"):
        writer.close()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("mask", "expected"), [(0o022, 0o644), (0o027, 0o640)])
def test_the_video_follows_the_umask(tmp_path, mask, expected):
    old = os.umask(mask)
    try:
        with VideoWriter(tmp_path / "o.mp4", 10, (W, H)) as writer:
            writer.write(np.zeros((H, W), np.uint8))
    finally:
        os.umask(old)
    assert stat.S_IMODE(writer.path.stat().st_mode) == expected


# -- containers and codecs ---------------------------------------------------------------

def test_codecs_fall_back_and_say_so(tmp_path, caplog):
    with caplog.at_level("INFO", logger="synth.render.video"), \
            VideoWriter(tmp_path / "v.mp4", 10, (32, 32),
                        codecs=((".mp4", "ZZZZ"), (".avi", "MJPG"))) as w:
        w.write(np.zeros((32, 32, 3), np.uint8))
    assert w.path == tmp_path / "v.avi" and w.path.exists() and w.fourcc == "MJPG"
    assert "ZZZZ" in w.note and "Motion-JPEG" in w.note and w.note in caplog.text
    assert [p.name for p in tmp_path.iterdir()] == ["v.avi"]


def test_mp4_falls_back_to_mjpg_avi(tmp_path, monkeypatch):
    monkeypatch.setattr(video, "_FALLBACKS", ((".mp4", "XXXX"), (".avi", "MJPG")))
    with VideoWriter(tmp_path / "o", 25, (W, H)) as writer:                # no suffix
        writer.write(np.zeros((H, W), np.uint8))
    assert writer.path == tmp_path / "o.avi" and _count(writer.path) == 1


def test_suffix_chooses_the_codec_and_a_working_mp4_needs_no_note(tmp_path):
    with VideoWriter(tmp_path / "o.avi", 10, (W, H)) as avi:
        avi.write(np.zeros((H, W), np.uint8))
    assert (avi.path, avi.fourcc, avi.note) == (tmp_path / "o.avi", "MJPG", None)
    with VideoWriter(tmp_path / "o.mp4", 10, (W, H)) as mp4:
        mp4.write(np.zeros((H, W), np.uint8))
    assert (mp4.path, mp4.fourcc, mp4.note) == (tmp_path / "o.mp4", "mp4v", None)


def test_refuses_to_replace_a_folder(tmp_path):
    (tmp_path / "overlay.avi").mkdir()                     # the fallback's name counts too
    with pytest.raises(ValueError, match="not a regular file"):
        VideoWriter(tmp_path / "overlay.mp4", 25, (W, H))
    assert [p.name for p in tmp_path.iterdir()] == ["overlay.avi"]


@pytest.mark.parametrize(("args", "match"), [
    (dict(fps=0, size=(4, 4)), "fps"),
    (dict(fps=float("nan"), size=(4, 4)), "fps"),
    (dict(fps=True, size=(4, 4)), "fps"),
    (dict(fps=25, size=(0, 4)), "size"),
    (dict(fps=25, size="big"), "size"),
    (dict(fps=25, size=(4, 4), channel_order="RGB"), "'rgb', 'bgr'"),
    (dict(fps=25, size=(4, 4), codecs=()), "codecs"),
    (dict(fps=25, size=(4, 4), codecs=((".avi", "MJPEG"),)), "codecs"),
    (dict(fps=25, size=(4, 4), codecs=("mp4v",)), "codecs"),
])
def test_validates(tmp_path, args, match):
    with pytest.raises(ValueError, match=match):
        VideoWriter(tmp_path / "o.mp4", **args)
    assert list(tmp_path.iterdir()) == []


def test_unsupported_suffix(tmp_path):
    with pytest.raises(ValueError, match=r"unsupported video suffix '\.gif'"):
        VideoWriter(tmp_path / "o.gif", 10, (W, H))

"""Video and image-folder input, frame normalisation and atomic video output."""

from __future__ import annotations

import gc
import threading
import tracemalloc
from contextlib import closing
from pathlib import Path

import cv2
import numpy as np
import pytest

from faceanalysis.io.frames import to_gray_float
from faceanalysis.io.report import input_metadata
from faceanalysis.io.video import (
    DEFAULT_FPS,
    Frame,
    Frames,
    as_video,
    open_video,
    read_ahead,
    read_image,
)

W, H = 96, 64


def frame_image(i: int, *, size=(W, H), color=True) -> np.ndarray:
    """A frame whose brightness encodes its index (robust to lossy coding)."""
    value = (20 + 7 * i) % 230
    shape = (size[1], size[0], 3) if color else (size[1], size[0])
    return np.full(shape, value, np.uint8)


def brightness_index(image: np.ndarray) -> int:
    value = float(np.median(image))
    return int(round((value - 20) / 7))


def make_video(path, n, *, fps=25.0, fourcc="mp4v", size=(W, H), color=True, noise=False):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, size, color)
    assert writer.isOpened()
    rng = np.random.default_rng(0)
    for i in range(n):
        img = frame_image(i, size=size, color=color)
        if noise:  # incompressible frames, so that damage hits several of them
            img = rng.integers(0, 255, img.shape, dtype=np.uint8)
        writer.write(img)
    writer.release()
    return path


@pytest.fixture
def video(tmp_path):
    return make_video(tmp_path / "clip.mp4", 30)


# -- video files ---------------------------------------------------------------------------

def test_reads_every_frame_with_container_timestamps(video):
    with open_video(video) as src:
        assert src.kind == "video"
        assert src.size == (W, H)
        assert src.fps == pytest.approx(25.0)
        assert src.fps_origin == "container"
        assert src.n_frames == 30 and len(src) == 30
        frames = list(src)
    assert [f.index for f in frames] == list(range(30))
    assert all(f.ok and f.image.shape == (H, W, 3) for f in frames)
    np.testing.assert_allclose([f.timestamp for f in frames], np.arange(30) / 25.0, atol=1e-6)
    assert [brightness_index(f.image) for f in frames] == list(range(30))


def test_fps_override_sets_timestamps(video):
    frames = list(open_video(video, fps=10))
    np.testing.assert_allclose([f.timestamp for f in frames], np.arange(30) / 10.0)


def test_start_end_select_the_right_frames(video):
    src = open_video(video, start=7, end=12)
    assert src.n_frames == 5
    frames = list(src)
    assert [f.index for f in frames] == [7, 8, 9, 10, 11]
    assert [brightness_index(f.image) for f in frames] == [7, 8, 9, 10, 11]
    np.testing.assert_allclose([f.timestamp for f in frames], np.arange(7, 12) / 25.0,
                               atol=1e-6)


def _numbered_frame(i: int) -> np.ndarray:
    """A frame whose halves' brightness encode its index up to 899 (robust to coding)."""
    img = np.empty((H, W, 3), np.uint8)
    img[:, : W // 2] = 20 + 7 * (i % 30)
    img[:, W // 2:] = 20 + 7 * (i // 30)
    return img


def _frame_number(img: np.ndarray) -> int:
    low, high = (int(round((float(np.median(half)) - 20) / 7))
                 for half in (img[:, : W // 2], img[:, W // 2:]))
    return 30 * high + low


@pytest.mark.parametrize("fourcc", ["mp4v", "MJPG"])
def test_reading_far_into_a_video_seeks_to_the_frames_decoding_gives(tmp_path, fourcc,
                                                                    monkeypatch):
    import faceanalysis.io.video as video_module
    from faceanalysis.io.video import SEEK_FROM, seek_video

    path = tmp_path / ("clip.mp4" if fourcc == "mp4v" else "clip.avi")
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 25.0, (W, H))
    for i in range(SEEK_FROM + 60):
        writer.write(_numbered_frame(i))
    writer.release()
    whole = {f.index: f for f in open_video(path)}
    assert [_frame_number(whole[i].image) for i in (0, 299)] == [0, 299]
    for start in (SEEK_FROM, SEEK_FROM + 31, SEEK_FROM + 58):
        part = list(open_video(path, start=start, end=start + 2))
        assert [f.index for f in part] == [start, start + 1]
        for f in part:
            assert f.timestamp == whole[f.index].timestamp
            np.testing.assert_array_equal(f.image, whole[f.index].image)
    # the seek put the decoder there, not decoding from the first frame
    capture = seek_video(path, SEEK_FROM + 31)
    assert _frame_number(capture.read()[1]) == SEEK_FROM + 31
    assert seek_video(path, 0) is None and seek_video(path, SEEK_FROM + 60) is None
    # where it cannot seek, every frame is decoded: the same frames
    monkeypatch.setattr(video_module, "seek_video", lambda path, start: None)
    part = list(open_video(path, start=SEEK_FROM + 31, end=SEEK_FROM + 33))
    assert [_frame_number(f.image) for f in part] == [SEEK_FROM + 31, SEEK_FROM + 32]


def test_no_seek_where_the_container_lost_pictures(tmp_path):
    """Damage that the demuxer steps over shifts the numbers decoding from the first frame
    gives the later frames, where the file's index does not: no seek there."""
    from faceanalysis.io.video import SEEK_FROM, seek_video

    path = tmp_path / "damaged.avi"
    rng = np.random.default_rng(0)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (W, H))
    for i in range(SEEK_FROM + 80):
        img = _numbered_frame(i)
        img[:8] = rng.integers(0, 255, img[:8].shape, dtype=np.uint8)   # incompressible
        writer.write(img)
    writer.release()
    data = bytearray(path.read_bytes())
    data[len(data) // 3: len(data) // 3 + 3000] = bytes(3000)
    path.write_bytes(bytes(data))
    whole = {f.index: f for f in open_video(path)}
    assert len(whole) < SEEK_FROM + 80               # pictures lost without a failed read
    start = SEEK_FROM + 20
    assert seek_video(path, start) is None
    part = list(open_video(path, start=start, end=start + 2))
    for f in part:
        np.testing.assert_array_equal(f.image, whole[f.index].image)


@pytest.mark.real_data
def test_seeking_in_real_clips_gives_the_frames_decoding_gives(real_video_dir):
    from faceanalysis.io.video import SEEK_FROM, seek_video

    for path in sorted(real_video_dir.glob("*.mp4")):
        n = int(cv2.VideoCapture(str(path)).get(cv2.CAP_PROP_FRAME_COUNT))
        starts = [s for s in (SEEK_FROM, n - 2) if s < n]
        wanted = {s + k for s in starts for k in (0, 1) if s + k < n}
        decoded = {f.index: f for f in open_video(path) if f.index in wanted}
        for start in starts:
            assert seek_video(path, start) is not None, path.name
            for f in open_video(path, start=start, end=min(n, start + 2)):
                assert f.timestamp == decoded[f.index].timestamp, (path.name, f.index)
                np.testing.assert_array_equal(f.image, decoded[f.index].image)


def test_iterating_twice_restarts(video):
    src = open_video(video, start=3, end=6)
    assert [f.index for f in src] == [3, 4, 5]
    assert [f.index for f in src] == [3, 4, 5]


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(start=30), r"start \(30\).*clip\.mp4"),
    (dict(end=31), r"end \(31\).*clip\.mp4"),
    (dict(start=5, end=5), r"end \(5\).*start \(5\)"),
    (dict(start=-1), "start"),
    (dict(start=1.5), "start"),
    (dict(fps=0), "fps"),
    (dict(fps=float("nan")), "fps"),
])
def test_bad_range_or_fps_is_named(video, kwargs, match):
    with pytest.raises(ValueError, match=match):
        open_video(video, **kwargs)


def test_grey_video_is_read(tmp_path):
    path = make_video(tmp_path / "grey.avi", 5, fourcc="MJPG", color=False)
    frames = list(open_video(path))
    assert len(frames) == 5 and all(f.ok for f in frames)
    assert to_gray_float(frames[0].image).shape == (H, W)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothere\.mp4: no such file"):
        open_video(tmp_path / "nothere.mp4")


@pytest.mark.parametrize("url", ["https://example.com/clip.mp4", "rtsp://camera/stream"])
def test_a_url_is_named_as_one_not_as_a_missing_file(url):
    # as given, and as a Path (the command line's), which folds '//' to '/'
    for given in (url, Path(url)):
        with pytest.raises(FileNotFoundError, match=rf"^{url}: a URL or stream; the toolkit "
                                                    r"reads local files .*download it first$"):
            open_video(given)
    with pytest.raises(FileNotFoundError, match=r"^C:/clips/a\.mp4: no such file or folder$"):
        open_video("C:/clips/a.mp4")


def test_random_bytes_are_not_a_video(tmp_path):
    path = tmp_path / "noise.mp4"
    path.write_bytes(np.random.default_rng(1).bytes(5000))
    with pytest.raises(ValueError, match=r"noise\.mp4: not a video"):
        open_video(path)


def test_empty_file(tmp_path):
    path = tmp_path / "empty.mp4"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.mp4.*empty"):
        open_video(path)


def test_zero_frame_video(tmp_path):
    path = make_video(tmp_path / "none.mp4", 0)
    assert path.exists()
    with pytest.raises(ValueError, match=r"none\.mp4: video has no decodable frames"):
        open_video(path)


def test_audio_file_and_phone_photograph_are_named_as_such(tmp_path):
    import wave

    with wave.open(str(tmp_path / "voice.wav"), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(8000)
        w.writeframes(b"\x00\x00" * 800)
    with pytest.raises(ValueError, match=r"voice\.wav: an audio file \(WAVE\): it holds no video"):
        open_video(tmp_path / "voice.wav")
    # an MP3 (its ID3 header), named as a video
    (tmp_path / "song.mp4").write_bytes(b"ID3\x04\x00\x00\x00\x00\x00\x00" + bytes(64))
    with pytest.raises(ValueError, match=r"song\.mp4: an audio file \(MP3\)"):
        open_video(tmp_path / "song.mp4")
    # a phone's HEIF photograph (its ftyp box), which reads like a damaged MPEG-4 otherwise
    (tmp_path / "IMG_0001.HEIC").write_bytes(b"\x00\x00\x00\x18ftypheic" + bytes(64))
    with pytest.raises(ValueError, match=r"IMG_0001\.HEIC: a HEIF/AVIF image \(heic.*"
                                         r"convert it to JPEG or PNG"):
        open_video(tmp_path / "IMG_0001.HEIC")


def test_truncated_mp4_without_index(tmp_path, video):
    data = video.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut\.mp4: video has no decodable frames"):
        open_video(cut)


def test_truncated_avi_ends_early_and_counts_missing_frames(tmp_path):
    full = make_video(tmp_path / "full.avi", 40, fourcc="MJPG", noise=True)
    data = full.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: len(data) // 2])
    src = open_video(cut)
    assert src.n_frames == 40  # what the container announces
    frames = list(src)
    assert 5 < len(frames) < 40
    assert all(f.ok for f in frames)
    assert [f.index for f in frames] == list(range(len(frames)))
    assert src.missing_tail == 40 - len(frames)
    assert src.n_failed == src.missing_tail
    # A range that lies wholly in the missing part is an error, not an empty result.
    with pytest.raises(ValueError, match=r"cut\.avi: no frame from 38 on could be decoded"):
        list(open_video(cut, start=38))


def test_damaged_frames_mid_stream_are_lost_and_reading_goes_on(tmp_path):
    path = make_video(tmp_path / "dmg.mp4", 30, noise=True)
    data = bytearray(path.read_bytes())
    start = len(data) // 3
    data[start:start + 2000] = bytes(2000)
    path.write_bytes(bytes(data))
    src = open_video(path)
    frames = list(src)
    lost = [f.index for f in frames if not f.ok]
    good = [f.index for f in frames if f.ok]
    assert lost, "the damaged region should cost at least one frame"
    assert max(good) > max(lost), "decoding must resume after the damage"
    assert [f.index for f in frames] == list(range(len(frames)))
    assert all(f.image is None for f in frames if not f.ok)
    assert src.n_failed == len(lost) + src.missing_tail
    ts = np.array([f.timestamp for f in frames])
    assert np.all(np.diff(ts) > 0)
    # Good frames after the damage keep the container's time, not a shifted one.
    after = [f for f in frames if f.ok and f.index > max(lost)]
    assert after[0].timestamp == pytest.approx(after[0].index / 25.0, abs=1e-6)


def test_tiny_frames_refused_with_min_size(tmp_path):
    path = make_video(tmp_path / "tiny.avi", 3, fourcc="MJPG", size=(48, 40))
    with pytest.raises(ValueError, match=r"tiny\.avi: frames are 48x40 pixels.*64"):
        open_video(path, min_size=64)
    assert len(list(open_video(path))) == 3  # readable when no minimum is asked


def _good_frames_and_peak_memory(frames) -> tuple[int, int]:
    """Frames decoded and the peak of traced memory (bytes) while iterating ``frames``."""
    gc.collect()
    tracemalloc.start()
    try:
        n = sum(frame.ok for frame in frames)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return n, peak


def test_streaming_memory_stays_flat(tmp_path):
    path = make_video(tmp_path / "long.avi", 120, fourcc="MJPG", size=(320, 240))
    frame_bytes = 320 * 240 * 3
    n, peak = _good_frames_and_peak_memory(open_video(path))
    assert n == 120
    assert peak < 6 * frame_bytes, f"peak {peak} bytes for {frame_bytes}-byte frames"


def test_abandoned_iteration_releases_decoder(video):
    with open_video(video) as src:
        for frame in src:
            if frame.index == 2:
                break
    assert src._capture is None


# -- reading ahead --------------------------------------------------------------------------

def _read_ahead_threads():
    return [t for t in threading.enumerate() if t.name == "read_ahead"]


def test_read_ahead_yields_the_same_frames_in_order(video):
    direct = [(f.index, f.timestamp, brightness_index(f.image)) for f in open_video(video)]
    src = open_video(video)
    ahead = [(f.index, f.timestamp, brightness_index(f.image)) for f in read_ahead(src, 3)]
    assert ahead == direct
    assert src.n_failed == 0 and not _read_ahead_threads()


def test_read_ahead_keeps_the_counts_of_a_damaged_video(tmp_path):
    path = make_video(tmp_path / "dmg.mp4", 30, noise=True)
    data = bytearray(path.read_bytes())
    data[len(data) // 3:len(data) // 3 + 2000] = bytes(2000)
    path.write_bytes(bytes(data))
    direct = open_video(path)
    expect = [(f.index, f.ok) for f in direct]
    src = open_video(path)
    assert [(f.index, f.ok) for f in read_ahead(src)] == expect
    assert (src.n_failed, src.missing_tail) == (direct.n_failed, direct.missing_tail)


def test_read_ahead_raises_the_error_at_its_item():
    def frames():
        yield from range(3)
        raise ValueError("clip.mp4: frame 3 cannot be decoded")

    got = []
    with pytest.raises(ValueError, match="frame 3"):
        for item in read_ahead(frames(), 2):
            got.append(item)
    assert got == [0, 1, 2]


def test_read_ahead_stops_early_and_releases_the_decoder(video):
    with open_video(video) as src, closing(read_ahead(src, 2)) as decoded:
        for frame in decoded:
            if frame.index == 2:
                break
    assert src._capture is None
    assert not _read_ahead_threads()


def test_read_ahead_memory_stays_bounded(tmp_path):
    path = make_video(tmp_path / "long.avi", 60, fourcc="MJPG", size=(320, 240))
    frame_bytes = 320 * 240 * 3
    n, peak = _good_frames_and_peak_memory(read_ahead(open_video(path), 4))
    assert n == 60
    assert peak < 10 * frame_bytes, f"peak {peak} bytes for {frame_bytes}-byte frames"


@pytest.mark.parametrize("depth", [0, -1, 1.5, "4"])
def test_read_ahead_refuses_a_bad_depth(depth):
    with pytest.raises(ValueError, match="depth"):
        read_ahead(range(3), depth)


# -- image folders -------------------------------------------------------------------------

def write_folder(folder, images, names=None, ext="png"):
    folder.mkdir(exist_ok=True)
    names = names or [f"frame{i}.{ext}" for i in range(len(images))]
    for name, img in zip(names, images):
        assert cv2.imwrite(str(folder / name), img)
    return folder


def test_folder_is_sorted_naturally_and_uses_default_fps(tmp_path):
    images = [np.full((H, W), 10 * i, np.uint8) for i in range(12)]
    folder = write_folder(tmp_path / "seq", images)
    (folder / "notes.txt").write_text("not an image")
    src = open_video(folder)
    assert src.kind == "images" and src.fps == DEFAULT_FPS and src.fps_origin == "default"
    frames = list(src)
    assert [int(f.image[0, 0]) for f in frames] == [10 * i for i in range(12)]
    np.testing.assert_allclose([f.timestamp for f in frames], np.arange(12) / DEFAULT_FPS)


def test_folder_keeps_16_bit_and_grey(tmp_path):
    images = [(np.arange(H * W).reshape(H, W) * 9 + i).astype(np.uint16) for i in range(3)]
    folder = write_folder(tmp_path / "deep", images, ext="tif")
    src = open_video(folder, fps=50, start=1)
    assert src.dtype == np.uint16 and src.channels == 1
    frames = list(src)
    assert [f.index for f in frames] == [1, 2]
    np.testing.assert_array_equal(frames[0].image, images[1])
    assert frames[1].timestamp == pytest.approx(0.04)
    grey = to_gray_float(frames[0].image)
    assert grey.dtype == np.float32 and grey.min() >= 0 and grey.max() <= 1
    assert grey.max() == pytest.approx(images[1].max() / 65535, rel=1e-6)


def test_folder_with_a_broken_image_marks_it_lost(tmp_path):
    images = [np.full((H, W, 3), 30 * i, np.uint8) for i in range(4)]
    folder = write_folder(tmp_path / "seq", images)
    (folder / "frame2.png").write_bytes(b"not a png")
    src = open_video(folder)
    frames = list(src)
    assert [f.ok for f in frames] == [True, True, False, True]
    assert src.n_failed == 1


def test_a_video_frame_of_another_size_is_lost_a_photograph_is_placed(tmp_path):
    """The frames of a video (a folder given a frame rate) share one size, and one of
    another is damage: lost. Photographs (no frame rate) may each have their own: each is
    fitted onto the first's canvas, and where it went is recorded."""
    rng = np.random.default_rng(0)
    first = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    other = rng.integers(0, 256, (H // 2, W // 2, 3), dtype=np.uint8)
    folder = write_folder(tmp_path / "seq", [first, first, first[:H - 2]])
    with open_video(folder, fps=25) as video:
        assert [f.ok for f in video] == [True, True, False] and video.placed == {}
    folder = write_folder(tmp_path / "photos", [first, np.repeat(np.repeat(other, 4, 0), 4, 1)])
    with open_video(folder) as video:
        frames = list(video)
        assert [f.ok for f in frames] == [True, True]
        assert video.placed == {1: {"file": "frame1.png", "size": [2 * W, 2 * H],
                                    "scale": [0.5, 0.5], "offset": [-0.25, -0.25]}}
        assert input_metadata(video)["placed"]["1"]["file"] == "frame1.png"
    # the photograph shrunk onto the canvas: its own pixels, 2x2 blocks averaged back
    np.testing.assert_array_equal(frames[1].image, np.repeat(np.repeat(other, 2, 0), 2, 1))
    with open_video(write_folder(tmp_path / "one", [first, first])) as video:
        list(video)
        assert "placed" not in input_metadata(video)


def _photo_with_orientation(path, orientation, *, mode="RGB"):
    """An asymmetric picture saved with an EXIF orientation tag (stored 48 wide, 32 high)."""
    from PIL import Image

    pixels = np.zeros((32, 48, 4), np.uint8)
    pixels[..., 3] = 255
    pixels[:8, :16, 0] = 250          # a red block in the stored top-left corner
    pixels[24:, 40:, 1] = 200         # a green one bottom right
    pixels[:, 20:24, 2] = np.arange(32, dtype=np.uint8)[:, None] * 8     # a blue ramp down
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(pixels if mode == "RGBA" else pixels[..., :3], mode).save(
        path, exif=exif.tobytes(), **({"quality": 95} if path.suffix == ".jpg" else {}))
    return path


@pytest.mark.parametrize("orientation", range(1, 9))
def test_photograph_is_read_upright_by_its_exif_orientation(tmp_path, orientation):
    # OpenCV turns a photograph by its tag when it converts the pixels: the reference
    path = _photo_with_orientation(tmp_path / "p.jpg", orientation)
    upright = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert upright.shape[:2] == ((48, 32) if orientation >= 5 else (32, 48))
    np.testing.assert_array_equal(read_image(path), upright)
    with open_video(path) as src:
        assert src.size == upright.shape[1::-1]
        np.testing.assert_array_equal(next(iter(src)).image, upright)


def test_orientation_keeps_alpha_and_a_folder_of_mixed_tags_is_one_size(tmp_path):
    # a portrait photograph stored on its side with its tag, then the same picture stored
    # as it is shown: one size, one picture (read unturned, the second was another size)
    folder = tmp_path / "seq"
    folder.mkdir()
    upright = read_image(_photo_with_orientation(folder / "a.png", 6, mode="RGBA"))
    assert upright.shape == (48, 32, 4) and (upright[..., 3] == 255).all()
    cv2.imwrite(str(folder / "b.png"), upright)
    frames = list(open_video(folder))
    assert [f.ok for f in frames] == [True, True]
    np.testing.assert_array_equal(frames[0].image, frames[1].image)


def test_unreadable_exif_reads_as_upright(tmp_path, monkeypatch):
    path = tmp_path / "p.png"
    cv2.imwrite(str(path), np.zeros((10, 20, 3), np.uint8))
    assert read_image(path).shape == (10, 20, 3)
    assert read_image(tmp_path / "missing.png") is None
    # a picture larger than Pillow decodes by default (a scan, a stitched panorama): its
    # header is read all the same, quietly
    from PIL import Image

    tagged = _photo_with_orientation(tmp_path / "big.jpg", 6)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)     # 48 x 32 is over it
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_image(tagged).shape == (48, 32, 3)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 500)      # past twice it: an error
    assert read_image(tagged).shape == (32, 48, 3)          # read as stored, not refused


def test_empty_folder(tmp_path):
    (tmp_path / "nothing").mkdir()
    with pytest.raises(ValueError, match=r"nothing: folder holds no images"):
        open_video(tmp_path / "nothing")
    (tmp_path / "nothing" / "IMG_0001.HEIC").write_bytes(b"\x00\x00\x00\x18ftypheic")
    with pytest.raises(ValueError, match=r"folder holds no images .*its 1 HEIF/AVIF "
                                         r"photograph \(IMG_0001\.HEIC\), as phones"):
        open_video(tmp_path / "nothing")
    (tmp_path / "nothing" / "IMG_0002.heif").write_bytes(b"\x00\x00\x00\x18ftypheic")
    with pytest.raises(ValueError, match=r"its 2 HEIF/AVIF photographs "
                                         r"\(IMG_0001\.HEIC, \.\.\.\)"):
        open_video(tmp_path / "nothing")


def test_a_folder_of_videos_is_not_taken_for_an_empty_image_folder(tmp_path, caplog):
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in ("take2.mp4", "take10.MOV", "take1.mp4"):
        (folder / name).write_bytes(b"\x00")
    with pytest.raises(ValueError, match=r"clips: folder holds no images .*; it holds 3 videos "
                                         r"\(take1\.mp4, take2\.mp4, take10\.MOV\): give a "
                                         r"video's own path, or analyse each with "
                                         r"'faceanalysis batch'$"):
        open_video(folder)
    # frames with a video beside them: the images are the frames, and the video is said to
    # be left unread, once however often the folder is opened
    cv2.imwrite(str(folder / "f0.png"), np.zeros((64, 64, 3), np.uint8))
    with caplog.at_level("WARNING", logger="faceanalysis.io.video"):
        for _ in range(2):
            with open_video(folder) as src:
                assert src.kind == "images" and src.n_frames == 1
    said = [r.getMessage() for r in caplog.records if "not read" in r.getMessage()]
    assert said == [f"{folder}: the folder's images are read as the frames (1); 3 videos "
                    "(take1.mp4, take2.mp4, take10.MOV) in it are not read (give a video's own "
                    "path to analyse it)"]


def test_folder_start_beyond_end(tmp_path):
    folder = write_folder(tmp_path / "seq", [np.zeros((H, W), np.uint8)] * 3)
    with pytest.raises(ValueError, match=r"start \(3\) is beyond the last frame \(2\)"):
        open_video(folder, start=3)


# -- pixel normalisation -------------------------------------------------------------------









def test_frame_is_a_plain_record():
    f = Frame(3, 0.1, None, False)
    assert (f.index, f.ok) == (3, False)


# -- writing overlays (BGR frames, synth's atomic writer) ----------------------------------

def VideoWriter(path, fps, size, **kwargs):
    from synth.render.video import VideoWriter as _VideoWriter

    return _VideoWriter(path, fps, size, channel_order="bgr", **kwargs)


def test_writer_round_trip(tmp_path):
    out = tmp_path / "overlay.mp4"
    with VideoWriter(out, fps=20, size=(W, H)) as writer:
        for i in range(8):
            writer.write(frame_image(i, color=i % 2 == 0))
    assert writer.path == out and out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["overlay.mp4"]
    frames = list(open_video(out))
    assert len(frames) == 8
    assert [brightness_index(f.image) for f in frames] == list(range(8))
    assert open_video(out).fps == pytest.approx(20)


def test_writer_interrupted_leaves_nothing(tmp_path):
    out = tmp_path / "overlay.mp4"
    with pytest.raises(RuntimeError), VideoWriter(out, fps=20, size=(W, H)) as writer:
        writer.write(frame_image(0))
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_writer_keeps_previous_result_when_interrupted(tmp_path):
    out = tmp_path / "overlay.mp4"
    out.write_bytes(b"previous complete result")
    with pytest.raises(KeyboardInterrupt), VideoWriter(out, fps=20, size=(W, H)) as writer:
        writer.write(frame_image(0))
        raise KeyboardInterrupt
    assert out.read_bytes() == b"previous complete result"
    assert list(tmp_path.iterdir()) == [out]


def test_writer_rejects_wrong_size_and_empty_video(tmp_path):
    out = tmp_path / "o.mp4"
    writer = VideoWriter(out, fps=20, size=(W, H))
    with pytest.raises(ValueError, match=r"frame 0 is 10x10, expected 96x64"):
        writer.write(np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match="no frames"):
        writer.close()
    assert list(tmp_path.iterdir()) == []


def test_writer_falls_back_to_mjpg_avi(tmp_path, monkeypatch, caplog):
    codecs = ((".mp4", "XXXX"), (".avi", "MJPG"))
    with caplog.at_level("INFO"), VideoWriter(tmp_path / "o.mp4", 25, (W, H),
                                              codecs=codecs) as writer:
        writer.write(frame_image(1))
    assert writer.path == tmp_path / "o.avi" and writer.path.exists()
    assert "Motion-JPEG" in caplog.text
    assert len(list(open_video(writer.path))) == 1


@pytest.mark.parametrize(("args", "match"), [
    (dict(fps=0, size=(4, 4)), "fps"),
    (dict(fps=25, size=(0, 4)), "size"),
    (dict(fps=25, size="big"), "size"),
])
def test_writer_validates(tmp_path, args, match):
    with pytest.raises(ValueError, match=match):
        VideoWriter(tmp_path / "o.mp4", args["fps"], args["size"])


def test_folder_of_webp_images(tmp_path):
    folder = tmp_path / "seq"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"f{i}.webp"), frame_image(i), [cv2.IMWRITE_WEBP_QUALITY, 101])
    src = open_video(folder)
    frames = list(src)
    assert src.kind == "images" and [f.ok for f in frames] == [True] * 3
    np.testing.assert_array_equal(frames[2].image, frame_image(2))     # quality 101: lossless


def test_single_image_is_one_frame(tmp_path):
    path = tmp_path / "still.png"
    cv2.imwrite(str(path), np.full((H, W), 4000, np.uint16))
    src = open_video(path)
    frames = list(src)
    assert src.kind == "images" and src.n_frames == 1 and len(frames) == 1
    assert frames[0].image.dtype == np.uint16 and frames[0].image[0, 0] == 4000
    broken = tmp_path / "broken.jpg"
    broken.write_bytes(b"nope")
    with pytest.raises(ValueError, match=r"broken\.jpg: cannot decode image"):
        open_video(broken)


def test_unreadable_file(tmp_path, video):
    import os

    if os.geteuid() == 0:
        pytest.skip("root reads everything")
    video.chmod(0)
    try:
        with pytest.raises(PermissionError, match=r"clip\.mp4: permission denied"):
            open_video(video)
    finally:
        video.chmod(0o644)


@pytest.mark.parametrize("announced", [20, None])
def test_frames_beyond_an_estimated_count_are_still_read(video, announced):
    src = open_video(video)
    src.frame_count = announced  # containers that estimate their length (or give none)
    frames = list(src)
    assert [f.index for f in frames] == list(range(30)) and all(f.ok for f in frames)
    assert src.missing_tail == 0 and src.n_failed == 0


def test_writer_refuses_to_replace_a_folder(tmp_path):
    (tmp_path / "overlay.mp4").mkdir()
    with pytest.raises(ValueError, match="not a regular file"):
        VideoWriter(tmp_path / "overlay.mp4", 25, (W, H))


def test_damaged_first_frame_is_lost_not_fatal(tmp_path):
    path = make_video(tmp_path / "first.avi", 10, fourcc="MJPG", noise=True)
    data = bytearray(path.read_bytes())
    first = data.find(b"\xff\xd8")               # JPEG start of the first frame
    second = data.find(b"\xff\xd8", first + 2)   # ... and of the second
    data[first:second - 8] = bytes(second - 8 - first)
    path.write_bytes(bytes(data))
    src = open_video(path)
    assert src.size == (W, H)
    frames = list(src)
    assert [f.ok for f in frames] == [False] + [True] * 9
    assert src.n_failed == 1


def test_eight_bit_brings_sixteen_bit_frames_to_their_eight_bit_originals(tmp_path):
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "f.png"), frame.astype(np.uint16) * 257)
    src = open_video(tmp_path / "f.png", eight_bit=True)
    image = next(iter(src)).image
    assert src.dtype == np.uint16                 # the input as stored
    assert image.dtype == np.uint8 and np.array_equal(image, frame)


# ------------------------------------------------------------------ frames in memory
def test_frames_in_memory_come_out_as_a_decoder_gives_them():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (5, H, W, 3), dtype=np.uint8)
    with open_video(rgb, fps=10, start=1, end=4) as video:
        assert video.kind == "frames" and video.path is None and video.n_frames == 3
        assert video.size == (W, H) and video.fps == 10 and video.fps_origin == "user"
        got = list(video)
    assert [(f.index, f.timestamp, f.ok) for f in got] == [(1, 0.1, True), (2, 0.2, True),
                                                          (3, 0.3, True)]
    # RGB in, OpenCV's BGR out; the caller's array untouched
    for f in got:
        np.testing.assert_array_equal(f.image, rgb[f.index][:, :, ::-1])
    assert input_metadata(open_video(rgb))["path"] is None
    # OpenCV's own frames, BGR, as they are
    with open_video(Frames(rgb[:, :, :, ::-1], channel_order="bgr")) as video:
        np.testing.assert_array_equal(next(iter(video)).image, rgb[0][:, :, ::-1])
    # a list of frames, grey, 16 bits: as an image folder's, brought to 8 bits on request
    grey = [np.full((H, W), 257 * v, np.uint16) for v in (10, 20)]
    with open_video(grey, eight_bit=True) as video:
        assert video.fps == DEFAULT_FPS and video.fps_origin == "default"
        assert [int(f.image[0, 0]) for f in video] == [10, 20]
    # each frame a new array: drawing on it leaves the caller's as they were
    g = np.zeros((2, H, W), np.uint8)
    for f in open_video(g):
        f.image[:] = 255
    assert not g.any()
    # floats in [0, 1], RGBA
    rgba = np.zeros((2, H, W, 4))
    rgba[..., 0] = 1.0
    with open_video(Frames(rgba, fps=5), eight_bit=True) as video:
        first = next(iter(video)).image
    assert first.shape == (H, W, 4) and first[0, 0].tolist() == [0, 0, 255, 0]


def test_frames_in_memory_are_named_in_messages_and_checked():
    clip = as_video(np.zeros((3, H, W, 3), np.uint8))
    assert isinstance(clip, Frames) and str(clip) == f"<frames: 3 frames of {W}x{H}>"
    assert as_video(clip) is clip and as_video("x.mp4") == "x.mp4"
    with pytest.raises(ValueError, match="of 96x64>: frames are 96x64 pixels"):
        open_video(clip, min_size=W + 1)
    with pytest.raises(ValueError, match=r"end \(4\) is beyond the 3 frames of <frames"):
        open_video(clip, end=4)
    for bad, match in [(np.zeros((H, W)), "shape"), ([], "no frame"),
                       (np.zeros((H, W, 3), np.uint8), "one \\(H, W, C\\) picture"),
                       ([np.zeros((H, W)), np.zeros((H, W + 1))], "frame 1 is"),
                       (np.zeros((2, H, W, 2)), "RGB"), (np.zeros((2, H, W), np.int32), "uint8"),
                       (object(), "sequence of arrays")]:
        with pytest.raises(ValueError, match=match):
            Frames(bad)
    with pytest.raises(ValueError, match="fps"):
        Frames(np.zeros((2, H, W)), fps=0)
    # floats in 0..255: the first frame at the call, a later one as it is read, by number
    with pytest.raises(ValueError, match=r"frames: frame 0: float pixels must lie in \[0, 1\]"):
        Frames(np.full((2, H, W, 3), 255.0))
    later = np.zeros((3, H, W), np.float32)
    later[2] = 255
    with (pytest.raises(ValueError, match=r"<frames: 3 frames of 96x64>: frame 2: float pixels "
                                          r"must lie in \[0, 1\], got values in \[255, 255\]: "
                                          "divide by 255"),
          open_video(later, eight_bit=True) as video):
        list(video)
    with pytest.raises(ValueError, match="'rgb' or 'bgr'"):
        Frames(np.zeros((2, H, W)), channel_order="BGR")


def test_a_video_gone_before_it_is_read_from_far_in_is_named(tmp_path):
    from faceanalysis.io.video import SEEK_FROM, display_stamps, seek_video

    path = make_video(tmp_path / "clip.avi", SEEK_FROM + 5, fourcc="MJPG")
    src = open_video(path, start=SEEK_FROM + 1)
    path.unlink()
    assert display_stamps(path) is None and seek_video(path, SEEK_FROM + 1) is None
    with pytest.raises(ValueError, match="cannot be opened as a video any more"):
        list(src)

"""classify's memory does not grow with the video: no per-frame displacement is kept."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from faceanalysis.flow.recognition import _FrameStore, classify_video


def test_the_frame_store_reads_back_what_was_written_and_nan_elsewhere():
    store = _FrameStore(5, (3, 2))
    try:
        a = np.arange(6, dtype=np.float32).reshape(3, 2)
        store[1] = a
        store[3] = -a
        got = store[0:5]
        assert got.shape == (5, 3, 2)
        assert np.isnan(got[[0, 2, 4]]).all()
        np.testing.assert_array_equal(got[1], a)
        np.testing.assert_array_equal(store[3:4][0], -a)
    finally:
        store.close()


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """One rendered smile played back and forth: 24 and 96 frames of the same motion."""
    from synth.render.sequence import synthesize
    from synth.render.video import VideoWriter

    seq = synthesize(expression="happiness", frames=12, size=160, seed=11, flow=False)
    cycle = list(seq.images) + list(seq.images)[::-1]
    out = tmp_path_factory.mktemp("clips")
    paths = {}
    for n in (24, 96):
        writer = VideoWriter(out / f"clip{n}.mp4", 24.0, (160, 160))
        for t in range(n):
            writer.write(cycle[t % len(cycle)])
        paths[n] = writer.close()
    return paths


def _peak(video) -> int:
    tracemalloc.start()
    try:
        classify_video(video)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_per_frame_state_does_not_accumulate(clips, monkeypatch):
    import faceanalysis.flow.recognition as recognition

    # frames are cleaned a chunk at a time; with chunks shorter than both clips, what grows
    # from one clip to the other is only what is kept per frame
    monkeypatch.setattr(recognition, "_CHUNK", 8)
    _peak(clips[24])                      # templates and caches are built once, not counted
    short, long = _peak(clips[24]), _peak(clips[96])
    per_frame = (long - short) / 72
    # the displacement on the 64 x 48 grid alone is 24.6 kB a frame in float32; what is
    # kept per frame now is the tracked table and a few numbers
    assert per_frame < 6000, f"{per_frame:.0f} bytes a frame"

"""Picture coding measures: blocking and sharpness."""

import cv2
import numpy as np
import pytest

from faceanalysis.io.picture import blockiness, sharpness


@pytest.fixture(scope="module")
def face():
    from synth.render.sequence import synthesize

    img = synthesize(frames=1, size=192, seed=3, flow=False, texture_size=256,
                     supersample=1).images[0]
    return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2BGR)


def _jpeg(img, quality):
    ok, data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.imdecode(data, cv2.IMREAD_COLOR)


def test_a_coarser_coding_shows_its_blocks_more(face):
    plain = blockiness(face)
    fine, coarse = blockiness(_jpeg(face, 95)), blockiness(_jpeg(face, 5))
    assert 0.8 < plain < 1.2 and 0.8 < fine < 1.3
    assert coarse > 1.5 * fine
    # the same picture moved by half a block: its blocks no longer lie on the grid
    assert blockiness(_jpeg(face, 5)[4:, 4:]) < 0.8 * coarse
    # and a coarse coding is less sharp
    assert sharpness(_jpeg(face, 5)) < sharpness(_jpeg(face, 95))


def test_channel_orders_grey_and_degenerate_frames(face):
    grey = cv2.cvtColor(face, cv2.COLOR_BGR2GRAY)
    assert blockiness(grey) == pytest.approx(blockiness(face), rel=1e-6)
    assert blockiness(face[:, :, ::-1], channel_order="rgb") == pytest.approx(
        blockiness(face), rel=1e-6)
    assert sharpness(grey[..., None]) == pytest.approx(sharpness(face), rel=1e-6)
    assert np.isnan(blockiness(np.full((64, 64), 7, np.uint8)))       # flat
    assert np.isnan(blockiness(grey[:10, :100]))                      # under two blocks
    assert sharpness(np.full((64, 64), 7, np.uint8)) == 0.0
    with pytest.raises(ValueError, match="'bgr' or 'rgb'"):
        blockiness(face, channel_order="hsv")
    with pytest.raises(ValueError, match="shape"):
        sharpness(np.zeros((4, 4, 4, 4)))

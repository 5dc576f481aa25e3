"""The snake solver's parameters (:mod:`trackers.snake_types`)."""

from trackers.snake_types import SnakeParams


def test_defaults_are_the_papers():
    p = SnakeParams()
    assert p.gamma / p.dt == 0.5 and p.a == 1.0 and p.b == 0.5 and p.nu == 0.2
    assert p.p == 0.001

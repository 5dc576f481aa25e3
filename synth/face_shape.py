"""The identity of a generated face: :class:`FaceShape`.

Sixteen dimensionless multipliers (1.0 = the default face) that
:func:`~synth.mesh.generate_face_mesh` turns into positions and tissue depths, with their
validation and a deterministic random draw per seed. Apart from the mesh generator
because callers that only choose or vary identities (personalisation, the evaluation
suite, the renderer's sequences) need nothing else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

__all__ = ["FaceShape"]

_SHAPE_MIN, _SHAPE_MAX = 0.5, 1.6


@dataclass(frozen=True, init=False)
class FaceShape:
    """Identity of a generated face: dimensionless multipliers, 1.0 = the default face.

    Parameters
    ----------
    face_width, face_length : float
        Overall width and (hairline-to-chin) length.
    forehead_height, brow_height : float
        Hairline-to-brow height and brow-to-eye distance.
    brow_prominence : float
        Forward bulge of the brow ridge.
    eye_spacing, eye_size : float
        Distance between the eye centres and size of the eye openings and eyeballs.
    nose_length, nose_width, nose_protrusion : float
        Nasion-to-tip length, alar width, forward projection of the nose.
    mouth_width, upper_lip_thickness, lower_lip_thickness : float
        Width of the mouth, height and volume of the upper and lower lip.
    chin_height, jaw_width, cheek_fullness : float
        Mouth-to-chin height, width of the lower face, volume and tissue depth of the cheeks.

    Every value must lie in [0.5, 1.6]; parameters are keyword-only.  Unknown names or values
    out of range raise ``ValueError``.

    Examples
    --------
    >>> FaceShape(nose_length=1.1).nose_length
    1.1
    >>> FaceShape.random(3) == FaceShape.random(3)
    True
    """

    face_width: float = 1.0
    face_length: float = 1.0
    forehead_height: float = 1.0
    brow_height: float = 1.0
    brow_prominence: float = 1.0
    eye_spacing: float = 1.0
    eye_size: float = 1.0
    nose_length: float = 1.0
    nose_width: float = 1.0
    nose_protrusion: float = 1.0
    mouth_width: float = 1.0
    upper_lip_thickness: float = 1.0
    lower_lip_thickness: float = 1.0
    chin_height: float = 1.0
    jaw_width: float = 1.0
    cheek_fullness: float = 1.0

    def __init__(self, **params: float) -> None:
        names = [f.name for f in fields(self)]
        unknown = sorted(set(params) - set(names))
        if unknown:
            raise ValueError(
                f"unknown FaceShape parameter(s) {unknown}; valid names are {names}"
            )
        bad = []
        for name in names:
            value = params.get(name, 1.0)
            try:
                value = float(value)
            except (TypeError, ValueError):
                bad.append(f"{name}={value!r}")
                continue
            if not (math.isfinite(value) and _SHAPE_MIN <= value <= _SHAPE_MAX):
                bad.append(f"{name}={value!r}")
            object.__setattr__(self, name, value)
        if bad:
            raise ValueError(
                f"FaceShape parameter(s) out of range [{_SHAPE_MIN}, {_SHAPE_MAX}]: "
                + ", ".join(bad)
            )

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Names of all shape parameters, in declaration order."""
        return tuple(f.name for f in fields(cls))

    def as_dict(self) -> dict[str, float]:
        """The parameters as a plain ``{name: value}`` dictionary."""
        return {name: getattr(self, name) for name in self.names()}

    @classmethod
    def random(cls, seed: int, *, spread: float = 1.0) -> FaceShape:
        """A plausible random identity, deterministic per ``seed``.

        Each multiplier is ``1 + spread * 0.075 * g`` with ``g`` a standard normal clipped to
        [-2, 2], so at ``spread=1`` every parameter stays within +-15 % of the default.
        Width-like parameters are mildly correlated (a wide face tends to have a wide jaw).

        Parameters
        ----------
        seed : int
            Seed of the generator (``numpy.random.default_rng``).
        spread : float, optional
            Scale of the variation, in [0, 4]; 0 gives the default face.

        Returns
        -------
        FaceShape

        Examples
        --------
        >>> s = FaceShape.random(0)
        >>> all(0.85 <= v <= 1.15 for v in s.as_dict().values())
        True
        """
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        spread = float(spread)
        if not (math.isfinite(spread) and 0.0 <= spread <= 4.0):
            raise ValueError(f"spread must be in [0, 4], got {spread!r}")
        rng = np.random.default_rng(int(seed))
        names = cls.names()
        g = np.clip(rng.standard_normal(len(names)), -2.0, 2.0)
        common = float(np.clip(rng.standard_normal(), -2.0, 2.0))
        values = {}
        for k, name in enumerate(names):
            z = g[k]
            if name in ("face_width", "jaw_width", "mouth_width", "nose_width"):
                z = float(np.clip(0.6 * z + 0.8 * common, -2.0, 2.0))
            value = 1.0 + spread * 0.075 * z
            values[name] = float(np.clip(value, _SHAPE_MIN, _SHAPE_MAX))
        return cls(**values)


def _as_shape(shape) -> FaceShape:
    if shape is None:
        return FaceShape()
    if isinstance(shape, FaceShape):
        return shape
    if isinstance(shape, dict):
        return FaceShape(**shape)
    raise ValueError(f"shape must be a FaceShape, a dict or None, got {type(shape).__name__}")

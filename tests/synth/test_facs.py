"""Tests of the FACS tables, timing curves and the muscles -> AU inverse (synth.facs)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from synth.facs import (
    ACTION_UNITS,
    AU_NAMES,
    CORE_AUS,
    EXPRESSIONS,
    JAW,
    MAX_JAW_ROTATION,
    MUSCLE_NAMES,
    PAIRED_MUSCLES,
    TIMELINE_COLUMNS,
    au_column,
    au_timeline,
    aus_to_contractions,
    envelope,
    expression_aus,
    expression_timeline,
    facs_letter,
    from_facs_scale,
    muscles_to_aus,
    to_facs_scale,
)

REQUIRED_AUS = (1, 2, 4, 6, 9, 10, 12, 14, 15, 16, 17, 20, 23, 25, 26, 27)
DESIGN_MUSCLES = {
    "frontalis_inner", "frontalis_major", "frontalis_outer", "corrugator",
    "zygomaticus_major", "zygomaticus_minor", "levator_labii_nasi", "levator_labii",
    "depressor_anguli", "depressor_labii", "mentalis", "buccinator", "risorius",
}


def test_muscle_names_follow_design():
    assert set(PAIRED_MUSCLES) == DESIGN_MUSCLES
    expected = {f"{m}_{s}" for m in DESIGN_MUSCLES for s in "lr"}
    expected |= {"orbicularis_oris", "orbicularis_oculi_l", "orbicularis_oculi_r"}
    assert set(MUSCLE_NAMES) == expected
    assert len(MUSCLE_NAMES) == len(set(MUSCLE_NAMES)) == 29
    assert (*MUSCLE_NAMES, "jaw_rotation") == TIMELINE_COLUMNS


def test_action_units_cover_the_required_set_with_known_muscles():
    assert set(REQUIRED_AUS) <= set(ACTION_UNITS)
    assert set(ACTION_UNITS) == set(AU_NAMES)
    assert set(CORE_AUS) <= set(ACTION_UNITS)
    for au, pattern in ACTION_UNITS.items():
        assert pattern, au
        assert set(pattern) <= set(TIMELINE_COLUMNS), au
        for muscle, value in pattern.items():
            if muscle == JAW:
                assert 0 < value <= MAX_JAW_ROTATION
            else:
                assert 0 < value <= 1, (au, muscle)
        # bilateral action units are left/right symmetric
        for muscle, value in pattern.items():
            if muscle.endswith("_l"):
                assert pattern[muscle[:-2] + "_r"] == value


def test_standard_facs_muscles():
    primary = {
        1: "frontalis_inner_l", 2: "frontalis_outer_l", 4: "corrugator_l",
        6: "orbicularis_oculi_l", 9: "levator_labii_nasi_l", 10: "levator_labii_l",
        12: "zygomaticus_major_l", 14: "buccinator_l", 15: "depressor_anguli_l",
        16: "depressor_labii_l", 17: "mentalis_l", 20: "risorius_l", 23: "orbicularis_oris",
    }
    for au, muscle in primary.items():
        pattern = ACTION_UNITS[au]
        assert max(pattern, key=pattern.get) == muscle, au
    assert ACTION_UNITS[26][JAW] == pytest.approx(0.15)
    assert ACTION_UNITS[27][JAW] == pytest.approx(0.30)
    assert 0 < ACTION_UNITS[25][JAW] < ACTION_UNITS[26][JAW]
    assert 5 not in ACTION_UNITS  # no levator palpebrae in the model


def test_expressions_are_emfacs_prototypes():
    assert set(EXPRESSIONS) == {"happiness", "sadness", "surprise", "fear", "anger", "disgust"}
    must = {
        "happiness": {6, 12}, "sadness": {1, 4, 15}, "surprise": {1, 2, 26},
        "fear": {1, 2, 4, 20, 26}, "anger": {4, 23}, "disgust": {9, 10, 15, 16},
    }
    for name, aus in EXPRESSIONS.items():
        assert must[name] <= set(aus), name
        assert set(aus) <= set(ACTION_UNITS)
        assert all(0 < v <= 1 for v in aus.values())
        c = aus_to_contractions(aus)
        assert set(c) == set(TIMELINE_COLUMNS)


def test_aus_to_contractions_combines_and_clips():
    c = aus_to_contractions({1: 1.0, 2: 1.0})
    # frontalis_major gets 0.3 + 0.5
    assert c["frontalis_major_l"] == pytest.approx(0.8)
    c = aus_to_contractions({6: 1.0, 7: 1.0})
    assert c["orbicularis_oculi_l"] == 1.0  # 0.7 + 0.35 clipped
    c = aus_to_contractions({26: 1.0, 27: 1.0})
    assert c[JAW] == pytest.approx(0.45)
    c = aus_to_contractions({12: 0.5}, emphasis=3 / 2)
    assert c["zygomaticus_major_r"] == pytest.approx(0.75)
    c = aus_to_contractions({"AU12": 1.0}, emphasis=2.0)
    assert c["zygomaticus_major_l"] == 1.0
    assert all(v == 0.0 for v in aus_to_contractions({}).values())


def test_unilateral_action_units():
    left = aus_to_contractions({"12L": 0.7})
    right = aus_to_contractions({"AU12_r": 0.7})
    assert left["zygomaticus_major_l"] == 0.7 and left["zygomaticus_major_r"] == 0.0
    assert right["zygomaticus_major_r"] == 0.7 and right["zygomaticus_major_l"] == 0.0
    # mirror images of each other
    for name in MUSCLE_NAMES:
        if name.endswith("_l"):
            assert left[name] == right[name[:-2] + "_r"]
    # unpaired muscles still act under a one-sided AU
    assert aus_to_contractions({"23L": 1.0})["orbicularis_oris"] == 1.0


@pytest.mark.parametrize("bad", [{5: 1.0}, {"AU99": 0.5}, {"smile": 1.0}, {True: 1.0}])
def test_unknown_action_units_raise(bad):
    with pytest.raises(ValueError, match="action unit"):
        aus_to_contractions(bad)


@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan"), "high"])
def test_bad_intensities_raise(value):
    with pytest.raises(ValueError, match="intensity"):
        aus_to_contractions({12: value})


def test_bad_emphasis_and_names_raise():
    with pytest.raises(ValueError, match="emphasis"):
        aus_to_contractions({12: 0.5}, emphasis=-1)
    with pytest.raises(ValueError, match="emphasis"):
        expression_timeline("fear", 10, emphasis=float("inf"))
    with pytest.raises(ValueError, match="expression"):
        expression_timeline("joy", 10)
    with pytest.raises(ValueError, match="mapping"):
        aus_to_contractions([12])


# -- timing ------------------------------------------------------------------------------


def test_envelope_shape():
    e = envelope(41)
    assert e.shape == (41,)
    assert e[0] == 0.0 and e[-1] == 0.0
    assert e.max() == 1.0
    # onset 30 % of the 40-frame span: apex reached at frame 12, held until frame 28
    assert np.all(e[12:29] == 1.0)
    assert np.all(np.diff(e[:13]) > 0) and np.all(np.diff(e[28:]) < 0)
    # cosine ease: symmetric rise, half way at half the onset
    np.testing.assert_allclose(e[6], 0.5, atol=1e-12)
    np.testing.assert_allclose(e[:13], e[40:27:-1])


def test_envelope_frames_and_fractions():
    e = envelope(20, onset=4, apex=5, offset=4, delay=3)
    assert np.all(e[:4] == 0.0)
    assert np.all(e[7:13] == 1.0)
    assert np.all(e[16:] == 0.0)
    lin = envelope(11, onset=0.5, apex=0.0, offset=0.5, ease="linear")
    np.testing.assert_allclose(lin, [0, .2, .4, .6, .8, 1, .8, .6, .4, .2, 0], atol=1e-12)
    sm = envelope(11, onset=0.5, apex=0.0, offset=0.5, ease="smoothstep")
    assert sm[1] < lin[1] and sm[5] == 1.0
    # a clip that ends at the apex (no offset)
    hold = envelope(10, onset=0.5, apex=0.5, offset=0.0)
    assert hold[-1] == 1.0
    assert envelope(1, onset=0, apex=0, offset=0)[0] == 1.0


@pytest.mark.parametrize("kwargs", [
    {"onset": 0.6, "apex": 0.6}, {"onset": -1}, {"apex": 1.5}, {"ease": "bounce"},
    {"offset": "slow"}, {"delay": True},
])
def test_envelope_bad_timing_raises(kwargs):
    with pytest.raises(ValueError):
        envelope(30, **kwargs)


@pytest.mark.parametrize("n", [0, -3, 2.5, "10"])
def test_envelope_bad_length_raises(n):
    with pytest.raises(ValueError, match="n_frames"):
        envelope(n)


def test_expression_timeline_surprise():
    df = expression_timeline("surprise", 40, emphasis=0.8)
    assert isinstance(df, pd.DataFrame)
    assert df.shape == (40, len(TIMELINE_COLUMNS))
    assert list(df.columns) == list(TIMELINE_COLUMNS)
    assert df.index.name == "frame"
    np.testing.assert_array_equal(df.index, np.arange(40))
    muscles = df[list(MUSCLE_NAMES)].to_numpy()
    assert muscles.min() >= 0.0 and muscles.max() <= 1.0
    assert df.iloc[0].abs().sum() == 0.0 and df.iloc[-1].abs().sum() == 0.0
    apex = df.iloc[20]
    assert apex["frontalis_inner_l"] == pytest.approx(0.8)
    assert apex["frontalis_outer_r"] == pytest.approx(0.8)
    assert apex[JAW] == pytest.approx(0.8 * (0.8 * 0.15 + 0.8 * 0.05))
    assert apex["zygomaticus_major_l"] == 0.0
    # left and right columns are identical for a symmetric expression
    for name in MUSCLE_NAMES:
        if name.endswith("_l"):
            np.testing.assert_array_equal(df[name], df[name[:-2] + "_r"])


@pytest.mark.parametrize("name", sorted(EXPRESSIONS))
def test_every_expression_timeline_in_range(name):
    df = expression_timeline(name, 25, emphasis=1.0, onset=5, apex=10, offset=5, delay=2)
    assert df.shape == (25, len(TIMELINE_COLUMNS))
    m = df[list(MUSCLE_NAMES)].to_numpy()
    assert np.all((m >= 0) & (m <= 1))
    assert np.all((df[JAW] >= 0) & (df[JAW] <= MAX_JAW_ROTATION))
    assert m.max() > 0.5
    active = set(df.columns[(df.abs() > 0).any()])
    expected = {k for au in EXPRESSIONS[name] for k in ACTION_UNITS[au]}
    assert active == expected


def test_au_timeline_scales_with_envelope():
    env = envelope(15, onset=0.4, apex=0.2, offset=0.4)
    df = au_timeline({12: 0.6, 17: 0.4}, 15, onset=0.4, apex=0.2, offset=0.4)
    np.testing.assert_allclose(df["zygomaticus_major_l"], 0.6 * env, atol=1e-12)
    np.testing.assert_allclose(df["mentalis_r"], 0.4 * env, atol=1e-12)


def test_expression_aus_emphasis():
    assert expression_aus("happiness") == EXPRESSIONS["happiness"]
    half = expression_aus("sadness", emphasis=0.5)
    assert half == {k: v / 2 for k, v in EXPRESSIONS["sadness"].items()}
    assert max(expression_aus("surprise", emphasis=2.0).values()) == 1.0


# -- scales and inverse ------------------------------------------------------------------


def test_scales_and_letters():
    assert to_facs_scale(1.0) == 5.0 and from_facs_scale(5.0) == 1.0
    np.testing.assert_allclose(from_facs_scale(to_facs_scale(np.linspace(0, 1, 7))),
                               np.linspace(0, 1, 7))
    with pytest.raises(ValueError):
        to_facs_scale(1.2)
    with pytest.raises(ValueError):
        from_facs_scale(-0.5)
    assert [facs_letter(x) for x in (0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0)] == [
        "", "A", "B", "C", "D", "E", "E"]
    assert au_column(1) == "AU01_r" and au_column("AU12") == "AU12_r"


def test_muscles_to_aus_recovers_single_aus():
    for au in CORE_AUS:
        for level in (0.3, 0.9):
            est = muscles_to_aus(aus_to_contractions({au: level}))
            if au != 27:  # AU 27 at low intensity is a jaw drop (AU 26) by the jaw rule
                assert est[au] == pytest.approx(level, abs=1e-4), au
            others = [a for a in CORE_AUS if a not in (au, 16, 25, 26, 27)]
            assert all(est[a] < 1e-4 for a in others), (au, est)


def test_muscles_to_aus_jaw_rule():
    est = muscles_to_aus({JAW: 0.075})
    assert est[26] == pytest.approx(0.5) and est[27] == 0.0 and est[25] == 1.0
    est = muscles_to_aus({JAW: 0.3})
    assert est[26] == 0.0 and est[27] == pytest.approx(1.0)
    est = muscles_to_aus({JAW: 0.225})
    assert est[26] == pytest.approx(0.5) and est[27] == pytest.approx(0.5)


def test_muscles_to_aus_recovers_expressions():
    for name in ("sadness", "disgust", "anger"):
        aus = EXPRESSIONS[name]
        est = muscles_to_aus(aus_to_contractions(aus))
        for au, v in aus.items():
            if au in est and au not in (7,):
                assert est[au] == pytest.approx(v, abs=1e-3), (name, au)


def test_muscles_to_aus_on_a_timeline():
    df = expression_timeline("happiness", 12)
    est = muscles_to_aus(df)
    assert list(est.columns) == [f"AU{a:02d}" for a in CORE_AUS]
    assert est.index.equals(df.index)
    assert est["AU12"].max() == pytest.approx(1.0, abs=1e-4)
    assert est["AU06"].max() == pytest.approx(0.7, abs=1e-4)
    assert est.iloc[0].abs().sum() == 0.0
    assert ((est >= 0) & (est <= 1)).all().all()


def test_muscles_to_aus_validation():
    with pytest.raises(ValueError, match="unknown muscle"):
        muscles_to_aus({"zygomatic": 0.5})
    with pytest.raises(ValueError, match="action unit"):
        muscles_to_aus({}, aus=(12, 99))
    with pytest.raises(ValueError, match="NaN"):
        muscles_to_aus({"mentalis_l": float("nan")})
    with pytest.raises(ValueError, match="mapping"):
        muscles_to_aus([0.5])

"""Model-made flow templates, the flow estimator and template-matching recognition."""

import numpy as np
import pytest

from faceanalysis.estimation.flow import FLOW_CONTROLS, FlowDesign, estimate_contractions
from faceanalysis.flow.grid import FaceGrid, rigid_basis
from faceanalysis.flow.personalize import implausible_fiducials, personalize, personalize_from_table
from faceanalysis.flow.recognition import (
    CLASSES,
    UNMATCHED,
    calibrate_threshold,
    classify_flow,
    find_segments,
    motion_energy,
    nuisance_free,
)
from faceanalysis.flow.templates import (
    EXPRESSION_NAMES,
    FlowTemplates,
    make_templates,
    preview_templates,
)

GRID = FaceGrid(rows=48, cols=36)


@pytest.fixture(scope="module")
def templates():
    from synth.model import FaceModel

    return make_templates(FaceModel.default(), grid=GRID, n_steps=4)


def _region_mean(tpl, field, name):
    m = tpl.region_masks()[name]
    return field[m].mean(axis=0)


def test_templates_have_the_model_motion(templates):
    t = templates
    assert t.control.shape == (len(t.controls), 48, 36, 2)
    assert t.controls[-1] == "jaw_rotation" and t.upper[-1] == pytest.approx(0.5)
    assert t.expression.shape == (6, 4, 48, 36, 2) and t.expressions == EXPRESSION_NAMES
    assert t.mask.sum() > 0.4 * t.mask.size
    assert t.meta["head_source"] == "tracker"
    # the jaw opens downward: the chin moves down (v grows) in the head frame
    jaw = t.control[t.controls.index("jaw_rotation")]
    assert _region_mean(t, jaw, "chin")[1] > 0.05
    # zygomaticus major pulls the mouth corner up and toward its own side
    zl = t.control[t.controls.index("zygomaticus_major_l")]
    zr = t.control[t.controls.index("zygomaticus_major_r")]
    left = t.mask & (GRID.points[..., 0] > 0.1) & (t.region == 8)
    right = t.mask & (GRID.points[..., 0] < -0.1) & (t.region == 8)
    assert zl[left].mean(axis=0)[1] < 0 and zl[left].mean(axis=0)[0] > 0
    assert np.linalg.norm(zl[left].mean(axis=0)) > 3 * np.linalg.norm(zl[right].mean(axis=0))
    assert zr[right].mean(axis=0)[0] < 0
    # frontalis raises the forehead/brows; surprise has the largest motion energy
    fm = t.control[t.controls.index("frontalis_major_l")]
    assert _region_mean(t, fm, "brows")[1] < 0
    assert np.argmax(t.energy.sum(axis=(1, 2))) == t.expressions.index("surprise")
    # expression templates grow from neutral to apex
    e = np.linalg.norm(t.expression, axis=-1).sum(axis=(2, 3))
    assert np.all(np.diff(e, axis=1) > 0)


def test_templates_roundtrip_and_previews(templates, tmp_path):
    p = templates.save(tmp_path / "t.npz")
    back = FlowTemplates.load(p)
    assert back.controls == templates.controls and back.grid == templates.grid
    np.testing.assert_allclose(back.control, templates.control, atol=1e-6)
    np.testing.assert_array_equal(back.mask, templates.mask)
    png = preview_templates(templates, tmp_path / "c.png", which="expressions")
    assert png.stat().st_size > 1000
    with pytest.raises(FileNotFoundError):
        FlowTemplates.load(tmp_path / "missing.npz")
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a flow-templates file"):
        FlowTemplates.load(tmp_path / "bad.npz")


def test_personalize_moves_features_with_the_fiducials(templates):
    same = personalize(templates, templates.fiducials)
    np.testing.assert_allclose(same.control, templates.control, atol=1e-6)
    # a subject whose mouth and chin sit lower: the jaw motion follows them down
    f = templates.fiducials.copy()
    f[6:8, 1] += 0.06
    f[10, 1] += 0.08
    low = personalize(templates, f)
    j = templates.controls.index("jaw_rotation")
    v = GRID.points[..., 1]
    mag0 = np.linalg.norm(templates.control[j], axis=-1)
    mag1 = np.linalg.norm(low.control[j], axis=-1)
    assert (mag1 * v).sum() / mag1.sum() > (mag0 * v).sum() / mag0.sum() + 0.02
    with pytest.raises(ValueError, match="fiducials"):
        personalize(templates, f[:5])


def test_personalize_from_table_refuses_a_mistracked_neutral_frame(templates, caplog):
    import pandas as pd

    from faceanalysis.io.table import FIDUCIALS

    head = dict(head_x=128.0, head_y=40.0, head_scale=90.0, head_roll=0.0)

    def table(fid_head):
        xy = np.asarray(fid_head) * 90.0 + [128.0, 40.0]
        row = {"frame": 0, "success": 1, **head}
        for n, (x, y) in zip(FIDUCIALS, xy):
            row[f"fid_{n}_x"], row[f"fid_{n}_y"] = x, y
        return pd.DataFrame([row])

    # another face's proportions: personalised
    f = templates.fiducials * [1.05, 0.97] + [0.0, 0.02]
    f[FIDUCIALS.index("chin"), 1] += 0.05
    assert implausible_fiducials(templates, f) == []
    assert personalize_from_table(templates, table(f), 0).meta.get("personalised")
    # the furrow contours slid down onto the mouth line (seen on a real video)
    bad = f.copy()
    for s in "lr":
        bad[FIDUCIALS.index(f"furrow_top_{s}"), 1] = f[FIDUCIALS.index(f"mouth_corner_{s}"), 1]
    assert implausible_fiducials(templates, bad) == ["furrow_top_l", "furrow_top_r"]
    with caplog.at_level("WARNING"):
        got = personalize_from_table(templates, table(bad), 0)
    assert got is templates
    assert "furrow_top_l, furrow_top_r too far" in caplog.text
    with pytest.raises(ValueError, match="shape"):
        implausible_fiducials(templates, f[:5])


def test_flow_estimator_recovers_contractions_under_rigid_nuisance(templates, rng):
    t = templates
    truth = np.zeros((5, len(t.controls)))
    for k, names in enumerate([("zygomaticus_major_l", "zygomaticus_major_r"),
                               ("frontalis_inner_l", "frontalis_inner_r"),
                               ("corrugator_l", "depressor_anguli_r"), ("jaw_rotation",), ()]):
        for n in names:
            truth[k, t.controls.index(n)] = 0.6 * t.upper[t.controls.index(n)]
    d = np.tensordot(truth, t.control, axes=1)
    d += np.tensordot(rng.normal(0, 0.01, (5, len(t.nuisance))), t.nuisance, axes=1)
    d += rng.normal(0, 2e-4, d.shape)
    d[:, ~t.mask] = 0.0
    est = estimate_contractions(d, t, regularization=1e-4)
    assert np.all(est >= 0) and np.all(est <= t.upper + 1e-12)
    assert np.abs(est - truth).max() < 0.1, np.abs(est - truth).max()
    # lost frames stay lost; a prepared design gives the same answer
    d[2, t.mask] = np.nan
    est2 = estimate_contractions(d, t, design=FlowDesign(t, regularization=1e-4))
    assert np.isnan(est2[2]).all() and np.allclose(est2[[0, 1, 3, 4]], est[[0, 1, 3, 4]])
    with pytest.raises(ValueError, match="shape"):
        estimate_contractions(d[:, :10], t)


def test_flow_estimator_leaves_out_near_twin_templates(templates):
    # buccinator's template is a near twin of risorius's: fitted together, noise shares
    # risorius's motion out between them; the default controls leave the twins out
    t = templates
    rng = np.random.default_rng(3)
    truth = {"zygomaticus_major_l": 0.8, "risorius_r": 0.6}
    d = sum(v * t.control[t.controls.index(n)] for n, v in truth.items())
    amp = np.abs(t.control[t.controls.index("zygomaticus_major_l")][t.mask]).max()
    d = d + rng.normal(0, 0.05 * amp, (8, *d.shape))
    d[:, ~t.mask] = 0.0
    controls = tuple(c for c in FLOW_CONTROLS if c in t.controls)
    assert "buccinator_r" not in controls and "zygomaticus_minor_l" not in controls
    every = estimate_contractions(d, t)
    chosen = estimate_contractions(d, t, controls=controls)
    assert chosen.shape == (8, len(controls))
    err_every = np.abs(every[:, t.controls.index("risorius_r")] - 0.6)
    err_chosen = np.abs(chosen[:, controls.index("risorius_r")] - 0.6)
    assert err_chosen.max() < 0.06, err_chosen
    assert err_every.mean() > 2 * err_chosen.mean(), (err_every, err_chosen)
    assert every[:, t.controls.index("buccinator_r")].mean() > 0.04
    for n, v in truth.items():
        assert np.abs(chosen[:, controls.index(n)] - v).max() < 0.06, n
    with pytest.raises(ValueError, match="controls must be distinct names"):
        estimate_contractions(d, t, controls=("risorius_r", "platysma"))
    with pytest.raises(ValueError, match="differ from the design"):
        estimate_contractions(d, t, controls=controls[:3], design=FlowDesign(t))


def _episode(t, name, rng, *, scale=0.9, T=24, rigid=0.01, noise=5e-4):
    """Neutral -> onset -> apex -> offset built from the expression template, plus head-frame
    jitter and noise."""
    e = t.expressions.index(name)
    steps = t.expression[e]
    env = np.concatenate([np.zeros(3), np.linspace(0, 1, 8)[1:], np.ones(8),
                          np.linspace(1, 0, 7)[1:]])[:T]
    idx = np.clip(env * (len(steps)) - 1, 0, len(steps) - 1)
    lo = np.floor(idx).astype(int)
    hi = np.minimum(lo + 1, len(steps) - 1)
    w = (idx - lo)[:, None, None, None]
    d = ((1 - w) * steps[lo] + w * steps[hi]) * (env > 0)[:, None, None, None] * scale
    d += np.tensordot(rng.normal(0, rigid, (T, 4)), rigid_basis(t.grid), axes=1)
    return d + rng.normal(0, noise, d.shape)


def test_recognition_names_each_expression_and_neutral(templates, rng):
    t = templates
    for name in EXPRESSION_NAMES:
        rec = classify_flow(_episode(t, name, rng), t)
        assert rec.label == name, (name, rec.scores)
        assert rec.segments and rec.segments[0].start >= 2
        assert set(rec.scores) == set(CLASSES)
    still = np.tensordot(rng.normal(0, 0.01, (20, 4)), rigid_basis(t.grid), axes=1)
    still += rng.normal(0, 3e-4, still.shape)
    rec = classify_flow(still, t)
    assert rec.label == "neutral" and rec.scores["neutral"] > 0.5
    # two episodes in one sequence give two segments
    pause = rng.normal(0, 3e-4, (6, *t.grid.shape, 2))       # neutral frames between
    two = np.concatenate([_episode(t, "happiness", rng), pause, _episode(t, "surprise", rng)])
    rec = classify_flow(two, t)
    assert [s.label for s in rec.segments] == ["happiness", "surprise"]
    assert rec.table().shape[0] == 2
    with pytest.raises(ValueError, match="shape"):
        classify_flow(two[:, :5], t)


def test_motion_matching_no_expression_and_lost_frames_are_reported(templates, rng):
    """An active stretch whose motion is none of the expressions (here a smooth random field,
    as a hand or talking gives) is reported apart, not hidden; lost frames are named."""
    t = templates
    happy = _episode(t, "happiness", rng)
    field = rng.normal(0, 1, (*t.grid.shape, 2))
    field = field / np.sqrt(np.mean(np.sum(field[t.mask] ** 2, axis=-1))) * 0.03
    other = np.concatenate([np.zeros((8, *field.shape)),
                            np.repeat(field[None], 12, axis=0) * np.linspace(0.2, 1, 12)[
                                :, None, None, None],
                            np.zeros((3, *field.shape))])
    gone = np.full((4, *field.shape), np.nan)
    rec = classify_flow(np.concatenate([happy, other, gone]), t,
                        frames=np.arange(100, 100 + len(happy) + len(other) + 4))
    assert rec.label == "happiness"
    assert [s.label for s in rec.segments] == ["happiness"]
    assert [s.label for s in rec.unmatched] == [UNMATCHED]
    seg = rec.unmatched[0]
    assert 100 + len(happy) + 8 <= seg.start and seg.end <= 100 + len(happy) + 20
    assert set(seg.scores) == set(CLASSES)
    assert list(rec.table()["label"]) == ["happiness", UNMATCHED]
    end = 100 + len(happy) + len(other)
    assert rec.lost_ranges() == [(end, end + 3)]
    d = rec.as_dict()
    assert d["lost_ranges"] == [[end, end + 3]] and d["unmatched"][0]["label"] == UNMATCHED
    assert repr(rec) == (f"<Recognition: happiness ({rec.scores['happiness']:.3f}); 1 segment, "
                         "1 unmatched, 4 frames not classified>")
    # alone, the same motion leaves the sequence neutral, with its score from that segment
    alone = classify_flow(other, t)
    assert alone.label == "neutral" and not alone.segments and len(alone.unmatched) == 1
    best = max(alone.unmatched[0].scores[n] for n in EXPRESSION_NAMES)
    assert alone.scores["neutral"] == pytest.approx(1 - best)


def test_motion_energy_segments_and_threshold(templates, rng):
    t = templates
    clean = nuisance_free(_episode(t, "happiness", rng), t)
    e = motion_energy(clean, t.mask)
    assert e[0] < 1e-3 < e[12]
    assert find_segments(np.array([0, 1, 1, 0, 0, 1, 1, 1, 0]), 0.5, min_length=2,
                         min_gap=1) == [(1, 2), (5, 7)]
    assert find_segments(np.array([np.nan, 1, 1, 1]), 0.5) == [(1, 3)]
    assert calibrate_threshold([0.001, 0.002], [0.008]) == pytest.approx(0.004)
    assert calibrate_threshold([0.001, 0.01], [0.008]) == pytest.approx(
        2 * np.percentile([0.001, 0.01], 95))
    with pytest.raises(ValueError):
        find_segments(e, 0.1, min_length=0)


@pytest.mark.parametrize("content", [b"my notes\n", b"not a zip"])
def test_a_file_that_is_not_templates_is_named_as_such(tmp_path, content):
    (tmp_path / "notes.txt").write_bytes(content)
    with pytest.raises(ValueError) as info:
        FlowTemplates.load(tmp_path / "notes.txt")
    message = str(info.value)
    assert "notes.txt: not a flow-templates file" in message and ".npz" in message
    assert "pickle" not in message and "\n" not in message


def test_an_npz_without_the_templates_arrays_is_named_as_such(tmp_path):
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match=r"other.npz: not a flow-templates file.*has no grid"):
        FlowTemplates.load(tmp_path / "other.npz")


def test_templates_print_their_size_not_their_fields(templates):
    assert repr(templates) == (
        f"<FlowTemplates: {len(templates.controls)} controls, 6 expressions (happiness, "
        "sadness, surprise, fear, anger, disgust), on a 48x36 face grid>")

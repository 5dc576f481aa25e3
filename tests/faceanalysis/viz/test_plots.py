"""contractions.png: what is drawn, and that it is written atomically."""

from __future__ import annotations

import matplotlib.image as mpimg
import numpy as np
import pytest

from faceanalysis.io.table import JAW, MUSCLES, empty_table
from faceanalysis.viz import plots as plotting
from faceanalysis.viz.plots import plot_contractions


@pytest.fixture
def table():
    n = 90
    t = empty_table(n, timestamps=np.arange(n) / 30)
    t["success"] = 1
    t[list(MUSCLES)] = 0.0
    s = np.arange(n)
    t["zygomaticus_major_l"] = 0.8 * np.exp(-0.5 * ((s - 40) / 10) ** 2)
    t["zygomaticus_major_r"] = 0.7 * np.exp(-0.5 * ((s - 40) / 10) ** 2)
    t["orbicularis_oris"] = 0.3
    t[JAW] = np.radians(10) * np.exp(-0.5 * ((s - 70) / 8) ** 2)
    t.loc[20:24, "success"] = 0
    t.loc[20:24, list(MUSCLES) + [JAW]] = np.nan
    return t


def test_default_plot_draws_active_muscles_pairs_and_jaw(table):
    original = table.copy()
    fig = plot_contractions(table)
    ax = fig.axes[0]
    labels = [line.get_label() for line in ax.lines]
    assert labels == ["zygomaticus_major_l", "zygomaticus_major_r", "orbicularis_oris"]
    styles = {line.get_label(): (line.get_color(), line.get_linestyle()) for line in ax.lines}
    assert styles["zygomaticus_major_l"][0] == styles["zygomaticus_major_r"][0]
    assert styles["zygomaticus_major_l"][1] == "-" and styles["zygomaticus_major_r"][1] == "--"
    assert ax.get_xlabel() == "time (s)"
    jaw_ax = fig.axes[1]
    assert "degrees" in jaw_ax.get_ylabel()
    np.testing.assert_allclose(np.nanmax(jaw_ax.lines[0].get_ydata()), 10, rtol=1e-3)
    assert len(ax.collections) == 1  # the lost-frame shading
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "lost frames (5)" in legend
    assert table.equals(original)


def test_selected_muscles_and_frame_axis(table):
    fig = plot_contractions(table.drop(columns="timestamp"), muscles=["orbicularis_oris"],
                            title="one")
    ax = fig.axes[0]
    assert [line.get_label() for line in ax.lines] == ["orbicularis_oris"]
    assert ax.get_xlabel() == "frame" and ax.get_title() == "one"


def test_bad_muscle_names(table):
    with pytest.raises(ValueError, match="unknown muscles: smile"):
        plot_contractions(table, muscles=["smile"])
    with pytest.raises(ValueError, match="not in the table: risorius_l"):
        plot_contractions(table.drop(columns="risorius_l"), muscles=["risorius_l"])


def test_no_activity_still_plots(table):
    table[list(MUSCLES)] = 0.0
    fig = plot_contractions(table)
    assert len(fig.axes[0].lines) == 0
    assert "no muscle" in fig.axes[0].texts[0].get_text()


def test_png_written_at_publication_resolution(table, tmp_path):
    path = tmp_path / "contractions.png"
    plot_contractions(table, path)
    assert [p.name for p in tmp_path.iterdir()] == ["contractions.png"]
    image = mpimg.imread(path)
    assert image.shape[1] >= 1400 and image.shape[0] >= 650  # 10 x 4.8 in at 150 dpi
    assert image[..., :3].std() > 0.05  # not blank


def test_interrupted_save_leaves_previous_png(table, tmp_path, monkeypatch):
    path = tmp_path / "contractions.png"
    path.write_bytes(b"old plot")

    def broken_savefig(self, fname, **kwargs):
        with open(fname, "wb") as fh:
            fh.write(b"\x89PNG half")
        raise KeyboardInterrupt

    monkeypatch.setattr(plotting.Figure, "savefig", broken_savefig)
    with pytest.raises(KeyboardInterrupt):
        plot_contractions(table, path)
    assert path.read_bytes() == b"old plot"
    assert list(tmp_path.iterdir()) == [path]


def test_many_muscles_are_stacked_one_panel_per_pair(table):
    for m in ("corrugator_l", "corrugator_r", "risorius_l", "mentalis_r",
              "frontalis_inner_l", "levator_labii_l"):
        table[m] = np.linspace(0, 0.5, len(table))
    fig = plot_contractions(table)
    labels = [ax.get_ylabel() for ax in fig.axes]
    # zygomaticus major, orbicularis oris + 5 more pairs, then the jaw panel
    assert len(fig.axes) == 8 and labels[-1] == "jaw (deg)"
    zyg = fig.axes[labels.index("zygomaticus major")]
    assert [line.get_label() for line in zyg.lines] == ["zygomaticus_major_l",
                                                         "zygomaticus_major_r"]
    assert all(len(ax.collections) == 1 for ax in fig.axes)  # lost frames on every panel
    single = plot_contractions(table, layout="single")
    assert len(single.axes) == 2  # one axis + the jaw's secondary axis
    with pytest.raises(ValueError, match="layout"):
        plot_contractions(table, layout="grid")


def test_isolated_lost_frames_are_visible(table):
    table["success"] = 1
    table.loc[[10, 50], "success"] = 0
    fig = plot_contractions(table)
    (bars,) = fig.axes[0].collections
    assert len(bars.get_paths()) == 2
    widths = [np.ptp(p.vertices[:, 0]) for p in bars.get_paths()]
    np.testing.assert_allclose(widths, 1 / 30, rtol=1e-6)  # one frame wide


def test_controls_the_points_cannot_tell_apart_are_drawn_faded(table):
    fig = plot_contractions(table, not_identifiable=["zygomaticus_major_l"])
    alpha = {line.get_label(): line.get_alpha() for line in fig.axes[0].lines}
    assert alpha["zygomaticus_major_l"] < 0.5
    assert alpha["zygomaticus_major_r"] in (None, 1.0)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "faded: not identifiable" in labels
    plain = plot_contractions(table)
    assert "faded: not identifiable" not in [t.get_text() for t in plain.legends[0].get_texts()]


def test_frames_with_the_head_turned_are_hatched(table):
    turned = np.zeros(len(table), bool)
    turned[50:60] = True
    turned[22] = True                       # a lost frame: shaded as lost, not hatched
    fig = plot_contractions(table, turned=turned)
    ax = fig.axes[0]
    assert len(ax.collections) == 2         # lost frames, then the turned ones
    hatched = ax.collections[1]
    assert hatched.get_hatch() == "///"
    (path,) = hatched.get_paths()            # one run: frames 50-59, half a frame each side
    x = path.vertices[:, 0]
    np.testing.assert_allclose([x.min(), x.max()], [49.5 / 30, 59.5 / 30])
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "head turned (10)" in legend and "lost frames (5)" in legend
    assert "head turned" not in " ".join(
        t.get_text() for t in plot_contractions(table).legends[0].get_texts())
    with pytest.raises(ValueError, match="turned must have one value per row"):
        plot_contractions(table, turned=turned[:5])


def test_measured_eyes_get_a_panel_above_the_jaw(table):
    from faceanalysis.io.table import EYE_COLUMNS

    table[list(EYE_COLUMNS)] = 1.0
    table.loc[50:53, list(EYE_COLUMNS)] = 0.1          # a blink
    fig = plot_contractions(table)
    labels = [ax.get_ylabel() for ax in fig.axes]
    # two muscle panels, the eyes, the jaw: stacked though few muscles are active
    assert len(fig.axes) == 4 and labels[2].startswith("eyes open") and labels[3] == "jaw (deg)"
    assert [line.get_label() for line in fig.axes[2].lines] == list(EYE_COLUMNS)
    assert np.nanmin(fig.axes[2].lines[0].get_ydata()) == pytest.approx(0.1)
    # without them (empty columns, the snakes tracker) the plot is as before
    table[list(EYE_COLUMNS)] = np.nan
    assert len(plot_contractions(table).axes) == 2


def test_shot_cuts_are_drawn_where_they_are(table):
    for layout in ("single", "stacked"):
        fig = plot_contractions(table, cuts=[45, 500], layout=layout)   # 500: not in it
        panels = fig.axes if layout == "stacked" else fig.axes[:1]  # (single: jaw's twin)
        for ax in panels:
            lines = [ln for ln in ax.get_lines() if ln.get_color() == "#7a3ec0"]
            assert [ln.get_xdata()[0] for ln in lines] == [pytest.approx(45 / 30)]
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "shot cut (1)" in legend
    assert not any("shot cut" in t.get_text()
                   for t in plot_contractions(table).legends[0].get_texts())


def test_photographs_are_marks_not_a_time_series():
    t = empty_table(4, timestamps=np.arange(4) / 30)
    t["success"] = [1, 1, 0, 1]
    t[list(MUSCLES)] = 0.0
    t["zygomaticus_major_l"] = [0.0, 0.5, np.nan, 0.1]
    t["zygomaticus_major_r"] = [0.0, 0.4, np.nan, 0.2]
    fig = plot_contractions(t, photographs=True, layout="single")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "photograph (frame)"
    assert list(ax.get_xticks()) == [0, 1, 2, 3] and ax.get_xlim() == (-0.5, 3.5)
    left, right = ax.lines[:2]
    # no line joins two photographs; left filled, right hollow
    assert left.get_linestyle() == right.get_linestyle() == "None"
    assert left.get_marker() == right.get_marker() == "o"
    assert right.get_markerfacecolor() == "white" != left.get_markerfacecolor()
    # the lost photograph is shaded over its own place
    (bar,) = [c for c in ax.collections if len(c.get_paths())]
    x0, x1 = bar.get_paths()[0].get_extents().intervalx
    assert (x0, x1) == pytest.approx((1.5, 2.5))
    # as a video, the same table is a time series
    video = plot_contractions(t, layout="single").axes[0]
    assert video.get_xlabel() == "time (s)" and video.lines[0].get_linestyle() == "-"

"""zentrack.common.plots: the PNG and the SVG written side by side (atomically), point labels that do not
overprint, a stable colour per name."""
from __future__ import annotations

import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.text import Text

from zentrack.common.plots import (
    color_of,
    figure_paths,
    label_points,
    new_figure,
    save_png_svg,
    style_axes,
)


def test_save_png_svg_writes_both_files_and_nothing_else(tmp_path):
    fig, (ax,) = new_figure()
    ax.plot([0, 1, 2], [1, 3, 2], label="a series")
    style_axes(ax, "a title", "time (s)", "error (m)")
    written = save_png_svg(fig, tmp_path / "sub" / "figure.png")
    assert written == [tmp_path / "sub" / "figure.png", tmp_path / "sub" / "figure.svg"]
    assert written[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = written[1].read_text()
    assert svg.lstrip().startswith("<?xml") and "<svg" in svg
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["figure.png", "figure.svg"]
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_title(loc="left")) == ("time (s)", "error (m)", "a title")


def test_a_failed_save_leaves_no_file(tmp_path, monkeypatch):
    fig, _ = new_figure()

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(fig, "savefig", broken)
    with pytest.raises(OSError):
        save_png_svg(fig, tmp_path / "figure")
    assert list(tmp_path.iterdir()) == []


def test_figure_paths_replace_only_an_image_suffix():
    assert [p.name for p in figure_paths("out/a.png")] == ["a.png", "a.svg"]
    assert [p.name for p in figure_paths("out/p3.json.png")] == ["p3.json.png", "p3.json.svg"]
    assert [p.name for p in figure_paths("out/soak.v2")] == ["soak.v2.png", "soak.v2.svg"]


def test_labels_of_points_close_together_do_not_overlap():
    fig, (ax,) = new_figure(width=6, height=4)
    xs, ys = [1.0, 1.0, 1.0, 1.02, 5.0], [2.0, 2.001, 2.002, 2.0, 2.0]
    ax.plot(xs, ys, "o")
    ax.set_xlim(0, 6)
    ax.set_ylim(1, 3)
    label_points(ax, xs, ys, ["ci", "ci-fast", "hcmci", "diff-ici", "far away"])
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    boxes = [Text.get_window_extent(t, renderer) for t in ax.texts]  # the text, without its leader line
    assert len(boxes) == 5
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert not a.overlaps(b), (a, b)


def test_a_name_has_one_colour_everywhere():
    assert color_of("cteskf") == color_of("dteskf") == color_of("TESKF")
    assert color_of("ukf") != color_of("ekf")
    assert color_of("some rule") == color_of("some rule")

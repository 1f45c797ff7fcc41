"""Every series a plot draws has a style of its own: each command's plot is drawn, and the lines
and markers of its top view are read back from the figure."""

from __future__ import annotations

from pathlib import Path

import matplotlib.colors as mcolors
import numpy as np
import pytest

from lie_factors.app import cli, plotting

DATA = Path(__file__).resolve().parents[2] / "data"


def _drawn(monkeypatch) -> list:
    """The figures the commands draw (plot_trajectories' arguments, drawn by trajectory_figure)."""
    figures = []
    save = plotting.plot_trajectories

    def capture(path, trajectories, *args, **kwargs):
        figures.append(plotting.trajectory_figure(trajectories, *args, **kwargs))
        save(path, trajectories, *args, **kwargs)

    monkeypatch.setattr(plotting, "plot_trajectories", capture)
    return figures


def _colours(fig) -> dict[str, tuple]:
    """Label → RGBA colour of every line and marker set of the figure's top view."""
    top = fig.axes[0]
    out = {}
    for line in top.get_lines():
        out[line.get_label()] = mcolors.to_rgba(line.get_color())
    for coll in top.collections:
        colour = coll.get_facecolor() if len(coll.get_facecolor()) else coll.get_edgecolor()
        out[coll.get_label()] = tuple(np.round(np.asarray(colour)[0], 6))
    return out


def _assert_distinct(fig):
    colours = _colours(fig)
    assert len(colours) >= 2
    assert len(set(colours.values())) == len(colours), colours


@pytest.mark.parametrize("extra", [["--init", "odometry"], ["--incremental"], []],
                         ids=["odometry-start", "incremental", "default"])
def test_posegraph_plot_draws_the_start_and_the_estimate_in_different_colours(tmp_path, monkeypatch, extra):
    figures = _drawn(monkeypatch)
    png = tmp_path / "intel.png"
    assert cli.main(["posegraph", f"{DATA}/intel.g2o", "--quiet", "--plot", str(png), *extra]) == 0
    (fig,) = figures
    _assert_distinct(fig)


def test_posegraph_plot_with_landmarks(tmp_path, monkeypatch):
    figures = _drawn(monkeypatch)
    png = tmp_path / "lm.png"
    assert cli.main(["posegraph", "known_landmark_localization_20.g2o", "--backend", "native", "--quiet",
                     "--plot", str(png)]) == 0
    colours = _colours(figures[0])
    assert any("landmarks" in label for label in colours)
    _assert_distinct(figures[0])


def test_posegraph_plot_with_ellipses(tmp_path, monkeypatch):
    figures = _drawn(monkeypatch)
    png = tmp_path / "e.png"
    assert cli.main(["posegraph", f"{DATA}/intel.g2o", "--quiet", "--plot", str(png),
                     "--covariances", str(tmp_path / "c.npz")]) == 0
    assert "95% position ellipses" in _colours(figures[0])
    _assert_distinct(figures[0])


@pytest.mark.parametrize("scenario", ["se3", "sim3"])
def test_demo_plots_draw_every_trajectory_in_its_own_colour(tmp_path, monkeypatch, scenario):
    figures = _drawn(monkeypatch)
    assert cli.main(["demo", "--scenario", scenario, "--poses", "40", "--quiet", "--output", str(tmp_path)]) == 0
    _assert_distinct(figures[0])


def test_a_series_without_a_style_is_refused():
    with pytest.raises(ValueError, match="no plot style for the series 'mystery'"):
        plotting.trajectory_figure({"optimized": np.zeros((2, 3)), "mystery": np.ones((2, 3))})
    fig = plotting.trajectory_figure({"initial (odometry)": np.zeros((2, 3)), "optimized": np.ones((2, 3))},
                                     roles={"initial (odometry)": "initial"})
    assert _colours(fig)["initial (odometry)"] == mcolors.to_rgba(plotting.STYLES["initial"]["color"])

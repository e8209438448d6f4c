"""Tests of gaussfuse.plotting (matplotlib, Agg canvas, no pyplot)."""

import os

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

import gaussfuse as gf
from gaussfuse.plotting import plot_demo, plot_measurements, save_figure

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def filtered():
    rng = np.random.default_rng(3)
    model = gf.constant_velocity(1.0, 0.5, 0.3, dim=2)
    zs = np.cumsum(rng.normal(size=(12, 2)), axis=0)
    zs[4, 1] = np.nan
    res = gf.filter(model, gf.Gaussian(np.zeros(4), 10 * np.eye(4)), zs)
    return np.arange(12.0), zs, res, model


def band_limits(ax):
    """(lower, upper) envelope of the one ±2σ band in `ax`, as drawn."""
    (band,) = [c for c in ax.collections if isinstance(c, PolyCollection)]
    verts = band.get_paths()[0].vertices
    return verts[:, 1].min(), verts[:, 1].max()


def test_plot_measurements_draws_one_panel_per_component(filtered):
    times, zs, res, model = filtered
    fig = plot_measurements(times, zs, res.means, res.covs, model.H, names=["east", "north"])
    assert isinstance(fig, Figure)
    axes = fig.get_axes()
    assert len(axes) == 2
    est = res.means @ model.H.T
    std = np.sqrt(np.diagonal(model.H @ res.covs @ model.H.T, axis1=1, axis2=2))
    for j, ax in enumerate(axes):
        assert ax.get_ylabel() == ["east", "north"][j]
        dots, line = ax.get_lines()
        np.testing.assert_array_equal(dots.get_ydata(), zs[:, j])
        np.testing.assert_array_equal(line.get_xdata(), times)
        np.testing.assert_allclose(line.get_ydata(), est[:, j], rtol=1e-12)
        low, high = band_limits(ax)
        assert low == pytest.approx(np.min(est[:, j] - 2 * std[:, j]))
        assert high == pytest.approx(np.max(est[:, j] + 2 * std[:, j]))
    assert axes[-1].get_xlabel() == "time"
    assert [t.get_text() for t in axes[0].get_legend().get_texts()] == ["measurement", "estimate",
                                                                          "estimate ±2σ"]


def test_plot_measurements_into_a_given_figure_with_time_varying_h(filtered):
    times, zs, res, model = filtered
    H = np.broadcast_to(model.H, (12, 2, 4))
    fig = Figure()
    assert plot_measurements(times, zs, res.means, res.covs, H, fig=fig) is fig
    assert [ax.get_ylabel() for ax in fig.get_axes()] == ["z0", "z1"]
    np.testing.assert_allclose(fig.get_axes()[1].get_lines()[1].get_ydata(), res.means[:, 1], rtol=1e-12)


def test_plot_measurements_one_component_as_a_vector():
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([1.0, 3.0]), R=10)
    zs = np.array([1.0, 2.0, 3.0, 2.0, 1.0])
    res = gf.filter(model, gf.Gaussian([0, 1], 500 * np.eye(2)), zs)
    fig = plot_measurements(np.arange(5), zs, res.means, res.covs, model.H)
    (ax,) = fig.get_axes()
    np.testing.assert_allclose(ax.get_lines()[1].get_ydata(), res.means[:, 0], rtol=1e-12)


def test_plot_demo(filtered):
    times, zs, res, model = filtered
    sm = gf.smooth(model, gf.Gaussian(np.zeros(4), 10 * np.eye(4)), zs)
    truth = np.column_stack([zs, np.zeros_like(zs)])
    fig = plot_demo(times, zs, truth, {"filter": (res.means, res.covs), "smoother": (sm.means, sm.covs)})
    track, xt = fig.get_axes()
    assert [l.get_label() for l in track.get_lines()] == ["measurement", "truth", "filter", "smoother"]
    np.testing.assert_array_equal(track.get_lines()[3].get_ydata(), sm.means[:, 1])
    assert sum(isinstance(c, PolyCollection) for c in xt.collections) == 2  # one band per estimate
    labels = [t.get_text() for t in xt.get_legend().get_texts()]
    assert labels == ["measurement", "truth", "filter", "filter ±2σ", "smoother", "smoother ±2σ"]


@pytest.mark.parametrize("name, signature", [("fig.png", PNG_SIGNATURE), ("fig.svg", b"<?xml"),
                                             ("fig", PNG_SIGNATURE)])
def test_save_figure_format_from_extension(tmp_path, filtered, name, signature):
    times, zs, res, model = filtered
    path = tmp_path / name
    save_figure(plot_measurements(times, zs, res.means, res.covs, model.H), path)
    assert path.read_bytes().startswith(signature)
    assert os.listdir(tmp_path) == [name]


def test_save_figure_unknown_format_writes_nothing(tmp_path, filtered):
    times, zs, res, model = filtered
    path = tmp_path / "fig.nope"
    with pytest.raises(ValueError, match=r"fig\.nope: unknown image format 'nope'; use one of .*png"):
        save_figure(plot_measurements(times, zs, res.means, res.covs, model.H), path)
    assert os.listdir(tmp_path) == []


def test_save_figure_failure_keeps_the_old_file(tmp_path, filtered, monkeypatch):
    times, zs, res, model = filtered
    fig = plot_measurements(times, zs, res.means, res.covs, model.H)
    path = tmp_path / "fig.png"
    path.write_bytes(b"old")

    def fail(*args, **kwargs):
        raise RuntimeError("renderer failed")

    monkeypatch.setattr(fig, "savefig", fail)
    with pytest.raises(RuntimeError, match="renderer failed"):
        save_figure(fig, path)
    assert path.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["fig.png"]

"""Tests of gaussfuse.plotting (matplotlib, Agg canvas, no pyplot)."""

import os
import subprocess
import sys

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

import gaussfuse as gf
from gaussfuse.diagnostics import chi2_interval, consistency, nees, nis
from gaussfuse.plotting import (plot_consistency, plot_demo, plot_measurements, plot_mode_probabilities,
                                plot_series, plot_trajectory, save_figure)

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


def test_plot_measurements_labels_units_title_and_track(filtered):
    """A "smoothed" legend, units on the axes, a title, and the x–y panel of the two components."""
    times, zs, res, model = filtered
    fig = plot_measurements(times, zs, res.means, res.covs, model.H, names=["east", "north"], label="smoothed",
                            units="m", xlabel="t", time_unit="s", title="track.csv: smoothed", track=True)
    east, north, track = fig.get_axes()
    assert [east.get_ylabel(), north.get_ylabel(), north.get_xlabel()] == ["east (m)", "north (m)", "t (s)"]
    assert [t.get_text() for t in east.get_legend().get_texts()] == ["measurement", "smoothed", "smoothed ±2σ"]
    assert fig.get_suptitle() == "track.csv: smoothed"
    assert [track.get_xlabel(), track.get_ylabel()] == ["east (m)", "north (m)"]
    dots, path = track.get_lines()
    np.testing.assert_array_equal(dots.get_xdata(), zs[:, 0])
    np.testing.assert_allclose(path.get_ydata(), (res.means @ model.H.T)[:, 1], rtol=1e-12)
    assert [t.get_text() for t in track.get_legend().get_texts()] == ["measurement", "smoothed", "smoothed 2σ"]
    fig = plot_measurements(times, zs, res.means, res.covs, model.H, units=["m", "km"], track=True)
    assert [ax.get_ylabel() for ax in fig.get_axes()] == ["z0 (m)", "z1 (km)", "z1"]  # mixed units: none on x–y
    assert fig.get_axes()[2].get_xlabel() == "z0"


@pytest.mark.parametrize("kwargs, match", [
    ({"units": ["m"]}, r"`units` must be one unit, or one per measurement component \(2\); got 1"),
    ({"track": True, "H": "one row"}, r"`track` draws two measurement components .* m = 1"),
])
def test_plot_measurements_bad_units_and_track(filtered, kwargs, match):
    times, zs, res, model = filtered
    H = model.H
    if kwargs.pop("H", None):
        H, zs = model.H[:1], zs[:, :1]
    with pytest.raises(ValueError, match=match):
        plot_measurements(times, zs, res.means, res.covs, H, **kwargs)


def test_series_and_trajectory_take_labels_and_units(filtered):
    times, zs, res, _ = filtered
    fig = plot_series(times, res.means, res.covs, component=2, xlabel="t", ylabel="vx", unit="m/s", time_unit="s")
    assert [fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()] == ["t (s)", "vx (m/s)"]
    fig = plot_trajectory(res.means, res.covs, xlabel="east", ylabel="north", unit="km")
    assert [fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()] == ["east (km)", "north (km)"]


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


# ---------------------------------------------------------------------------
# The single-panel functions
# ---------------------------------------------------------------------------


def assert_png(fig, path):
    """Save `fig` to `path` and check it is a real PNG image of some substance."""
    save_figure(fig, path)
    data = path.read_bytes()
    assert data.startswith(PNG_SIGNATURE)
    assert len(data) > 5_000


@pytest.fixture
def track():
    """A 2-D constant-velocity track, filtered, with its truth."""
    rng = np.random.default_rng(5)
    model = gf.constant_velocity(0.5, 0.2, 0.5, dim=2)
    truth = np.cumsum(np.column_stack([np.full((40, 2), 0.5), rng.normal(0, 0.05, (40, 2))]), axis=0)
    truth[:, 2:] = 1.0
    zs = truth[:, :2] + rng.normal(0, 0.7, (40, 2))
    zs[7] = np.nan
    res = gf.filter(model, gf.Gaussian(np.zeros(4), 4 * np.eye(4)), zs)
    return 0.5 * np.arange(1, 41), zs, truth, res


def test_plot_series_new_figure(tmp_path, track):
    times, zs, truth, res = track
    fig = plot_series(times, res.means, res.covs, component=1, k=3.0, zs=zs, truth=truth)
    assert isinstance(fig, Figure)
    (ax,) = fig.get_axes()
    dots, true, line = ax.get_lines()
    np.testing.assert_array_equal(dots.get_ydata(), zs[:, 1])
    np.testing.assert_array_equal(true.get_ydata(), truth[:, 1])
    np.testing.assert_array_equal(line.get_xdata(), times)
    np.testing.assert_array_equal(line.get_ydata(), res.means[:, 1])
    std = np.sqrt(res.covs[:, 1, 1])
    low, high = band_limits(ax)
    assert low == pytest.approx(np.min(res.means[:, 1] - 3 * std))
    assert high == pytest.approx(np.max(res.means[:, 1] + 3 * std))
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["measurement", "truth", "estimate",
                                                                   "estimate ±3σ"]
    assert ax.get_xlabel() == "time"
    assert_png(fig, tmp_path / "series.png")


def test_plot_series_into_given_axes(tmp_path, track):
    times, zs, truth, res = track
    fig = Figure()
    left, right = fig.subplots(1, 2)
    assert plot_series(times, res.means, res.covs, zs=zs, ax=right, label="filter") is fig
    assert fig.get_axes() == [left, right]
    assert not left.get_lines() and len(right.get_lines()) == 2
    assert [t.get_text() for t in right.get_legend().get_texts()] == ["measurement", "filter", "filter ±2σ"]
    assert_png(fig, tmp_path / "series.png")


def test_plot_series_in_a_subfigure_returns_the_root_figure(track):
    times, zs, truth, res = track
    fig = Figure()
    ax = fig.subfigures(1, 2)[1].add_subplot()
    assert plot_series(times, res.means, res.covs, ax=ax) is fig


def test_plot_series_one_dimensional_and_without_band():
    times = np.arange(5.0)
    means, variances = np.array([1.0, 2.0, 3.0, 2.0, 1.0]), np.array([4.0, 1.0, 1.0, 1.0, 0.25])
    ax = plot_series(times, means, variances).get_axes()[0]
    low, high = band_limits(ax)
    assert (low, high) == pytest.approx((np.min(means - 2 * np.sqrt(variances)),
                                         np.max(means + 2 * np.sqrt(variances))))
    ax = plot_series(times, means, None).get_axes()[0]
    assert not [c for c in ax.collections if isinstance(c, PolyCollection)]
    np.testing.assert_array_equal(ax.get_lines()[0].get_ydata(), means)


def ellipse_points(patch, count=16):
    """Points on a drawn Ellipse patch, from its centre, axes and angle."""
    t = np.linspace(0, 2 * np.pi, count, endpoint=False)
    a = np.radians(patch.angle)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    local = np.column_stack([patch.width / 2 * np.cos(t), patch.height / 2 * np.sin(t)])
    return np.asarray(patch.center) + local @ rot.T


def test_plot_trajectory_ellipses_are_k_sigma_contours(tmp_path, track):
    from matplotlib.patches import Ellipse

    times, zs, truth, res = track
    # a strongly correlated, rotated covariance as well as the filter's own
    covs = res.covs.copy()
    covs[10, :2, :2] = [[2.0, 1.2], [1.2, 1.0]]
    fig = plot_trajectory(res.means, covs, truth=truth, zs=zs, every=5, k=3.0)
    (ax,) = fig.get_axes()
    assert [line.get_label() for line in ax.get_lines()] == ["measurement", "truth", "estimate"]
    np.testing.assert_array_equal(ax.get_lines()[2].get_xydata(), res.means[:, :2])
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == 8  # steps 0, 5, ..., 35
    for patch, step in zip(ellipses, range(0, 40, 5)):
        np.testing.assert_allclose(patch.center, res.means[step, :2])
        d = ellipse_points(patch) - res.means[step, :2]
        quad = np.einsum("ki,ij,kj->k", d, np.linalg.inv(covs[step, :2, :2]), d)
        np.testing.assert_allclose(quad, 9.0, rtol=1e-9)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["measurement", "truth", "estimate",
                                                                   "estimate 3σ"]
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_aspect()) == ("x", "y", 1.0)
    assert_png(fig, tmp_path / "track.png")


def test_plot_trajectory_into_given_axes_skips_undefined_ellipses(tmp_path, track):
    times, zs, truth, res = track
    fig = Figure()
    ax = fig.add_subplot()
    covs = res.covs.copy()
    covs[:3] = np.nan  # e.g. a diffuse start
    assert plot_trajectory(res.means, covs, every=1, ax=ax, label="filter") is fig
    assert len(ax.patches) == 37
    plot_trajectory(res.means[:, :2], ax=ax, label="positions only")  # no covariances: no ellipses
    assert len(ax.patches) == 37 and len(ax.get_lines()) == 2
    assert_png(fig, tmp_path / "track.png")


def test_plot_consistency_of_diagnostics_output(tmp_path, track):
    times, zs, truth, res = track
    values = nees(truth - res.means, res.covs)
    interval = chi2_interval(4, count=values.size)
    fig = plot_consistency(values, interval)
    (ax,) = fig.get_axes()
    per_step, average, low, high = ax.get_lines()
    np.testing.assert_array_equal(per_step.get_xdata(), np.arange(1, 41))
    np.testing.assert_array_equal(per_step.get_ydata(), values)
    assert average.get_ydata()[0] == pytest.approx(values.mean())
    assert (low.get_ydata()[0], high.get_ydata()[0]) == pytest.approx(interval)
    mean = values.mean()
    verdict = ("consistent" if interval[0] <= mean <= interval[1]
               else "overconfident" if mean > interval[1] else "too cautious")
    assert ax.get_title().startswith(f"NEES: average {mean:.3f} ") and ax.get_title().endswith(verdict)
    assert ax.get_ylabel() == "NEES" and ax.get_xlabel() == "step"
    assert_png(fig, tmp_path / "nees.png")

    report = consistency(res)  # the one-call report's interval is accepted as it is
    fig = Figure()
    ax = fig.add_subplot()
    assert plot_consistency(nis(res.innovations, res.innovation_covs), report.nis_interval, kind="NIS",
                            ax=ax) is fig
    assert ax.get_title().startswith("NIS: average ")
    assert_png(fig, tmp_path / "nis.png")


@pytest.mark.parametrize("scale, words", [(1.0, "in [1.732, 2.287]: consistent"),
                                          (3.0, "above [1.732, 2.287]: overconfident"),
                                          (0.3, "below [1.732, 2.287]: too cautious")])
def test_plot_consistency_verdicts(scale, words):
    values = np.random.default_rng(2).chisquare(2, size=200)
    values *= 2.0 * scale / values.mean()  # average exactly 2·scale
    ax = plot_consistency(values, chi2_interval(2, count=200), kind="NIS").get_axes()[0]
    assert ax.get_title() == f"NIS: average {2.0 * scale:.3f} {words}"


def test_plot_consistency_monte_carlo_runs_with_missing_steps():
    values = np.array([[1.0, np.nan, 3.0], [3.0, np.nan, 5.0], [2.0, 4.0, np.nan]])
    ax = plot_consistency(values, (1.0, 6.0), kind="NIS").get_axes()[0]
    per_step = ax.get_lines()[0]
    np.testing.assert_array_equal(per_step.get_ydata(), [2.0, 4.0, 4.0])
    assert per_step.get_label() == "NIS, average of 3 runs"
    assert ax.get_lines()[1].get_ydata()[0] == pytest.approx(3.0)  # over all the finite values


@pytest.mark.parametrize("stacked", [False, True])
def test_plot_mode_probabilities(tmp_path, stacked):
    times = np.linspace(0, 10, 60)
    p = 0.5 + 0.45 * np.sin(times)
    probs = np.column_stack([0.8 * p, 0.2 * p, 1 - p])
    fig = plot_mode_probabilities(times, probs, ["CV", "CT", "CA"], stacked=stacked)
    (ax,) = fig.get_axes()
    if stacked:
        assert sum(isinstance(c, PolyCollection) for c in ax.collections) == 3
    else:
        lines = ax.get_lines()
        assert [line.get_label() for line in lines] == ["CV", "CT", "CA"]
        np.testing.assert_array_equal(lines[2].get_ydata(), 1 - p)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["CV", "CT", "CA"]
    assert ax.get_ylim() == pytest.approx((-0.02, 1.02))
    assert_png(fig, tmp_path / "modes.png")


def test_plot_mode_probabilities_into_given_axes_with_default_names(tmp_path):
    fig = Figure()
    ax = fig.add_subplot()
    times = np.arange(30.0)
    p = np.clip(np.linspace(0.05, 0.95, 30), 0, 1)
    assert plot_mode_probabilities(times, np.column_stack([p, 1 - p]), ax=ax) is fig
    assert [line.get_label() for line in ax.get_lines()] == ["mode 0", "mode 1"]
    assert_png(fig, tmp_path / "modes.png")


BAD = [
    (lambda: plot_series(np.arange(3.0), np.zeros((4, 2)), None),
     r"`means` must have shape .*got shape \(4, 2\)"),
    (lambda: plot_series(np.zeros((3, 1)), np.zeros((3, 2)), None), r"`times` must have shape \(T,\)"),
    (lambda: plot_series(np.arange(3.0), np.zeros((3, 2)), np.zeros((3, 3, 3))),
     r"`covs` must have shape \(3, 2, 2\) \(`means` has n = 2, `times` T = 3\); got shape \(3, 3, 3\)"),
    # two reasons ran together: "(4, 2, 2) to match `means` with T = 4 to match `times`" (audit X4)
    (lambda: plot_series(np.arange(4.0), np.zeros((4, 2)), np.zeros((4, 2))),
     r"^`covs` must have shape \(4, 2, 2\) \(`means` has n = 2, `times` T = 4\); got shape \(4, 2\)\.$"),
    (lambda: plot_series(np.arange(3.0), np.zeros((3, 2)), None, component=2), r"`component` must be"),
    (lambda: plot_series(np.arange(3.0), np.zeros((3, 2)), None, zs=np.zeros(4)), r"`zs` must have shape"),
    (lambda: plot_series(np.arange(3.0), np.zeros((3, 2)), None, component=1, truth=np.zeros((3, 1))),
     r"`truth` must have shape \(T,\) or \(T, d\) with d > 1"),
    (lambda: plot_series(np.arange(3.0), np.zeros(3), None, k=0), r"`k` must be a positive number"),
    (lambda: plot_trajectory(np.zeros((5, 1))), r"`means` must have shape \(T, n\) with n >= 2"),
    (lambda: plot_trajectory(np.zeros(5)), r"`means` must have shape \(T, n\) with n >= 2"),
    (lambda: plot_trajectory(np.zeros((5, 4)), np.zeros((5, 2, 2))),
     r"`covs` must have shape \(5, 4, 4\) to match `means`"),
    (lambda: plot_trajectory(np.zeros((5, 2)), truth=np.zeros(5)), r"`truth` must have shape \(K, d\)"),
    (lambda: plot_trajectory(np.zeros((5, 2)), zs=np.zeros((5, 1))), r"`zs` must have shape \(K, d\)"),
    (lambda: plot_trajectory(np.zeros((5, 2)), every=0), r"`every` must be a positive integer"),
    (lambda: plot_consistency(np.zeros((2, 3, 4)), (1, 2)), r"`values` must have shape \(T,\) or \(N, T\)"),
    (lambda: plot_consistency(np.full(3, np.nan), (1, 2)), r"`values` must have at least one finite value"),
    (lambda: plot_consistency(np.ones(3), 2.0), r"`interval` must be a pair"),
    (lambda: plot_consistency(np.ones(3), (3.0, 2.0)), r"`interval` must be finite with low <= high"),
    (lambda: plot_mode_probabilities(np.arange(4.0), np.ones((3, 2))),
     r"`probs` must have shape \(4, M\) to match `times`"),
    (lambda: plot_mode_probabilities(np.arange(3.0), np.ones((3, 2)), ["a"]), r"`names` must have one name"),
    (lambda: plot_measurements(np.arange(3.0), np.zeros((3, 2)), np.zeros((3, 4)), np.zeros((3, 4, 4)),
                               np.zeros((2, 3))), r"`H` must have shape \(2, 4\) or \(3, 2, 4\)"),
    (lambda: plot_measurements(np.arange(3.0), np.zeros((4, 2)), np.zeros((3, 4)), np.zeros((3, 4, 4)),
                               np.zeros((2, 4))), r"`zs` must have shape"),
]


@pytest.mark.parametrize("call, match", BAD, ids=range(len(BAD)))
def test_bad_input_names_the_argument(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_ax_must_be_axes():
    with pytest.raises(TypeError, match=r"`ax` must be a matplotlib Axes or None; got Figure"):
        plot_trajectory(np.zeros((3, 2)), ax=Figure())


def test_docstring_examples():
    import contextlib
    import doctest
    import io

    import gaussfuse.plotting

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        result = doctest.testmod(gaussfuse.plotting, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0, out.getvalue()


def test_drawing_never_touches_pyplot():
    code = ("import sys, numpy as np\n"
            "from gaussfuse.plotting import *\n"
            "t = np.arange(5.0); m = np.column_stack([t, t]); P = np.broadcast_to(np.eye(2), (5, 2, 2))\n"
            "plot_series(t, m, P); plot_trajectory(m, P); plot_consistency(t, (1, 3))\n"
            "plot_mode_probabilities(t, np.full((5, 2), 0.5), stacked=True)\n"
            "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot imported'\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_figures_go_through_pyplot_only_when_the_caller_uses_it(tmp_path):
    """With pyplot imported, a new figure is pyplot's (plt.show() shows it); a process that never imports pyplot
    draws on an Agg canvas and leaves pyplot unimported."""
    import subprocess
    import sys

    script = (
        "import sys, numpy as np\n"
        "from gaussfuse.plotting import plot_series\n"
        "fig = plot_series(np.arange(5.0), np.arange(5.0)[:, None], np.ones((5, 1, 1)))\n"
        "print('matplotlib.pyplot' in sys.modules, type(fig.canvas).__name__)\n"
        "import matplotlib\n"
        "matplotlib.use('Agg')\n"
        "import matplotlib.pyplot as plt\n"
        "fig = plot_series(np.arange(5.0), np.arange(5.0)[:, None], np.ones((5, 1, 1)))\n"
        "print(fig.number in plt.get_fignums())\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["False", "FigureCanvasAgg", "True"]


def test_arguments_of_the_wrong_kind_are_named(track):
    """They gave AttributeError or bare unpacking errors, or were read as something else: "13" as the interval
    (1, 3), names="ab" as ["a", "b"], stacked="no" as True, component -1 (the message says [0, n))."""
    times, zs, truth, res = track
    probs = np.full((40, 2), 0.5)
    cases = [
        (lambda: plot_demo(times, zs, truth, [(res.means, res.covs)]), TypeError, "`estimates` must be a mapping"),
        (lambda: plot_demo(times, zs, truth, {"f": res.means}), TypeError, "`estimates` must be a mapping"),
        (lambda: plot_demo(times, zs, truth, {}), ValueError, "`estimates` must have at least one"),
        (lambda: plot_demo(times, zs, truth, {"f": (res.means, res.covs)}, fig="x"), TypeError, "`fig` must be"),
        (lambda: plot_measurements(times, zs, res.means, res.covs, np.eye(2, 4), fig=3), TypeError, "`fig` must be"),
        (lambda: plot_measurements(times, zs, res.means, res.covs, np.eye(2, 4), track="yes"), TypeError,
         "`track` must be True or False"),
        (lambda: plot_measurements(times, zs, res.means, res.covs, np.eye(2, 4), names="xy"), TypeError,
         "`names` must be a sequence of strings"),
        (lambda: save_figure("x", "o.png"), TypeError, "`fig` must be a matplotlib Figure"),
        (lambda: plot_consistency(np.ones(5), "13"), ValueError, "`interval` must be a pair"),
        (lambda: plot_mode_probabilities(times, probs, names="ab"), TypeError, "`names` must be a sequence"),
        (lambda: plot_mode_probabilities(times, probs, stacked="no"), TypeError, "`stacked` must be True or False"),
        (lambda: plot_series(times, res.means, res.covs, component=-1), ValueError,
         r"`component` must be an integer in \[0, 4\)"),
    ]
    for call, error, match in cases:
        with pytest.raises(error, match=match):
            call()
    fig = plot_mode_probabilities(times, probs, names=np.array(["cv", "ct"]))  # an array of names is a sequence
    assert [line.get_label() for line in fig.axes[0].get_lines()] == ["cv", "ct"]


def test_a_refused_demo_leaves_no_pyplot_figure_open(track):
    """Through pyplot (the caller imported it) a call makes a figure; one that fails must not leave it open."""
    assert figures_left_open(
        "from gaussfuse.plotting import plot_demo\n"
        "times, zs = np.arange(5.0), np.zeros((5, 2))\n"
        "calls = [lambda bad=bad: plot_demo(times, zs, np.zeros((5, 4)), bad)\n"
        "         for bad in ({'f': (np.zeros((5, 4)), np.zeros((4, 4, 4)))}, {'f': (np.zeros((3, 4)), None)})]\n"
    ) == "0"


def figures_left_open(setup: str) -> str:
    """In a new process whose caller uses pyplot, run `setup` (it defines `calls`), make each call (refused with
    ValueError or TypeError), and return how many pyplot figures are left open."""
    code = (
        "import numpy as np, matplotlib; matplotlib.use('Agg'); import matplotlib.pyplot as plt\n" + setup +
        "for call in calls:\n"
        "    try:\n"
        "        call()\n"
        "    except (ValueError, TypeError):\n"
        "        pass\n"
        "print(len(plt.get_fignums()))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_datetimes_are_drawn_as_dates(filtered):
    """A zoned DatetimeIndex was drawn as microseconds since 1970 (1 s steps as 1e6 on the axis), and naive
    datetime64, a naive DatetimeIndex, durations and a list of datetimes were refused: each is drawn at its
    instants (UTC for a zone), the same x as the naive UTC datetime64."""
    import datetime

    import matplotlib.dates as mdates
    import pandas as pd

    _, zs, res, model = filtered
    start = np.datetime64("2024-01-01T00:00:00", "ns")
    utc = start + np.arange(12) * np.timedelta64(1, "s")
    want = mdates.date2num(utc)
    kinds = [utc, pd.DatetimeIndex(utc), pd.DatetimeIndex(utc).tz_localize("UTC").tz_convert("Asia/Tokyo"),
             [datetime.datetime(2024, 1, 1) + datetime.timedelta(seconds=i) for i in range(12)]]
    for times in kinds:
        for fig in (plot_series(times, res.means, res.covs, zs=zs), plot_measurements(times, zs, res.means, res.covs,
                                                                                        model.H)):
            line = fig.axes[0].get_lines()[-1]
            np.testing.assert_allclose(mdates.date2num(line.get_xdata()), want, rtol=0, atol=1e-9)
    # durations in seconds, whatever their unit: matplotlib drew their counts (4 s was 4, 4000 or 4e6; audit X4)
    for times in (np.arange(12) * np.timedelta64(1, "s"), np.arange(12) * np.timedelta64(1000, "ms"),
                  pd.to_timedelta(np.arange(12), unit="s"), [pd.Timedelta(i, "s") for i in range(12)],
                  [datetime.timedelta(seconds=i) for i in range(12)]):  # (lists of durations: refused before)
        for fig in (plot_series(times, res.means, res.covs, zs=zs),
                    plot_measurements(times, zs, res.means, res.covs, model.H)):
            np.testing.assert_array_equal(fig.axes[0].get_lines()[-1].get_xdata(), np.arange(12.0))
            assert "time (s)" in [ax.get_xlabel() for ax in fig.axes]
        assert plot_series(times, res.means, res.covs).axes[0].get_xlabel() == "time (s)"
        # in the unit asked for (review R9: 3 minutes under "time (min)" were drawn as 0, 60, 120)
        fig = plot_series(times, res.means, res.covs, time_unit="ms")
        assert fig.axes[0].get_xlabel() == "time (ms)"
        np.testing.assert_array_equal(fig.axes[0].get_lines()[-1].get_xdata(), 1000.0 * np.arange(12.0))
        with pytest.raises(ValueError, match=r"^`time_unit` must be one of D, h, m, s, ms, us, ns .* got 'min'\.$"):
            plot_series(times, res.means, res.covs, time_unit="min")
        probs = np.full((12, 2), 0.5)
        fig = plot_mode_probabilities(times, probs)
        assert fig.axes[0].get_xlabel() == "time (s)"
        np.testing.assert_array_equal(fig.axes[0].get_lines()[0].get_xdata(), np.arange(12.0))
    with pytest.raises(ValueError, match="`times` must not hold NaT"):
        plot_series(np.r_[utc[:11], np.datetime64("NaT")], res.means, res.covs)


def test_a_refused_series_or_trajectory_leaves_no_pyplot_figure_open():
    """plot_series and plot_trajectory made their figure before checking zs and truth: each refused call left one
    open."""
    assert figures_left_open(
        "from gaussfuse.plotting import plot_series, plot_trajectory\n"
        "m, P = np.zeros((5, 4)), np.tile(np.eye(4), (5, 1, 1))\n"
        "calls = [lambda: plot_series(np.arange(5.0), m, P, zs=np.zeros(3)),\n"
        "         lambda: plot_series(np.arange(5.0), m, P, truth='x'),\n"
        "         lambda: plot_trajectory(m, P, zs=np.zeros(3)),\n"
        "         lambda: plot_trajectory(m, P, truth=np.zeros((4, 1)))]\n"
    ) == "0"


def test_measurements_without_covariances_are_drawn_without_bands(filtered):
    """A keep="means" result has no covariances: plot_measurements refused it ("`covs` must be an array of numbers;
    got NoneType"), where plot_series and plot_trajectory draw it without bands (audit X4)."""
    times, zs, res, model = filtered
    H = np.atleast_2d(model.H)
    fig = plot_measurements(times, np.column_stack([zs, zs]) if zs.ndim == 1 else zs, res.means, None,
                            np.vstack([H, H]) if H.shape[0] == 1 else H, track=True)
    for ax in fig.axes:
        assert not ax.collections and not ax.patches  # no band, no ellipse
    line = fig.axes[0].get_lines()[-1]
    np.testing.assert_allclose(line.get_ydata(), (res.means @ H.T)[:, 0])


def test_a_single_step_is_a_point_and_a_bar():
    """A line and a band of one step have no length and no width: only their legend was drawn (audit X4)."""
    fig = plot_series(np.array([2.0]), np.array([[1.0, 0.0]]), np.array([np.diag([0.25, 1.0])]), k=3)
    ax = fig.axes[0]
    (line,) = ax.get_lines()
    assert line.get_marker() == "o" and line.get_xydata().tolist() == [[2.0, 1.0]]
    (bar,) = ax.collections
    np.testing.assert_allclose(bar.get_segments()[0], [[2.0, 1.0 - 1.5], [2.0, 1.0 + 1.5]])
    assert bar.get_label() == "estimate ±3σ"
    line = plot_series(np.arange(2.0), np.zeros((2, 1)), np.ones((2, 1, 1))).axes[0].get_lines()[0]
    assert line.get_marker() in (None, "None", "")  # two steps or more: a line, as before
    # the truth, and a trajectory's estimate and truth, of one step are dots too (review R9)
    ax = plot_series(np.array([2.0]), np.array([[1.0]]), None, truth=np.array([[0.5]])).axes[0]
    assert [line.get_marker() for line in ax.get_lines()] == ["o", "o"]
    ax = plot_trajectory(np.array([[1.0, 2.0]]), truth=np.array([[1.5, 2.5]])).axes[0]
    assert [line.get_marker() for line in ax.get_lines()] == ["o", "o"]


def test_messages_name_the_argument_at_fault(filtered):
    """units=5 was a bare "'int' object is not iterable"; plot_trajectory's covs were said not to match `times`,
    which it has no argument for; plot_demo's pair that is not a pair was named as "got dict"."""
    times, zs, res, model = filtered
    with pytest.raises(TypeError, match=r"`units` must be a str or a sequence of 2 str \(None for none\); got 5\."):
        plot_measurements(times, zs, res.means, res.covs, model.H, units=5)
    with pytest.raises(ValueError, match=r"^`covs` must have shape \(12, 4, 4\) to match `means`; got shape "
                                         r"\(3, 4, 4\)\.$"):
        plot_trajectory(res.means, res.covs[:3])
    with pytest.raises(TypeError, match=r"got ndarray for 'f'\.$"):
        plot_demo(times, zs, res.means[:, :4], {"f": res.means})


@pytest.mark.parametrize("stacked", [False, True])
def test_mode_probabilities_of_one_step_are_drawn(stacked):
    """Audit PP1: a one-step IMM result drew nothing (one-point lines without a marker; stacked areas of no width)
    under a legend that said otherwise. Oracle: the result's own mode probabilities."""
    from gaussfuse.plotting import plot_mode_probabilities

    model = gf.constant_velocity(1.0, 0.1, 1.0)
    imm = gf.imm_filter([model, gf.constant_velocity(1.0, 10.0, 1.0)], gf.Gaussian([0.0, 1.0], np.eye(2)),
                        np.array([0.3]), [[0.9, 0.1], [0.1, 0.9]])
    ax = plot_mode_probabilities([0.0], imm.mode_probs, ["slow", "fast"], stacked=stacked).axes[0]
    if stacked:  # a stacked bar: mode j from the sum of those before it to the sum up to it
        segments = [np.asarray(c.get_segments()[0]) for c in ax.collections]
        top = np.cumsum(imm.mode_probs[0])
        np.testing.assert_allclose([seg[:, 1] for seg in segments], np.column_stack([top - imm.mode_probs[0], top]))
        assert all((seg[:, 0] == 0.0).all() and c.get_linewidth()[0] > 1 for seg, c in zip(segments, ax.collections))
    else:
        lines = ax.get_lines()
        assert [line.get_marker() for line in lines] == ["o", "o"]
        np.testing.assert_array_equal([line.get_ydata()[0] for line in lines], imm.mode_probs[0])
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["slow", "fast"]


def test_values_that_cannot_be_what_is_drawn_are_refused():
    """A negative variance drew a band of no width, NIS values of -1 were titled "too cautious", and negative mode
    probabilities were drawn (audit XX4); a variance of round-off below 0, as a filter leaves, is drawn."""
    from gaussfuse.plotting import plot_consistency, plot_mode_probabilities, plot_series

    T, covs = 10, np.tile(np.eye(2), (10, 1, 1))
    bad = covs.copy()
    bad[4, 1, 1] = -1.0
    with pytest.raises(ValueError, match=r"^`covs` must be covariances, whose variances are >= 0; got -1 at step 4, "
                                         r"component 1\.$"):
        plot_series(np.arange(T), np.zeros((T, 2)), bad)
    roundoff = covs.copy()
    roundoff[4, 1, 1] = -1e-17
    assert isinstance(plot_series(np.arange(T), np.zeros((T, 2)), roundoff, component=1), Figure)
    with pytest.raises(ValueError, match=r"^`values` must be NIS or NEES values, >= 0; got -1\.$"):
        plot_consistency(-np.ones(5), (1.0, 2.0))
    with pytest.raises(ValueError, match=r"^`probs` must be probabilities, in \[0, 1\]; got -1\.$"):
        plot_mode_probabilities(np.arange(T), -np.ones((T, 2)))

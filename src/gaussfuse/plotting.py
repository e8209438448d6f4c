"""Figures of measurements and estimates.

matplotlib is an optional dependency (``pip install gaussfuse[plot]``); it is
imported inside these functions only, and figures are drawn with the Agg
canvas on a :class:`matplotlib.figure.Figure`, never through pyplot's global
state. Every function takes an optional `fig` and returns the figure.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["plot_measurements", "plot_demo", "save_figure"]


def plot_measurements(
    times,
    zs,
    means,
    covs,
    H,
    *,
    names: Sequence[str] | None = None,
    fig: Figure | None = None,
) -> Figure:
    r"""Measurements against the estimated measurement, one panel per component.

    Panel j shows the measurements :math:`z_{k,j}` as dots, the estimate
    :math:`(H m_k)_j` as a line and a band of :math:`\pm 2\sigma` with
    :math:`\sigma = \sqrt{(H P_k H^\top)_{jj}}`.

    Parameters
    ----------
    times : array_like of shape (T,)
        Times.
    zs : array_like of shape (T, m) or (T,)
        Measurements; NaN (missing) components are not drawn.
    means : array_like of shape (T, n)
        State means (filtered or smoothed).
    covs : array_like of shape (T, n, n)
        State covariances.
    H : array_like of shape (m, n) or (T, m, n)
        Measurement matrix, e.g. ``model.H``.
    names : sequence of str of length m, optional
        Names of the measurement components (y-axis labels).
    fig : matplotlib.figure.Figure, optional
        Figure to draw into; a new one by default.

    Returns
    -------
    matplotlib.figure.Figure
    """
    times = np.asarray(times, dtype=np.float64)
    zs = np.asarray(zs, dtype=np.float64).reshape(times.shape[0], -1)
    means, covs = np.asarray(means, dtype=np.float64), np.asarray(covs, dtype=np.float64)
    H = np.asarray(H, dtype=np.float64)
    est = (H @ means[..., None])[..., 0]
    std = np.sqrt(np.diagonal(H @ covs @ np.swapaxes(H, -1, -2), axis1=-2, axis2=-1))
    m = zs.shape[1]
    names = list(names) if names is not None else [f"z{j}" for j in range(m)]
    fig = fig if fig is not None else _figure((7.0, 1.0 + 2.2 * m))
    axes = fig.subplots(m, 1, sharex=True, squeeze=False)[:, 0]
    for j, ax in enumerate(axes):
        ax.plot(times, zs[:, j], ".", color="0.35", markersize=4, label="measurement")
        _band(ax, times, est[:, j], std[:, j], "estimate")
        ax.set_ylabel(names[j])
    axes[0].legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time")
    return fig


def plot_demo(
    times,
    zs,
    truth,
    estimates: Mapping[str, tuple[np.ndarray, np.ndarray]],
    *,
    fig: Figure | None = None,
) -> Figure:
    """A 2-D track: the x–y trajectory, and the x position against time with ±2σ bands.

    Parameters
    ----------
    times : array_like of shape (T,)
        Times.
    zs : array_like of shape (T, 2)
        Position measurements (x, y).
    truth : array_like of shape (T, n)
        True states, positions (x, y) first.
    estimates : mapping of str to (means, covs)
        Label to means of shape (T, n) and covariances of shape (T, n, n),
        positions first, e.g. ``{"filter": (res.means, res.covs)}``.
    fig : matplotlib.figure.Figure, optional
        Figure to draw into; a new one by default.

    Returns
    -------
    matplotlib.figure.Figure
    """
    times, zs, truth = (np.asarray(a, dtype=np.float64) for a in (times, zs, truth))
    fig = fig if fig is not None else _figure((11.0, 4.5))
    track, xt = fig.subplots(1, 2)
    track.plot(zs[:, 0], zs[:, 1], ".", color="0.35", markersize=4, label="measurement")
    track.plot(truth[:, 0], truth[:, 1], color="black", linewidth=1, label="truth")
    xt.plot(times, zs[:, 0], ".", color="0.35", markersize=4, label="measurement")
    xt.plot(times, truth[:, 0], color="black", linewidth=1, label="truth")
    for label, (means, covs) in estimates.items():
        means, covs = np.asarray(means), np.asarray(covs)
        track.plot(means[:, 0], means[:, 1], label=label)
        _band(xt, times, means[:, 0], np.sqrt(covs[:, 0, 0]), label)
    track.set(xlabel="x", ylabel="y", title="trajectory", aspect="equal", adjustable="datalim")
    xt.set(xlabel="time", ylabel="x", title="x position, ±2σ bands")
    track.legend(loc="best", fontsize="small")
    xt.legend(loc="best", fontsize="small")
    return fig


def save_figure(fig: Figure, path: str | os.PathLike[str]) -> None:
    """Save `fig` atomically; the format is the file's extension (PNG if none).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or os.PathLike
        The image file; nothing is left there if saving fails.

    Raises
    ------
    ValueError
        If matplotlib cannot write the extension's format.
    """
    from .io import open_atomic

    fmt = os.path.splitext(os.fspath(path))[1][1:].lower() or "png"
    supported = fig.canvas.get_supported_filetypes()
    if fmt not in supported:
        raise ValueError(
            f"{os.fspath(path)}: unknown image format {fmt!r}; use one of {', '.join(sorted(supported))}."
        )
    with open_atomic(path, "wb") as f:
        fig.savefig(f, format=fmt)


def _figure(figsize: tuple[float, float]) -> Figure:
    """A new figure on an Agg canvas, outside pyplot."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _band(ax: Axes, times: np.ndarray, mean: np.ndarray, std: np.ndarray, label: str) -> None:
    """A line for `mean` and a shaded band of ±2 `std` in the same colour."""
    (line,) = ax.plot(times, mean, label=label)
    ax.fill_between(times, mean - 2 * std, mean + 2 * std, color=line.get_color(),
                    alpha=0.2, linewidth=0, label=f"{label} ±2σ")

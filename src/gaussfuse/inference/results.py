"""The results of the filters and smoothers, and what every engine does to them.

Only NumPy and the Gaussian type are used here, so that the compiled kernels
can build these results too.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from .._frozen import reduce_frozen, shapes_repr
from ..errors import not_finite
from ..gaussian import Gaussian

__all__ = ["FilterResult", "SmoothResult", "KEEP", "stack", "first", "kept", "check_smoothed"]

KEEP = ("all", "means", "last")
"""What :func:`gaussfuse.filter` can keep per step: everything, no covariances, or only the final belief."""


@dataclass(frozen=True, eq=False)
class FilterResult:
    r"""The output of :func:`filter`.

    With a leading series axis on the measurements (N series), every array
    gains that axis and `loglik` has shape (N,).

    Attributes
    ----------
    means : ndarray of shape (T, n)
        Filtered means ``E[x_k | z_1..z_k]``.
    covs : ndarray of shape (T, n, n)
        Filtered covariances.
    predicted_means : ndarray of shape (T, n)
        One-step predictions ``E[x_k | z_1..z_{k-1}]``.
    predicted_covs : ndarray of shape (T, n, n)
        Covariances of the predictions.
    innovations : ndarray of shape (T, m)
        ``z_k - E[z_k | z_1..z_{k-1}]``; NaN where ``z_k`` is missing.
    innovation_covs : ndarray of shape (T, m, m)
        Covariances of the predicted measurements.
    loglik : float
        ``log p(z_1..z_T)`` over the observed components, including the
        ``-m/2 log 2π`` constants.
    last_mean : ndarray of shape (n,)
        The final filtered mean (the belief to continue from).
    last_cov : ndarray of shape (n, n)
        The final filtered covariance.
    iterations : ndarray of int, shape (T,), or None
        For the iterated methods ("iekf", "iplf"): the number of
        linearise-and-update passes made at each step, at most the option
        `iterations` (see `tol` in :func:`filter`). None for the other
        methods.
    cov_factors : ndarray of shape (T, n, n), or None
        With ``form="sqrt"``: the lower-triangular Cholesky factors
        :math:`L_k` the square-root filter propagates, ``covs[k] = L_k L_kᵀ``
        (symmetrised). None for the covariance form. A singular covariance
        (a state known exactly) has many such factors: below a pivot of 0
        (or of round-off) a column holds whatever the triangularisation left,
        and the two engines may leave different ones (a noise-free sensor:
        entries 0.3 and -0.47 for the same ``covs``).
    predicted_cov_factors : ndarray of shape (T, n, n), or None
        With ``form="sqrt"``: the factors of `predicted_covs`.
    gains : ndarray of shape (T, n, m), or None
        With ``gains=True``: the Kalman gain :math:`K_k` of each step (its
        columns for missing components are zero). None otherwise.
    nis : ndarray of shape (T,), or None
        The normalised innovation squared :math:`v_k^\top S_k^{-1} v_k` over
        the observed components (χ² with that many degrees of freedom for a
        consistent filter; NaN where nothing was observed): what the
        divergence check (`check` in :func:`filter`) tests. None with
        ``keep="last"``.
    rejected : ndarray of bool, shape (T, m), or None
        With `gate`: the measurement components the gate rejected (treated
        as missing). None without a gate.

    Notes
    -----
    With ``keep="means"`` the covariance fields are None; with
    ``keep="last"`` every per-step field (`iterations` too) is None, so that
    a long series filters in memory independent of its length. The fields'
    type annotations are those of the default ``keep="all"`` (so that
    ``res.means[-1]`` type-checks), and are not true of the fields these
    two leave out. `table` and
    `state_names` carry a pandas input's index and columns and the model's
    component names, for :meth:`to_pandas`.
    """

    # Annotated as what the default keep="all" gives, so that ``res.means[-1]`` type-checks in user code;
    # keep="means" and keep="last" leave some of them None (see the Notes).
    means: np.ndarray
    covs: np.ndarray
    predicted_means: np.ndarray
    predicted_covs: np.ndarray
    innovations: np.ndarray
    innovation_covs: np.ndarray
    loglik: float | np.ndarray
    last_mean: np.ndarray
    last_cov: np.ndarray
    iterations: np.ndarray | None = None
    cov_factors: np.ndarray | None = None
    predicted_cov_factors: np.ndarray | None = None
    gains: np.ndarray | None = None
    nis: np.ndarray | None = None
    rejected: np.ndarray | None = None
    table: object = None
    state_names: tuple[str, ...] | None = None

    __reduce__ = reduce_frozen  # pickles and copies keep read-only arrays read-only
    __repr__ = shapes_repr

    def to_pandas(self, covariances: bool = False, names=None):
        """The filtered means and standard deviations as a pandas DataFrame, indexed like the input.

        Parameters
        ----------
        covariances : bool, default False
            Also the covariances, one column ``cov_a_b`` per pair of components.
        names : sequence of str, optional
            The state components' names (default: the model's, else x0, x1, ...).

        Returns
        -------
        pandas.DataFrame
            Columns ``name`` and (when the covariances were kept) ``name_sd``
            per component; the index of a
            Series or DataFrame given as `zs` (else 0..T-1).
        """
        from .frames import to_frame

        return to_frame(self.means, self.covs, self.table, self.state_names if names is None else names, covariances)

    @property
    def last(self) -> Gaussian:
        """The final filtered belief, to continue filtering from (one series only)."""
        if self.last_mean.ndim != 1:
            raise ValueError("`last` is for one series; use `last_mean` and `last_cov` for a batch.")
        # the filter's own belief, not checked as a user's (its round-off can fail the PSD test: audit GG2)
        return Gaussian._trusted(np.array(self.last_mean), np.array(self.last_cov))


@dataclass(frozen=True, eq=False)
class SmoothResult:
    """The output of :func:`smooth`.

    Attributes
    ----------
    means : ndarray of shape (T, n)
        Smoothed means ``E[x_k | z_1..z_T]``.
    covs : ndarray of shape (T, n, n)
        Smoothed covariances.
    gains : ndarray of shape (T - 1, n, n)
        Smoother gains ``G_k``, k = 0..T-2. Where the prediction ``P⁻_{k+1}``
        is singular (no process noise on a degenerate belief), ``G_k`` is
        fixed only on its range: ``G_k P⁻_{k+1}`` is the cross-covariance, and
        the smoothed moments and the lag-one covariance ``G_k P^s_{k+1}`` use
        no more than that. Off the range, whether a direction of round-off
        counts as singular turns on the last bits of ``P⁻_{k+1}``, so the two
        engines can differ there (by O(1)) while agreeing on all of these.
    filtered : FilterResult
        The forward pass.
    iterations : int or None
        For the iterated smoothers ("iekf", "iplf"): the number of passes
        made, at most the option `iterations` (see `tol` in :func:`smooth`).
        None for the other methods.
    cov_factors : ndarray of shape (T, n, n), or None
        With ``form="sqrt"``: the lower-triangular factors of `covs`
        (``covs[k] = L_k L_kᵀ``, symmetrised); not unique where a covariance
        is singular (see :class:`FilterResult`). None for the covariance form.
    """

    means: np.ndarray
    covs: np.ndarray
    gains: np.ndarray
    filtered: FilterResult
    iterations: int | np.ndarray | None = None
    cov_factors: np.ndarray | None = None

    __reduce__ = reduce_frozen
    __repr__ = shapes_repr

    @property
    def loglik(self) -> float | np.ndarray:
        """The log-likelihood of the measurements (from the forward pass)."""
        return self.filtered.loglik

    def to_pandas(self, covariances: bool = False, names=None):
        """The smoothed means and standard deviations as a pandas DataFrame (see :meth:`FilterResult.to_pandas`).

        Parameters
        ----------
        covariances : bool, default False
            Also the covariances, one column ``cov_a_b`` per pair of components.
        names : sequence of str, optional
            The state components' names (default: the model's, else x0, x1, ...).

        Returns
        -------
        pandas.DataFrame
            Columns ``name`` and (when the covariances were kept) ``name_sd``
            per component; the index of a
            Series or DataFrame given as `zs` (else 0..T-1).
        """
        from .frames import to_frame

        names = self.filtered.state_names if names is None else names
        return to_frame(self.means, self.covs, self.filtered.table, names, covariances)


def stack(results: list):
    """Stack per-series results along a new leading axis."""
    cls = type(results[0])
    values = {}
    for f in fields(cls):
        items = [getattr(r, f.name) for r in results]
        if f.name == "filtered":
            values[f.name] = stack(items)
        else:
            values[f.name] = None if items[0] is None else np.stack(items)
    return cls(**values)


def first(result, index: int = 0):
    """Series `index` of a batched result (by default the first, or only, one), without the leading axis."""
    values = {}
    for f in fields(type(result)):
        item = getattr(result, f.name)
        if f.name == "filtered":
            values[f.name] = first(item, index)
        elif f.name == "loglik":
            values[f.name] = float(item[index])
        elif f.name == "iterations" and np.ndim(item) == 1 and isinstance(result, SmoothResult):
            values[f.name] = int(item[index])
        elif f.name in ("state_names", "table"):  # the call's labels, the same for every series
            values[f.name] = item
        else:
            values[f.name] = None if item is None else item[index]
    return type(result)(**values)


def kept(result: FilterResult, keep: str) -> FilterResult:
    """Drop what `keep` does not ask for from a full single-series result."""
    covariances = ("covs", "predicted_covs", "innovation_covs", "cov_factors", "predicted_cov_factors")
    per_step = ("means", "predicted_means", "innovations", "iterations", "gains", "nis", "rejected")
    drop = {"all": (), "means": covariances, "last": per_step + covariances}[keep]
    return replace(result, **dict.fromkeys(drop))


def check_smoothed(means: np.ndarray, covs: np.ndarray) -> None:
    """Raise FloatingPointError for a smoothed belief (N, T, n) of a compiled engine that is not finite.

    Names the step the readable backward pass would have stopped at: in the
    first series that overflowed, the latest step.
    """
    bad = ~(np.isfinite(means).all(axis=-1) & np.isfinite(np.diagonal(covs, axis1=-2, axis2=-1)).all(axis=-1))
    if bad.any():
        s = int(np.flatnonzero(bad.any(axis=1))[0])
        where = f"in series {s}, " if means.shape[0] > 1 else ""
        raise FloatingPointError(f"{where}at step {int(np.flatnonzero(bad[s])[-1])}: {not_finite('smoothed')}")

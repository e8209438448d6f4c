r"""Is the filter consistent? NIS, NEES, innovation whiteness, RMSE.

A filter whose model is right produces

* innovations :math:`v_k \sim N(0, S_k)`, independent over time, so the
  normalised innovation squared :math:`\epsilon_v = v_k^\top S_k^{-1} v_k` is
  :math:`\chi^2_{m}`;
* estimation errors :math:`e_k = x_k - \hat x_k \sim N(0, P_k)`, so the
  normalised estimation error squared :math:`\epsilon_x = e_k^\top P_k^{-1}
  e_k` is :math:`\chi^2_{n}` (needs the truth: simulations).

An average of :math:`K` independent :math:`\chi^2_d` values times
:math:`K` is :math:`\chi^2_{Kd}`, which gives the two-sided confidence
interval of the average (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4). The
NIS of one run are independent over time, so their average over time
has that interval. The NEES of one run are not: the estimation errors of
consecutive steps are strongly correlated (a local level's time-averaged
NEES spreads three times as wide as the χ² interval assumes, which called
a consistent filter inconsistent in half of its runs); the NEES are
averaged at each step across independent Monte Carlo runs, or, as
:func:`consistency` does, each run's time average is tested across runs
(a t interval). An average above the interval means the filter is
overconfident (for example Q too small); below, too cautious. Whiteness is tested on the innovations
whitened by :math:`S_k^{-1/2}`: their sample autocorrelations at lags
1..L should lie within :math:`\pm z_{1-\alpha/2}/\sqrt{T}`, summarised by
the Ljung–Box statistic.
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass

import numpy as np

from ._linalg import PSD_RTOL, UNRESOLVED, observed_gram, step_cholesky, whiten, wrap_components
from .errors import DivergenceWarning, average_text, diverging, gate_lost
from ._validation import as_array, component_mask, integer, is_integer, negative_variance, shape_error

__all__ = ["nis", "nees", "chi2_interval", "divergence", "DivergenceMonitor", "DIVERGENCE_WINDOW",
           "DIVERGENCE_FALSE_ALARM", "whiteness", "rmse", "consistency", "ConsistencyReport", "Whiteness"]

DIVERGENCE_WINDOW = 50
"""Steps per window of :func:`divergence` (windows overlap by half)."""

DIVERGENCE_FALSE_ALARM = 1e-3
"""The chance that :func:`divergence` flags a consistent filter's run, at most (over all its windows)."""


def _vectors(name: str, errors, cov_name: str, covs) -> tuple[np.ndarray, np.ndarray]:
    """`errors` (..., m) and `covs` (..., m, m) as arrays, their shapes checked (arguments `name` and `cov_name`)."""
    e = as_array(name, errors, allow_nan=True)
    C = as_array(cov_name, covs, allow_nan=True)
    if e.ndim < 1 or not e.shape[-1]:
        raise shape_error(name, "(..., m), one vector of m >= 1 components per step", e.shape)
    if C.shape != e.shape + e.shape[-1:]:
        raise shape_error(cov_name, f"{e.shape + e.shape[-1:]} to match `{name}` {e.shape}", C.shape)
    _symmetric(cov_name, C)
    return e, C


def _symmetric(cov_name: str, C: np.ndarray) -> None:
    """Raise, naming the first index, where the covariances `C` (..., m, m) are not symmetric to round-off: one
    triangle of each would be used, silently."""
    d = np.sqrt(np.abs(np.diagonal(C, axis1=-2, axis2=-1)))
    with np.errstate(invalid="ignore"):  # (NaN entries: a step not computed)
        asym = np.abs(C - np.swapaxes(C, -1, -2)) > PSD_RTOL * d[..., :, None] * d[..., None, :]
    if asym.any():
        where = tuple(int(i) for i in np.argwhere(asym)[0])
        raise ValueError(f"`{cov_name}` must be symmetric; it is not at index {where}.")


def _place(index: tuple) -> str:
    """Where a step of one series (T,), of N series (N, T) or of a deeper batch is, for an error message."""
    index = tuple(int(i) for i in index)
    if len(index) == 1:
        return f"at step {index[0]}"
    if len(index) == 2:
        return f"in series {index[0]}, at step {index[1]}"
    return f"at index {index}"


def _counts(a: np.ndarray) -> bool:
    """Whether every entry of `a` is a count: 0, 1, 2, ..."""
    return not ((a < 0).any() or (a != np.round(a)).any())


def _broken(cov_name: str, where: str) -> ValueError:
    """The error for a covariance that is NaN or infinite in part (not throughout, as one not computed is)."""
    return ValueError(f"`{cov_name}` must be finite where it was computed; it is NaN or infinite in part {where}.")


def _uncomputed(cov_name: str, C: np.ndarray) -> np.ndarray:
    """Which covariances of `C` (..., m, m) were not computed (NaN throughout: a diffuse start's first steps), as a
    bool array (...); raises, naming the step, for one that is NaN or infinite in part (review R17)."""
    uncomputed = np.isnan(C).all(axis=(-2, -1))
    broken = np.argwhere(~uncomputed & ~np.isfinite(C).all(axis=(-2, -1)))
    if broken.size:
        raise _broken(cov_name, _place(broken[0]))
    return uncomputed


def _quadratic(name: str, errors, cov_name: str, covs) -> tuple[np.ndarray, np.ndarray]:
    """``eᵀ C⁻¹ e`` over the non-NaN components of each e, and their number (arguments `name` and `cov_name`)."""
    e, C = _vectors(name, errors, cov_name, covs)
    flat_e, flat_C = e.reshape(-1, e.shape[-1]), C.reshape(-1, *C.shape[-2:])
    observed = ~np.isnan(flat_e) & ~_uncomputed(cov_name, C).reshape(-1)[:, None]

    def where(t: int) -> str:
        return _place(np.unravel_index(t, e.shape[:-1]))

    gram, _ = observed_gram(flat_C, np.nan_to_num(flat_e)[..., None], observed, f"`{cov_name}`", where=where)
    dof = observed.sum(axis=1)
    out = np.where(dof > 0, gram[:, 0, 0], np.nan)
    return out.reshape(e.shape[:-1]), dof.reshape(e.shape[:-1])


def nis(innovations, innovation_covs) -> np.ndarray:
    """Normalised innovation squared ``vᵀ S⁻¹ v`` at each step.

    Parameters
    ----------
    innovations : array_like of shape (..., T, m)
        ``res.innovations``; NaN components (missing data) are left out.
    innovation_covs : array_like of shape (..., T, m, m)
        ``res.innovation_covs``.

    Returns
    -------
    ndarray of shape (..., T)
        NaN where nothing was observed, or S holds NaN (a step without an
        innovation covariance, as :func:`nees` takes it). Each value is χ²
        with as many degrees of freedom as observed components.

    Raises
    ------
    ValueError
        For a covariance that is not symmetric, or shapes that do not match.
    numpy.linalg.LinAlgError
        Naming the first such step, where S of the observed components is
        not positive definite: indefinite, or singular (a noise-free
        measurement of a state known exactly): v has no density to weigh
        there (:func:`nees` takes a singular P, whose error is 0 off its
        range).
    """
    return _quadratic("innovations", innovations, "innovation_covs", innovation_covs)[0]


def nees(errors, covs, scale=None) -> np.ndarray:
    """Normalised estimation error squared ``eᵀ P⁻¹ e`` at each step.

    Parameters
    ----------
    errors : array_like of shape (..., T, n)
        ``truth - estimate``, angle components wrapped to [-π, π)
        (:func:`gaussfuse.wrap_angle`); a step whose errors are all NaN (an estimate
        not yet identified, as a diffuse prior's first steps) gives NaN.
    covs : array_like of shape (..., T, n, n)
        The estimate's covariances. A singular one (a component known
        exactly, or a combination of them) is valid: the value is then
        ``eᵀ P⁺ e`` over its range, on P scaled to unit diagonal so that
        which directions count as singular does not depend on units; the
        error along the rest, which a consistent filter makes 0, is not
        counted. A direction whose variance there is at most
        :data:`SINGULAR` n ε of the largest counts as singular: the
        filter's round-off, where it is 0 in exact arithmetic.
    scale : array_like of shape (..., T, n), optional
        The size of the values each error was computed from
        (:func:`consistency` takes the largest of the truth, the estimate
        and the prediction): a component whose standard deviation is at
        most 8 ε of it counts as known exactly. A filter leaves a variance
        of round-off (1e-40, say) where a noise-free sensor fixed a
        component, and an error that is round-off of the value too (4e-16
        for a value of 2): their ratio means nothing.

    Returns
    -------
    ndarray of shape (..., T)
        Each value χ² with rank(P) degrees of freedom (n for a positive
        definite P) for a consistent filter.

    Raises
    ------
    ValueError, TypeError
        For arrays of the wrong shape or type, and a covariance that is NaN
        or infinite in part, naming the step.
    numpy.linalg.LinAlgError
        For a covariance that is not positive semi-definite (a negative
        variance, or an eigenvalue below round-off on its components'
        scales), naming the step.
    """
    return _nees(errors, covs, scale)[0]


SINGULAR = 4
""":func:`nees` takes a direction of P, scaled to unit diagonal, as singular where its variance is at most
``SINGULAR n ε`` of the largest: the Joseph form leaves up to 2.25 ε there where it is 0 in exact arithmetic (a
noise-free sensor of x0 + x1 of three states, both forms and engines), while a sensor 1e14 times more precise than
the prediction leaves 1e-14, computed to about 1%."""


def _nees(errors, covs, scale=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nees` and each value's degrees of freedom (the rank of the observed block of P)."""
    e, C = _vectors("errors", errors, "covs", covs)
    flat_e, flat_C = e.reshape(-1, e.shape[-1]), C.reshape(-1, *C.shape[-2:])
    floor = np.zeros(flat_e.shape)  # each component's standard deviation at or below which it is known exactly
    if scale is not None:
        size = as_array("scale", scale, allow_nan=True)
        if size.shape != e.shape:
            raise shape_error("scale", f"{e.shape}, that of `errors`", size.shape)
        floor = UNRESOLVED * np.abs(size.reshape(flat_e.shape))
    out, dof = np.full(flat_e.shape[0], np.nan), np.zeros(flat_e.shape[0], dtype=np.int64)
    whole = ~np.isnan(flat_e).any(axis=1) & np.isfinite(flat_C).all(axis=(1, 2))
    def place(steps: np.ndarray):  # where the k-th of a stack of these flat steps is, for an error message
        return lambda k: _place(np.unravel_index(steps[k], e.shape[:-1]))

    out[whole], dof[whole] = _pseudo_nees(flat_e[whole], flat_C[whole], floor[whole], place(np.flatnonzero(whole)))
    for t in np.flatnonzero(~whole & ~np.isnan(flat_e).all(axis=1)):  # some components missing: their block
        o = ~np.isnan(flat_e[t])
        block = flat_C[t][np.ix_(o, o)]
        if np.isfinite(block).all():
            value, rank = _pseudo_nees(flat_e[t][o][None], block[None], floor[t][o][None], place(np.array([t])))
            out[t], dof[t] = value[0], rank[0]
        elif not np.isnan(block).all():  # as nis refuses it (a NaN was left as NaN, unseen: audit II7)
            raise _broken("covs", _place(np.unravel_index(t, e.shape[:-1])))
    return out.reshape(e.shape[:-1]), dof.reshape(e.shape[:-1])


def _pseudo_nees(e: np.ndarray, P: np.ndarray, floor: np.ndarray, where) -> tuple[np.ndarray, np.ndarray]:
    """``eᵀ P⁺ e`` and rank(P) for stacks e (k, n) and P (k, n, n), on P scaled to unit diagonal (see :func:`nees`).

    A component of variance 0, or of standard deviation at most its `floor` (k, n), is a zero row of the scaled P:
    its eigenvalue 0 falls below the cut, and its error is not counted. ``where(k)`` says where the k-th is, for
    the error of one that is not positive semi-definite (it named no step, where nis names it: audit XX2).
    """
    n = P.shape[-1]
    variances = np.diagonal(P, axis1=-2, axis2=-1)
    negative = negative_variance(P)
    if negative is not None:
        k, i = negative
        raise np.linalg.LinAlgError(f"`covs` must be positive semi-definite; the covariance {where(k)} has a "
                                    f"variance of {variances[k, i]:.3g} at component {i}.")
    d = np.sqrt(variances.clip(min=0.0))
    known = d <= floor
    unit = np.where(known, 1.0, d)
    scaled = np.where(known[:, :, None] | known[:, None, :], 0.0, P / unit[:, :, None] / unit[:, None, :])
    vals, vecs = np.linalg.eigh(scaled)
    bad = np.flatnonzero(vals[:, 0] < -PSD_RTOL * vals[:, -1])
    if bad.size:  # indefinite on its components' scales: not dropped as singular
        raise np.linalg.LinAlgError(f"`covs` must be positive semi-definite; the covariance {where(bad[0])} has an "
                                    f"eigenvalue of {vals[bad[0], 0]:.3g} relative to its variances.")
    rank = vals > SINGULAR * n * np.finfo(np.float64).eps * vals.max(axis=-1, initial=0.0)[:, None]
    w = np.einsum("kij,ki->kj", vecs, np.where(known, 0.0, e / unit))
    return np.sum(np.where(rank, w * w / np.where(rank, vals, 1.0), 0.0), axis=-1), rank.sum(axis=-1)


def _confidence(confidence) -> float:
    """`confidence` as a float in (0, 1), or a ValueError/TypeError naming it."""
    if isinstance(confidence, (bool, np.bool_)) or not isinstance(confidence, (int, float, np.integer, np.floating)):
        raise TypeError(f"`confidence` must be a probability in (0, 1); got {confidence!r:.60}.")
    if not 0 < confidence < 1:
        raise ValueError(f"`confidence` must be in (0, 1); got {confidence!r}.")
    return float(confidence)


def chi2_interval(dof: int, count: int = 1, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided interval for the average of `count` independent χ²_dof values.

    Parameters
    ----------
    dof : int
        Degrees of freedom of each value.
    count : int, default 1
        Number of values averaged.
    confidence : float, default 0.95
        Probability of the interval, in (0, 1).

    Returns
    -------
    low : float
        The ``χ²_{count·dof}`` quantile at (1 - confidence)/2, divided by `count`.
    high : float
        The quantile at (1 + confidence)/2, divided by `count`.

    Examples
    --------
    >>> lo, hi = chi2_interval(2, count=100)
    >>> round(lo, 2), round(hi, 2)
    (1.63, 2.41)
    """
    from scipy.special import chdtri, gammaincinv  # here: `import gaussfuse` loads only NumPy

    dof, count = integer("dof", dof), integer("count", count)
    confidence = _confidence(confidence)
    k = count * dof
    alpha = 1.0 - confidence
    # each bound from its own tail, without importing scipy.stats: 2 gammaincinv(k/2, s) is the χ²_k quantile of
    # lower tail s, chdtri(k, s) that of upper tail s (the lower bound as chdtri(k, 1 - alpha/2) lost the digits of
    # alpha that 1 - alpha/2 rounds away: 21% at a confidence of 1 - 1e-15, audit OO1)
    return float(2.0 * gammaincinv(k / 2, alpha / 2) / count), float(chdtri(k, alpha / 2) / count)


def divergence(nis_values, dof, window: int = DIVERGENCE_WINDOW,
               false_alarm: float = DIVERGENCE_FALSE_ALARM) -> list[tuple[int, int, int, float]]:
    r"""The steps where a filter's normalised innovations are too large for a consistent filter.

    Parameters
    ----------
    nis_values : array_like of shape (T,) or (N, T)
        :attr:`FilterResult.nis <gaussfuse.FilterResult>` of one series or N;
        NaN steps (nothing observed) are left out.
    dof : array_like of int, shape like `nis_values` or broadcastable to it
        The observed components at each step (its χ² degrees of freedom);
        a scalar when every step observes as many.
    window : int, default 50
        Steps per window; consecutive windows overlap by half, and the last
        one ends at the last step.
    false_alarm : float, default 1e-3
        The largest probability that a consistent filter is flagged anywhere
        (in any window of any series).

    Returns
    -------
    list of (series, first, last, average)
        The flagged step ranges (0-based, inclusive; overlapping windows
        merged), each with its series (0 for one series) and the average NIS
        per observed component over it (1 for a consistent filter).

    Raises
    ------
    ValueError
        For a shape or value out of range, naming the argument, and for a
        positive NIS at a step of 0 degrees of freedom (nothing observed
        there, nothing to normalise).

    Notes
    -----
    For a consistent filter the NIS of different steps are independent
    :math:`\chi^2_{m_k}`, so a window's sum :math:`X` is :math:`\chi^2_d`,
    :math:`d = \sum m_k`. By Laurent & Massart's bound (Ann. Statist. 28,
    2000, Lemma 1), :math:`P(X \ge d + 2\sqrt{d t} + 2t) \le e^{-t}`; a
    window is flagged above that threshold with
    :math:`t = \log(W / \alpha)`, W the number of windows tested and
    :math:`\alpha` = `false_alarm`, so that by the union (Bonferroni) bound a
    consistent filter is flagged with probability at most :math:`\alpha`
    per call, however long or many the series. The bound is in closed form
    (no quantile to compute) and slightly conservative: at d = 50 and
    W = 11 it flags an average above 2.24 per component where the exact
    quantile would flag above 1.93. Only large values are flagged: a filter
    too cautious for its data is not diverging.

    Examples
    --------
    >>> import numpy as np
    >>> calm = np.ones(200)
    >>> wild = np.concatenate([np.ones(100), 3.0 * np.ones(100)])
    >>> divergence(calm, np.ones(200)), divergence(wild, np.ones(200))
    ([], [(0, 100, 199, 3.0)])
    """
    window, false_alarm = _test_settings(window, false_alarm)
    v = np.atleast_2d(as_array("nis_values", nis_values, allow_nan=True))
    if v.ndim != 2:
        raise shape_error("nis_values", "(T,) or (N, T)", np.shape(nis_values))
    if (v < 0).any():
        raise ValueError("`nis_values` must be non-negative (normalised innovations squared); got a negative value.")
    per_step = np.ndim(dof) == 0  # the same dof at every step: a window's is dof times its observed steps
    counts = as_array("dof", dof)
    if not _counts(counts):
        raise ValueError("`dof` must be non-negative integers (each step's observed components).")
    try:
        k = np.broadcast_to(counts, v.shape)
    except ValueError:
        raise shape_error("dof", f"() or one broadcastable to `nis_values` {v.shape}", counts.shape) from None
    T = v.shape[-1]
    if T == 0:
        return []
    window = min(window, T)
    lo = _window_starts(T, window)
    seen = ~np.isnan(v)
    stray = np.argwhere(seen & (v > 0) & (k == 0))
    if stray.size:  # nothing observed there, so nothing to normalise (audit OO6: it was left out of the test)
        at = tuple(int(i) for i in stray[0][-np.ndim(nis_values):]) if np.ndim(nis_values) else ()
        raise ValueError(f"`nis_values` is positive at a step of 0 degrees of freedom (index {at}): a step with "
                         "nothing observed has a NIS of 0 or NaN; check that `dof` counts each step's observed "
                         "components.")
    complete = seen.all()
    if not complete:
        v, k = np.where(seen, v, 0.0), np.where(seen, k, 0.0)
    sums = _window_sums(v, window, lo)
    dofs = np.full(sums.shape, float(dof) * window) if complete and per_step else _window_sums(k, window, lo)
    flagged = (dofs > 0) & (sums >= _threshold(dofs, np.log(sums.size / false_alarm)))
    out = []
    for series, first, last in _flagged_ranges(flagged, lo, window):
        observed = seen[series, first:last + 1]
        average = v[series, first:last + 1][observed].sum() / k[series, first:last + 1][observed].sum()
        out.append((series, first, last, float(average)))
    return out


def _window_starts(T: int, window: int) -> np.ndarray:
    """The first steps of the windows of `window` steps: every ``window // 2``, and the last ending at T."""
    lo = np.arange(0, T - window + 1, max(window // 2, 1))
    return lo if lo[-1] + window >= T else np.append(lo, T - window)


def _window_sums(x: np.ndarray, window: int, lo: np.ndarray) -> np.ndarray:
    """Each window's sum of `x` (N, T), summed on its own: differences of running sums lose every later
    window to the rounding of one huge value (an NIS of 1e18 rounds them to 128)."""
    return np.lib.stride_tricks.sliding_window_view(x, window, axis=1)[:, lo].sum(axis=-1)


def _flagged_ranges(flagged: np.ndarray, lo: np.ndarray, window: int):
    """``(series, first, last)`` of the flagged windows (N, W), overlapping windows of a series merged."""
    for series in np.flatnonzero(flagged.any(axis=1)):
        ranges: list[list[int]] = []
        for start in lo[flagged[series]]:
            if ranges and start <= ranges[-1][1] + 1:
                ranges[-1][1] = int(start) + window - 1
            else:
                ranges.append([int(start), int(start) + window - 1])
        for first, last in ranges:
            yield int(series), first, last


def rejections(rejected, offered, probability: float, window: int = DIVERGENCE_WINDOW,
               false_alarm: float = DIVERGENCE_FALSE_ALARM) -> list[tuple[int, int, int, int, int]]:
    r"""The steps where a gate rejected at least half of what it was offered: a filter that has lost the data.

    Parameters
    ----------
    rejected, offered : array_like of int, shape (T,) or (N, T)
        At each step, the measurements (or components, gating by component)
        the gate rejected, and those it was offered (rejected or kept).
    probability : float
        The gate's: a consistent filter's measurement passes with it.
    window, false_alarm : as :func:`divergence`.

    Returns
    -------
    list of (series, first, last, rejected, offered)
        The flagged step ranges (0-based, inclusive; overlapping windows
        merged), with the counts over them: each flagged window holds at
        least half, a merged range may hold less (26 of 75).

    Notes
    -----
    Against a consistent prediction each offered measurement is rejected
    with probability at most :math:`p = 1 - \text{probability}`,
    independently, so a window's count K of N would be at most binomial:
    a window is flagged when :math:`P(\mathrm{Bin}(N, p) \ge K)` is below
    `false_alarm` over the number of windows and K is at least N / 2.
    Rejected steps carry no innovation into :func:`divergence`, so this is
    what sees a filter that has lost the data (a level that jumped, every
    measurement since rejected). The binomial tail alone would flag most
    long gated runs of a consistent model: each rejection leaves the next
    predictions less certain than they claim, so rejections come in runs
    (gate=0.99 on a local level with q/r = 100, 10,000 steps: 1.3%
    rejected, up to 8 in a row, 7 of 50 in one window); the half is what
    separates a filter that has lost the data from one that coasts.
    """
    window, false_alarm = _test_settings(window, false_alarm)
    if isinstance(probability, (bool, np.bool_)) or not isinstance(probability, (int, float, np.integer, np.floating)) \
            or not 0.0 < probability < 1.0:
        raise ValueError(f"`probability` must be the gate's, in (0, 1); got {probability!r}.")
    counts = []
    for name, value in (("rejected", rejected), ("offered", offered)):  # (booleans count: gate_counts' any())
        try:
            a = np.asarray(value)
        except ValueError:  # ragged
            a = np.asarray(value, dtype=object)
        if a.dtype.kind not in "biuf" or not np.isfinite(a).all() or not _counts(a):
            raise ValueError(f"`{name}` must be counts (0, 1, 2, ...) of shape (T,) or (N, T); got "
                             f"{value!r:.60}.")  # (offered counts of 1.5 and inf were cast: audit II3)
        counts.append(a)
    r, o = counts
    if r.shape != o.shape or r.ndim not in (1, 2) or (r > o).any():
        raise ValueError(f"`rejected` and `offered` must be counts of one shape, (T,) or (N, T), with rejected <= "
                         f"offered; got shapes {r.shape} and {o.shape}.")
    r, o = np.atleast_2d(r.astype(np.int64)), np.atleast_2d(o.astype(np.int64))
    T = r.shape[-1]
    if T == 0 or not r.any():
        return []
    window = min(window, T)
    lo = _window_starts(T, window)
    K, N = _window_sums(r, window, lo), _window_sums(o, window, lo)
    flagged = _lost(K, N, 1.0 - probability, false_alarm / K.size)
    return [(series, first, last, int(r[series, first:last + 1].sum()), int(o[series, first:last + 1].sum()))
            for series, first, last in _flagged_ranges(flagged, lo, window)]


def _lost(K, N, p, level):
    """Where K rejections of N offered are at least half and beyond the binomial tail at `level` for a rejection
    probability p: lost, not merely unlucky (:func:`rejections`' rule, for arrays or one window)."""
    from scipy.special import bdtrc  # P(Bin(n, p) > k)

    K, N = np.asarray(K), np.asarray(N)
    tail = np.where(K > 0, bdtrc(np.maximum(K - 1, 0), np.maximum(N, 1), p), 1.0)  # P(≥ K)
    return (tail <= level) & (2 * K >= N)


def gate_counts(rejected, seen, by: str) -> tuple[np.ndarray, np.ndarray]:
    """Per step, what a gate rejected and what it was offered (:func:`rejections`' counts).

    Parameters
    ----------
    rejected, seen : array_like of bool, shape (..., m)
        The components the gate rejected, and those it kept.
    by : {"measurement", "component"}
        The gate's unit: a measurement counts once (rejected whole; offered
        when any component was there), or each component counts.

    Returns
    -------
    rejected : ndarray of shape (...)
        What the gate rejected at each step.
    offered : ndarray of shape (...)
        What it was offered (rejected or kept).
    """
    rejected, seen = np.asarray(rejected), np.asarray(seen)
    if by == "measurement":
        lost = rejected.any(axis=-1)
        return lost, lost | seen.any(axis=-1)
    lost = rejected.sum(axis=-1)
    return lost, lost + seen.sum(axis=-1)


class _Rejections:
    """:func:`rejections` for updates that come one at a time; the j-th window is tested at ``α / (j (j + 1))``."""

    __slots__ = ("window", "false_alarm", "_counts", "_steps", "_since", "_tested", "_flagged")

    def __init__(self, window: int, false_alarm: float) -> None:
        self.window, self.false_alarm = window, false_alarm
        self._counts: deque = deque(maxlen=window)  # (rejected, offered, probability of a rejection) per update
        self._steps: deque = deque(maxlen=window)
        self._since, self._tested, self._flagged = 0, 0, False

    def add(self, lost: int, offered: int, probability: float, step) -> tuple[object, object, int, int] | None:
        """Record an update; ``(first, last, rejected, offered)`` when the window ending here newly fails."""
        if offered == 0:
            return None
        self._counts.append((int(lost), int(offered), 1.0 - probability))
        self._steps.append(step)
        self._since += 1
        if len(self._counts) < self.window or (self._tested and self._since < max(self.window // 2, 1)):
            return None
        self._since = 0
        self._tested += 1
        K, N = sum(c[0] for c in self._counts), sum(c[1] for c in self._counts)
        p = max(c[2] for c in self._counts)  # the most lenient gate of the window
        flagged = bool(_lost(K, N, p, self.false_alarm / (self._tested * (self._tested + 1))))
        report = flagged and not self._flagged
        self._flagged = flagged
        return (self._steps[0], self._steps[-1], K, N) if report else None


def _test_settings(window, false_alarm) -> tuple[int, float]:
    """`window` a positive integer and `false_alarm` a probability in (0, 1), or a ValueError/TypeError naming them."""
    window = integer("window", window)
    if isinstance(false_alarm, (bool, np.bool_)) or not isinstance(false_alarm, (int, float, np.integer, np.floating)) \
            or not 0.0 < false_alarm < 1.0:
        raise ValueError(f"`false_alarm` must be a probability in (0, 1); got {false_alarm!r}.")
    return window, float(false_alarm)


def _threshold(dof, t):
    """Laurent & Massart: a χ²_dof exceeds ``dof + 2√(dof t) + 2t`` with probability at most e^-t."""
    return dof + 2.0 * np.sqrt(dof * t) + 2.0 * t


class DivergenceMonitor:
    r""":func:`divergence` for a filter that runs one update at a time (``KalmanFilter``, ``Fuser``).

    Parameters
    ----------
    window : int, default 50
        Updates per window; windows overlap by half.
    false_alarm : float, default 1e-3
        The largest probability that a consistent filter is ever flagged,
        however long it runs.
    check : {"warn", "raise", "off"}, default "warn"
        What :meth:`observe` does with a failing window: warn, raise, or
        nothing ("off": :meth:`add` and :meth:`add_many` still return the
        windows that fail).

    Notes
    -----
    The number of windows is not known in advance, so the j-th window
    (j = 1, 2, ...) is tested at level :math:`\alpha / (j (j + 1))`, which
    sums to :math:`\alpha` over all of them; its threshold is
    :func:`divergence`'s with :math:`t = \log(j (j + 1) / \alpha)`.
    """

    __slots__ = ("window", "false_alarm", "check", "_values", "_dofs", "_steps", "_since", "_tested", "_flagged",
                 "_rejections")

    def __init__(self, window: int = DIVERGENCE_WINDOW, false_alarm: float = DIVERGENCE_FALSE_ALARM,
                 check: str = "warn") -> None:
        self.window, self.false_alarm = _test_settings(window, false_alarm)
        if not isinstance(check, str) or check not in ("warn", "raise", "off"):
            raise ValueError(f"`check` must be 'warn', 'raise' or 'off'; got {check!r}.")
        self.check = check
        self._values: list[float] = []  # the last `window` updates with observations: NIS, dof, step
        self._dofs: list[int] = []
        self._steps: list = []
        self._since = 0                  # updates since the last test
        self._tested = 0                 # windows tested so far
        self._flagged = False            # whether the last window tested failed
        self._rejections = _Rejections(self.window, self.false_alarm)  # the gate's, when updates are gated

    def add(self, nis_value: float, dof: int, step) -> tuple[object, object, float] | None:
        """Record an update; return ``(first, last, average)`` when the window ending here newly fails the test.

        `step` labels the update (a step number, a time). Updates without
        observations (`dof` 0, with a NIS of 0 or NaN) are skipped. A window is
        tested once the first `window` updates are in, then every
        ``window // 2`` updates; consecutive failing windows are reported
        once, at the first.

        Parameters
        ----------
        nis_value : float
            The update's normalised innovation squared.
        dof : int
            Its number of observed components (its χ² degrees of freedom).
        step : object
            The update's label.

        Returns
        -------
        tuple of (object, object, float) or None
            ``(first, last, average)``: the labels of the failing window's
            first and last updates and its average NIS per observed
            component; None when no window newly fails here.

        Raises
        ------
        ValueError
            For a positive NIS with `dof` 0 (nothing observed, nothing to
            normalise).
        """
        if dof == 0:
            if nis_value > 0.0:  # as `divergence` refuses it (review R45)
                raise ValueError(f"`nis_value` is {nis_value:g} at an update of 0 degrees of freedom: an update with "
                                 "nothing observed has a NIS of 0 or NaN.")
            return None
        self._values.append(float(nis_value))
        self._dofs.append(int(dof))
        self._steps.append(step)
        if len(self._values) > self.window:
            del self._values[0], self._dofs[0], self._steps[0]
        self._since += 1
        if len(self._values) < self.window or (self._tested and self._since < max(self.window // 2, 1)):
            return None
        self._since = 0
        self._tested += 1
        total, d = sum(self._values), float(sum(self._dofs))
        flagged = total >= _threshold(d, np.log(self._tested * (self._tested + 1) / self.false_alarm))
        report = flagged and not self._flagged
        self._flagged = flagged
        return (self._steps[0], self._steps[-1], total / d) if report else None

    def add_many(self, nis_values, dofs, steps) -> list[tuple[object, object, float]]:
        """:meth:`add` each of many updates, in order; the windows that newly failed, each ``(first, last, average)``.

        The same rule as :meth:`add`, vectorised over the updates (a piece of
        a long series); the two may be mixed on one monitor.

        Parameters
        ----------
        nis_values : array_like of shape (k,)
        dofs : array_like of int, shape (k,)
        steps : sequence of length k
            The updates' labels.

        Raises
        ------
        ValueError
            For arguments of different lengths, degrees of freedom that are
            not counts, or a positive NIS with 0 degrees of freedom.
        """
        # as add takes them (an infinite NIS too), in arrays of one length (paired silently, or an IndexError,
        # when the lengths differed: audit II2)
        nis_values, dofs = np.asarray(nis_values, dtype=np.float64), np.asarray(dofs, dtype=np.float64)
        if nis_values.ndim != 1:
            raise shape_error("nis_values", "(k,)", nis_values.shape)
        if dofs.shape != nis_values.shape:
            raise shape_error("dofs", f"{nis_values.shape}, that of `nis_values`", dofs.shape)
        if not _counts(dofs):
            bad = float(dofs[(dofs < 0) | (dofs != np.round(dofs))][0])
            raise ValueError(f"`dofs` must be counts of observed components (0, 1, 2, ...); got {bad:g}.")
        if len(steps) != nis_values.shape[0]:
            raise ValueError(f"`steps` must hold one label per update, {nis_values.shape[0]}; got {len(steps)}.")
        stray = np.flatnonzero((dofs == 0) & (nis_values > 0))
        if stray.size:
            raise ValueError(f"`nis_values` is positive at an update of 0 degrees of freedom (index {stray[0]}): an "
                             "update with nothing observed has a NIS of 0 or NaN.")
        kept = np.flatnonzero(dofs > 0)
        if kept.size == 0:
            return []
        old = len(self._values)
        values = np.concatenate([np.asarray(self._values, dtype=np.float64), nis_values[kept]])
        counts = np.concatenate([np.asarray(self._dofs, dtype=np.float64), dofs[kept]])
        stride = max(self.window // 2, 1)
        # the updates (indices into `values`) whose window is tested: the window-th, then every stride-th
        first = self.window - 1 if not self._tested else old - 1 + stride - self._since
        tests = np.arange(first, values.size, stride)  # first >= old: a test is never overdue

        def label(i: int):
            return self._steps[i] if i < old else steps[kept[i - old]]
        reports = []
        if tests.size:  # each window summed on its own: running sums lose later windows to one huge value
            starts = tests + 1 - self.window
            total = _window_sums(values[None], self.window, starts)[0]
            d = _window_sums(counts[None], self.window, starts)[0]
            j = self._tested + 1 + np.arange(tests.size)
            flagged = total >= _threshold(d, np.log(j * (j + 1.0) / self.false_alarm))
            newly = flagged & ~np.concatenate([[self._flagged], flagged[:-1]])
            reports = [(label(i - self.window + 1), label(i), float(total[t] / d[t]))
                       for t, i in zip(np.flatnonzero(newly), tests[newly])]
            self._tested += tests.size
            self._flagged = bool(flagged[-1])
            self._since = values.size - 1 - int(tests[-1])
        else:
            self._since += kept.size
        self._steps = [label(i) for i in range(max(values.size - self.window, 0), values.size)]
        self._values, self._dofs = values[-self.window:].tolist(), [int(d) for d in counts[-self.window:]]
        return reports

    @classmethod
    def for_check(cls, check) -> DivergenceMonitor | None:
        """The monitor an online filter keeps for its `check` argument ("warn", "raise"; None for "off").

        Parameters
        ----------
        check : {"warn", "raise", "off"}
            The filter's `check` argument.

        Returns
        -------
        DivergenceMonitor or None
            A monitor with that `check` and the default window and false
            alarm rate; None for "off".

        Raises
        ------
        ValueError
            For any other `check`.
        """
        if not isinstance(check, str) or check not in ("warn", "raise", "off"):
            raise ValueError(f"`check` must be one of ['warn', 'raise', 'off']; got {check!r}.")
        return None if check == "off" else cls(check=check)

    def observe(self, update, step, where: str, gate=None) -> None:
        """:meth:`add` an update (a kalman.Update); warn or raise a DivergenceWarning when a window newly fails.

        `where` formats the failing window's first and last `step` labels.
        With `gate`, the update's rejections are tested too, as
        :func:`rejections` does over a whole series (windows of gated
        updates; the j-th tested at ``false_alarm / (j (j + 1))``): a
        filter whose gate rejects everything has no innovations left to
        fail the χ² test.

        Parameters
        ----------
        update : kalman.Update
            The update; its `nis`, and its number of observed components
            from the non-NaN entries of its `innovation`.
        step : object
            The update's label.
        where : str
            A format string with two fields, for the failing window's first
            and last labels (e.g. ``"times {:g}-{:g}"``).
        gate : kalman.Gate, optional
            The gate the update ran with (its ``rejected`` says what it
            rejected).

        Raises
        ------
        DivergenceWarning
            With ``check="raise"``, when a window newly fails.

        Warns
        -----
        DivergenceWarning
            With ``check="warn"``, when a window newly fails.
        """
        seen = ~np.isnan(update.innovation)
        flagged = self.add(update.nis, int(np.sum(seen)), step)
        messages = []
        if flagged is not None:
            first, last, average = flagged
            messages.append(diverging([f"{average_text(average)} over {where.format(first, last)}"],
                                       self.false_alarm))
        if gate is not None and update.rejected is not None:
            lost, offered = gate_counts(update.rejected, seen, gate.by)
            found = self._rejections.add(lost, offered, gate.probability, step)
            if found is not None:
                first, last, K, N = found
                messages.append(gate_lost([f"{K} of {N} over {where.format(first, last)}"], gate.by, gate.probability,
                                          0, self.window))
        if not messages or self.check == "off":  # (audit DD2: "off" warned)
            return
        message = " ".join(messages)
        if self.check == "raise":
            raise DivergenceWarning(message)
        warnings.warn(message, DivergenceWarning, stacklevel=3)


@dataclass(frozen=True)
class Whiteness:
    """Whiteness of the normalised innovations.

    Parameters
    ----------
    autocorrelation : ndarray of shape (lags,)
        Sample autocorrelation of the whitened innovations (pooled over
        components) at lags 1..lags.
    bound : float
        ``z_{1-α/2} / sqrt(m T)``: the pooled autocorrelation of a white
        sequence stays within ±bound at each lag with the `confidence` (the
        m components' autocorrelations, each of sd 1/√T, averaged; the bound
        was that of one component, which m = 3 white components crossed at
        0.05% of the lags, not 5%).
    statistic : float
        Ljung–Box ``T (T + 2) Σ ρ_j² / (T - j)``, χ² with `lags` × m
        degrees of freedom summed over components.
    p_value : float
        The probability of a statistic at least as large for white
        innovations (χ² tail).
    white : bool
        ``p_value >= 1 - confidence``.
    """

    autocorrelation: np.ndarray
    bound: float
    statistic: float
    p_value: float
    white: bool


def whiteness(innovations, innovation_covs, lags: int = 10, confidence: float = 0.95) -> Whiteness:
    """Test one series' innovations (T, m) for whiteness (see the module notes).

    Steps with a missing component are left out.

    Parameters
    ----------
    innovations : array_like of shape (T, m)
        ``res.innovations`` of one series; NaN components are missing.
    innovation_covs : array_like of shape (T, m, m)
        ``res.innovation_covs``; a step where it is NaN (a diffuse prior's
        first steps) is left out with its innovation.
    lags : int, default 10
        Autocorrelation lags 1..lags, in [1, T' - 1] for the T' steps with
        no missing component.
    confidence : float, default 0.95
        The test's confidence: the innovations are white when the p-value is
        at least ``1 - confidence``; also sets the bound's normal quantile.

    Returns
    -------
    Whiteness
        The autocorrelations, their bound, the Ljung–Box statistic, its
        p-value and the verdict.
    """
    from scipy.special import chdtrc, ndtri

    confidence = _confidence(confidence)
    v = as_array("innovations", innovations, allow_nan=True)
    S = as_array("innovation_covs", innovation_covs, allow_nan=True)
    if v.ndim != 2 or not v.shape[1]:
        raise shape_error("innovations", "(T, m), m >= 1", v.shape)
    if S.shape != v.shape + v.shape[-1:]:
        raise shape_error("innovation_covs", f"{v.shape + v.shape[-1:]} to match `innovations` {v.shape}", S.shape)
    _symmetric("innovation_covs", S)  # one triangle was used, silently (audit AA3)
    # complete innovations with an innovation covariance (a diffuse start's first steps have neither: review R16)
    keep = ~np.isnan(v).any(axis=1) & ~_uncomputed("innovation_covs", S)
    if keep.sum() < 2:
        raise ValueError(f"whiteness needs at least 2 steps with a complete innovation and its covariance; "
                         f"{int(keep.sum())} of the {v.shape[0]} have both.")
    L = step_cholesky(S[keep], "`innovation_covs`", np.flatnonzero(keep))  # (named at its step: review R16)
    w = whiten(L, v[keep][..., None])[..., 0]  # (T', m) whitened
    T, m = w.shape
    if not is_integer(lags):
        raise TypeError(f"`lags` must be an integer in [1, {T - 1}] for {T} complete innovations; got {lags!r}.")
    if not 1 <= lags < T:
        raise ValueError(f"`lags` must be an integer in [1, {T - 1}] for {T} complete innovations; got {lags!r}.")
    w = w - w.mean(axis=0)
    denom = np.sum(w * w, axis=0)
    rho = np.array([np.sum(w[j:] * w[:-j], axis=0) / denom for j in range(1, lags + 1)])  # (lags, m)
    q = T * (T + 2) * np.sum(rho**2 / (T - np.arange(1, lags + 1))[:, None])
    p = float(chdtrc(lags * m, q))  # the χ² survival function
    # the mean over m components of independent autocorrelations of sd 1/√T has sd 1/√(mT)
    bound = float(-ndtri((1 - confidence) / 2) / np.sqrt(m * T))  # the normal quantile, from its own tail (R45)
    return Whiteness(rho.mean(axis=1), bound, float(q), p, p >= 1 - confidence)


def rmse(estimates, truth, axis=None, angles=None) -> np.ndarray | float:
    """Root mean squared error ``sqrt(mean(sum((estimate - truth)², -1)))``.

    Parameters
    ----------
    estimates, truth : array_like of shape (..., T, d), or (T,)
        A 1-D array is T scalar estimates (d = 1), not one vector.
    axis : int or tuple, optional
        Axes of the mean (over the leading axes, after summing over the
        last); all by default.
    angles : sequence of int or of bool, optional
        The components that are angles (a model's ``state_angles``): their
        differences are wrapped to [-π, π), so that estimates of 3.1 and
        -3.1 rad are 0.08 apart, not 6.2.

    Returns
    -------
    float or ndarray
        The RMSE; an array when `axis` leaves axes.

    Examples
    --------
    >>> from gaussfuse.diagnostics import rmse
    >>> rmse([1.0, -1.0, 1.0, -1.0], [0.0, 0.0, 0.0, 0.0])
    1.0
    """
    a, b = as_array("estimates", estimates), as_array("truth", truth)
    if a.shape != b.shape:
        raise shape_error("truth", f"{a.shape}, that of `estimates`", b.shape)
    if a.ndim == 1:  # a series of scalars
        a, b = a[:, None], b[:, None]
    if axis is not None:  # (NumPy's AxisError named the array left after the sum over the last axis: audit II6)
        lead, axes = a.ndim - 1, axis if isinstance(axis, tuple) else (axis,)
        expected = f"`axis` must be one of the estimates' {lead} leading axes, from {-lead} to {lead - 1}, or a tuple"
        if not all(isinstance(i, (int, np.integer)) and not isinstance(i, (bool, np.bool_)) for i in axes):
            raise TypeError(f"{expected} of them; got {axis!r:.60}.")
        if not all(-lead <= i < lead for i in axes) or len({i % lead for i in axes}) < len(axes):
            raise ValueError(f"{expected} of them, each once (estimates of shape {np.shape(estimates)}); got "
                             f"{axis!r}.")
    with np.errstate(over="ignore"):  # (a difference beyond the largest float is an error of inf)
        diff = wrap_components(a - b, None if angles is None else component_mask("angles", angles, a.shape[-1]))
    # in units of the largest difference that each mean takes in, so that the squares neither overflow (errors
    # of 1e155 gave inf) nor underflow (1e-170 gave 0: audit DD2)
    top = np.max(np.abs(diff), axis=-1, initial=0.0)  # (initial: no error on no estimates, whose RMSE is NaN)
    largest = np.max(top, axis=axis, keepdims=True, initial=0.0)
    unit = np.where((largest > 0.0) & np.isfinite(largest), largest, 1.0)
    squares = np.sum((diff / unit[..., None]) ** 2, axis=-1)
    with np.errstate(invalid="ignore"):  # no estimates: NaN, not NumPy's "mean of empty slice" (audit XX5)
        mean = np.sum(squares, axis=axis) / np.sum(np.ones_like(squares), axis=axis)
    out = np.squeeze(unit, axis=axis) * np.sqrt(mean)
    return float(out) if np.ndim(out) == 0 else out


@dataclass(frozen=True)
class ConsistencyReport:
    """What :func:`consistency` finds; ``str(report)`` is a short table.

    Parameters
    ----------
    nis : float
        Average NIS over every observed step and run.
    nis_interval : tuple of float
        Its χ² interval ``(low, high)``.
    nis_ok : bool
        Whether `nis` lies inside.
    nees : float or None
        Average NEES over every step and run (None without the truth).
    nees_interval : tuple of float or None
        The interval it must lie in for a consistent filter, from the spread
        of the runs' time averages (a t interval around n); None without the
        truth, or with one run (a run's NEES over time are correlated: no
        interval follows from one).
    nees_ok : bool or None
        Whether `nees` lies inside (None without an interval).
    whiteness : Whiteness or None
        Of the first run's innovations (None with fewer than 10 steps
        without a missing component).
    rmse : float or None
        Of the means, with the truth.
    runs : int
        Number of runs (series).
    confidence : float, default 0.95
        The intervals' confidence.
    """

    nis: float
    nis_interval: tuple[float, float]
    nis_ok: bool
    nees: float | None
    nees_interval: tuple[float, float] | None
    nees_ok: bool | None
    whiteness: Whiteness | None
    rmse: float | None
    runs: int
    confidence: float = 0.95

    @property
    def consistent(self) -> bool:
        """NIS (and NEES, when known) inside their intervals."""
        return self.nis_ok and self.nees_ok is not False

    def __str__(self) -> str:
        # (it said 95% whatever the confidence: audit II4)
        lines = [f"{'statistic':<10} {'average':>10} {f'{100 * self.confidence:.10g}% interval':>22}  verdict"]

        def row(name, value, interval, ok):
            verdict = "consistent" if ok else ("overconfident" if value > interval[1] else "too cautious")
            lines.append(f"{name:<10} {value:>10.3f} {f'[{interval[0]:.3f}, {interval[1]:.3f}]':>22}  {verdict}")

        row("NIS", self.nis, self.nis_interval, self.nis_ok)
        if self.nees is not None and self.nees_interval is not None:
            row("NEES", self.nees, self.nees_interval, self.nees_ok)
        elif self.nees is not None:
            lines.append(f"{'NEES':<10} {self.nees:>10.3f} {'(one run: no interval)':>22}")
        if self.whiteness is not None:
            w = self.whiteness
            lines.append(f"{'whiteness':<10} {'p = ' + format(w.p_value, '.3f'):>10} "
                         f"{'Ljung-Box':>22}  {'white' if w.white else 'correlated'}")
        if self.rmse is not None:
            lines.append(f"{'RMSE':<10} {self.rmse:>10.4g}")
        return "\n".join(lines)


def consistency(result, truth=None, confidence: float = 0.95, lags: int | None = None,
                angles=None) -> ConsistencyReport:
    """One-call consistency report of a filter result (one series or N runs).

    Parameters
    ----------
    result : FilterResult
        From :func:`gaussfuse.filter`, with a leading axis for N Monte Carlo
        runs or series.
    truth : array_like of shape ([N,] T, n), optional
        True states (simulation): adds NEES and RMSE.
    confidence : float, default 0.95
    lags : int, optional
        Whiteness lags (default min(10, C // 5), with C the steps whose
        components are all observed, after a diffuse start); the test needs
        C >= 10.
    angles : sequence of int or of bool, optional
        The state components that are angles (the model's
        ``state_angles``): their errors ``truth - mean`` are wrapped to
        [-π, π) for the NEES and the RMSE, as the filter wraps its means.

    Returns
    -------
    ConsistencyReport

    Raises
    ------
    ValueError
        For a result without per-step innovations, with nothing observed,
        or filtered with a gate (whose kept NIS are not χ²), and for a
        `truth` of another shape than the means.
    """
    from .inference.results import FilterResult

    if not isinstance(result, FilterResult):
        more = " (a SmoothResult's filter is its .filtered)" if hasattr(result, "filtered") else ""
        raise TypeError(f"`result` must be a FilterResult from gaussfuse.filter{more}; got {type(result).__name__}.")
    if result.nis is None:
        raise ValueError("`result` holds no per-step innovations (keep='last'): filter with keep='all' or 'means'.")
    if result.rejected is not None:  # (audit AA3: the true model's gated filter was called "too cautious")
        raise ValueError(
            "`result` was filtered with a gate: the NIS of the measurements it kept are χ² cut off at the gate, and "
            "each rejection leaves the next predictions surer than they claim, so no χ² interval holds them. Test "
            "the consistency of the same filter without `gate`, and see what the gate did with "
            "gaussfuse.diagnostics.rejections.")
    # the filter's own NIS: with the steps of a diffuse prior's start (no innovation covariance) left out
    q = np.asarray(result.nis, dtype=np.float64)
    dof = (~np.isnan(result.innovations)).sum(axis=-1)
    seen = ~np.isnan(q)
    runs = 1 if np.ndim(result.innovations) == 2 else np.shape(result.innovations)[0]
    if not seen.any():
        raise ValueError("`result` has no observed innovation (every measurement is missing): nothing to test.")
    # the sum of the K observed NIS values is χ² with their total degrees of freedom
    lo, hi = chi2_interval(int(dof[seen].sum()), 1, confidence)
    nis_interval = (lo / seen.sum(), hi / seen.sum())
    nis_avg = float(np.mean(q[seen]))
    nees_avg = nees_interval = nees_ok = err = None
    if truth is not None:
        truth = as_array("truth", truth)
        if truth.shape != np.shape(result.means):
            raise shape_error("truth", f"{np.shape(result.means)}, that of the filtered means", truth.shape)
        # the steps whose estimate is identified (not a diffuse prior's first steps, NaN)
        known = np.isfinite(result.means).all(axis=-1)
        mask = None if angles is None else component_mask("angles", angles, truth.shape[-1])
        if result.covs is None:
            raise ValueError("`result` holds no covariances (keep='means'), which the NEES needs: filter with "
                             "keep='all', or leave out `truth`.")
        sizes = np.fmax(np.abs(result.means), np.abs(truth))  # what an error's round-off is relative to
        if result.predicted_means is not None:
            sizes = np.fmax(sizes, np.abs(result.predicted_means))
        e, dof_e = _nees(wrap_components(truth - result.means, mask), result.covs, sizes)
        nees_avg = float(np.mean(e[known]))
        if e.ndim == 2 and e.shape[0] >= 2:  # each run's time average: independent across runs
            from scipy.stats import t as student

            per_run = np.sum(np.where(known, e, 0.0), axis=1) / known.sum(axis=1)
            half = student.ppf(0.5 + confidence / 2, per_run.size - 1) * per_run.std(ddof=1) / np.sqrt(per_run.size)
            n = float(np.mean(dof_e[known]))  # the state dimension, less directions known exactly
            nees_interval = (n - half, n + half)
            nees_ok = bool(nees_interval[0] <= nees_avg <= nees_interval[1])
        err = rmse(result.means[known], truth[known], angles=mask)
    batch = np.ndim(result.innovations) == 3
    first_v = result.innovations[0] if batch else result.innovations
    first_S = result.innovation_covs  # (None with keep="means": a batch's raised a TypeError, audit II1)
    first_S = first_S[0] if batch and first_S is not None else first_S
    white = None
    if first_S is not None:
        # from the first step with an innovation covariance on (a diffuse prior's first steps have none)
        start = int(np.argmax(np.isfinite(first_S).all(axis=(1, 2)))) if len(first_S) else 0
        first_v, first_S = first_v[start:], first_S[start:]
        complete = int(np.sum(~np.isnan(first_v).any(axis=1)))
        if np.isfinite(first_S).all() and complete >= 10:
            white = whiteness(first_v, first_S, min(10, complete // 5) if lags is None else lags, confidence)
    return ConsistencyReport(nis_avg, nis_interval, nis_interval[0] <= nis_avg <= nis_interval[1],
                             nees_avg, nees_interval, nees_ok, white, err, runs, confidence)

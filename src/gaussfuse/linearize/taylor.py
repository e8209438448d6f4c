r"""First-order Taylor linearisation, with analytic or automatic Jacobians.

A function :math:`g` is approximated around a point :math:`\hat x` by

.. math::

    g(x) \approx J (x - \hat x) + g(\hat x) = A x + b, \qquad
    A = J = \partial g / \partial x \,|_{\hat x}, \quad b = g(\hat x) - A \hat x,

with no error covariance (:math:`\Omega = 0`). This is the extended Kalman
filter's linearisation; the iterated EKF re-linearises at each iterate.
"""

from __future__ import annotations

import warnings
from typing import Callable

import numpy as np

from .._linalg import marginal_std, wrap_angle
from .._validation import call_checked, call_each, size_reason
from ..errors import ModelFunctionError

__all__ = ["Taylor", "jacobian", "complex_step_jacobian", "finite_difference_jacobian"]

_COMPLEX_STEP = 1e-20
"""The complex step, relative to each component's scale (:func:`_scales`). Its error is of order
(step / the length over which f curves)², and ``Im f`` is the derivative times the step, which must
not underflow: an absolute step such as 1e-100 would be 1.5% off on a state of size 1e-99, and would
lose an output below about 1e-208 to underflow."""


def jacobian(name: str, fn: Callable, x: np.ndarray, args: tuple, size: int,
             vectorized: bool = False, spread: np.ndarray | None = None,
             angles: np.ndarray | None = None, check: str = "all") -> np.ndarray:
    """Jacobian of ``fn(x, *args)`` (returning shape (size,)) at x of shape (n,).

    Complex-step differentiation [1]_ when `fn` accepts complex input:
    ``J[:, i] = Im fn(x + i h_i e_i) / h_i`` with :math:`h_i` 1e-20 times the
    component's scale (see :func:`_scales`): no subtractive cancellation, so exact to round-off for analytic
    functions at any scale, unless they curve over lengths below 1e-12 of the component's scale (the error is
    of order (h_i / that length)²: a relative 7e-10 for 1 / (1 + x / 1e-16) under a spread
    of 1, audit CC1). Otherwise adaptive
    central differences with Richardson extrapolation
    (:func:`scipy.differentiate.jacobian`), with steps on each component's
    own scale (:func:`finite_difference_jacobian`).

    Parameters
    ----------
    name : str
        The function's name, for error messages ("f" or "h").
    fn : callable
        ``fn(x, *args)``; with `vectorized`, it takes a stack of states (k, n).
    x : ndarray of shape (n,)
    args : tuple
        Further arguments (the control).
    size : int
        The length of ``fn``'s output.
    vectorized : bool
        Whether `fn` takes a stack of states.
    spread : ndarray of shape (n,), optional
        Each component's standard deviation under the belief, the scale of
        its steps (not finer than 1e-7 of the component's size).
    angles : array of bool, shape (size,), optional
        Outputs that are angles: their finite differences are wrapped to
        [-π, π), so that a step across the ±π cut is not a jump of 2π.
    check : {"all", "faint"}, default "all"
        Which rows of the complex-step Jacobian are checked against
        differences of `fn` (:func:`_dropped`), the Jacobian then taken by
        finite differences where they disagree: every row, along each
        component (a component whose `spread` is 0 is not stepped), or
        only the rows whose derivatives are all too small to move the
        output, along two mixed directions. A function that drops the
        imaginary part on the way (``np.linalg.norm``, ``np.abs``,
        ``np.real``) gives the affected derivatives 0; a pseudorange
        ``norm(p - s) + b`` keeps only the clock bias b's. :class:`Taylor`
        checks every row at a function's first three Jacobians and the
        faint ones after.

    Returns
    -------
    ndarray of shape (size, n)

    References
    ----------
    .. [1] J. R. R. A. Martins, P. Sturdza and J. J. Alonso, "The complex-step
       derivative approximation", ACM TOMS 29(3), 2003.
    """
    try:
        return complex_step_jacobian(name, fn, x, args, size, vectorized, spread, check)
    except _RejectsComplex:
        return finite_difference_jacobian(name, fn, x, args, size, vectorized, spread, angles)


def _scales(x: np.ndarray, spread: np.ndarray | None, floor: bool = True) -> np.ndarray:
    """Each component's scale for a derivative's step (see :func:`finite_difference_jacobian`).

    ``spread_j`` where given and positive (at least ``1e-7 |x_j|``), else
    ``|x_j|``; the state's, ``0.1 max_i |x_i|`` (0.01 for a
    state of zeros), where that is 0 or below 1e-280 (a complex step of
    1e-20 of it would underflow); and without `spread`, the state's as a
    floor for every component, unless ``floor=False``.
    """
    largest = np.max(np.abs(x))
    whole = 0.1 * largest if largest > 1e-279 else 1e-2  # an all-zero state has no scale: a guess
    # the belief's spread where given: a range to a beacon 10 m away in Earth-centred metres (|x| = 6.4e6,
    # spread 1) was stepped by 6.4e5 m; no finer than 1e-7 |x|, or the steps would reach round-off
    own = np.abs(x) if spread is None else np.where(spread > 0, np.maximum(spread, 1e-7 * np.abs(x)), np.abs(x))
    if floor and spread is None:
        return np.maximum(own, whole)
    return np.where(own > 1e-280, own, whole)


class _RejectsComplex(Exception):
    """The function cannot be evaluated at a complex argument."""


def complex_step_jacobian(name: str, fn: Callable, x: np.ndarray, args: tuple, size: int,
                          vectorized: bool = False, spread: np.ndarray | None = None,
                          check: str = "all") -> np.ndarray:
    """Complex-step Jacobian, shape (size, n); see :func:`jacobian`. Raises ``_RejectsComplex`` where `fn`
    refuses a complex argument, returns a real or non-finite one, or changes otherwise than the `check`ed rows
    say."""
    if check not in ("all", "faint"):
        raise ValueError(f"`check` must be 'all' or 'faint'; got {check!r}.")
    n = x.shape[0]
    step = _COMPLEX_STEP * _scales(x, spread, floor=False)  # no cancellation to fear: no state-wide floor
    X = x + 1j * np.diag(step)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", np.exceptions.ComplexWarning)
            if vectorized:
                Y = np.asarray(fn(X, *args))
            else:
                Y = np.stack([np.asarray(fn(xi, *args)).reshape(-1) for xi in X])
    except Exception as exc:
        raise _RejectsComplex from exc
    if not np.iscomplexobj(Y) or Y.size != n * size:
        raise _RejectsComplex
    J = Y.reshape(n, size).imag.T / step
    if not np.all(np.isfinite(J)):
        raise _RejectsComplex
    scale = step / _COMPLEX_STEP
    if check == "all":  # along each component the linearisation reads
        rows = np.ones(size, dtype=bool)
        moves = np.diag(1e-3 * scale)[np.ones(n, dtype=bool) if spread is None else spread > 0]
    else:  # derivatives that move the output by less than 1e-8 of itself over a scale, along two directions
        rows = np.abs(J) @ step <= 1e-28 * np.abs(Y.reshape(n, size)[0].real)
        k = np.arange(n)
        moves = 1e-3 * scale * np.stack([(1.0 + k / (n + 1)) * (-1.0) ** k,
                                         (1.0 + ((k + 1) * 0.6180339887498949) % 1.0) * (-1.0) ** (k // 2)])
        if spread is not None:
            moves *= spread > 0  # a component known exactly is not stepped (review R33)
    if rows.any() and _dropped(fn, x, args, vectorized, moves, J, rows, size):
        raise _RejectsComplex  # an output that the step's imaginary part did not reach, but x does
    return J


def _dropped(fn: Callable, x: np.ndarray, args: tuple, vectorized: bool, moves: np.ndarray, J: np.ndarray,
             rows: np.ndarray, size: int) -> bool:
    """Whether outputs `rows` of ``fn`` change along any of `moves` (k, n) otherwise than their complex-step
    derivatives J say.

    A complex step gives an output a derivative of 0 (or of round-off) when the function drops the imaginary
    part on the way (``np.linalg.norm``, ``np.vdot``, ``np.abs``, ``np.real``, ``np.angle``) and returns other
    outputs that keep it, so the result is complex: a range beside a bearing got no gradient at all, silently
    (audit CC1), and a pseudorange beside its clock bias only the bias's. Along each move m, f's change is
    estimated twice: by central differences over m and over 2m (whose quadratic terms cancel, at a stationary
    point too: review R22); inside a domain narrower than 2m, over m/2 and m; where f raises on one side of x
    (a domain's edge), by 4 (f(x + m/2) - f(x)) - (f(x + m) - f(x)), whose quadratic term cancels, and by
    f(x + m) - f(x) (review R24; a second step could leave a narrow domain: review R26). An output disagrees
    when the first estimate is further from J m than 1% of itself, plus the two estimates' difference (the
    truncation error, which grows with the step: at a stationary point of x³, or along sin(1000 x) stepped by
    a thousandth of a spread of 1, the cubic term alone disagreed: review R28), plus f's round-off; and it must
    not agree at a step 1/32 or 1/1024 as long.
    """
    eps = np.finfo(np.float64).eps

    def at(z: np.ndarray) -> np.ndarray | None:
        try:
            with np.errstate(all="ignore"):
                if vectorized:
                    return np.asarray(fn(z[None, :], *args), dtype=np.float64).reshape(size)
                return np.asarray(fn(z, *args), dtype=np.float64).reshape(size)
        except Exception:  # (a domain's edge a step away)
            return None

    centre = None

    def disagrees(move: np.ndarray) -> np.ndarray | None:
        """Per row: 1 where the differences disagree with J, else 0, or -1 where they agree but the change is
        within 100 times f's round-off (no evidence at this step); None where f raised on both sides."""
        nonlocal centre
        ahead, behind = at(x + move), at(x - move)
        if ahead is not None and behind is not None:
            far = (at(x + 2 * move), at(x - 2 * move))
            if far[0] is not None and far[1] is not None:
                fine, coarse, ends = (ahead - behind) / 2, (far[0] - far[1]) / 4, (ahead, behind, *far)
            else:  # a domain's edge between one step and two
                near = (at(x + move / 2), at(x - move / 2))
                if near[0] is None or near[1] is None:
                    return None  # no evidence either way
                fine, coarse, ends = near[0] - near[1], (ahead - behind) / 2, (ahead, behind, *near)
        else:
            centre = at(x) if centre is None else centre
            side, sign = (ahead, 1.0) if ahead is not None else (behind, -1.0)
            half = None if side is None or centre is None else at(x + sign * move / 2)
            if half is None:
                return None
            fine, coarse = sign * (4 * (half - centre) - (side - centre)), sign * (side - centre)
            ends = (side, centre, half)
        fine, coarse, linear = fine[rows], coarse[rows], (J @ move)[rows]
        slack = 64 * eps * np.max(np.abs(np.stack(ends)), axis=0)[rows]
        verdict = (np.abs(fine - linear) > 0.01 * np.abs(fine) + np.abs(fine - coarse) + slack).astype(int)
        return np.where((verdict == 0) & (np.maximum(np.abs(fine), np.abs(linear)) <= 100 * slack), -1, verdict)

    # a derivative that was dropped is missed at every step; the truncation error of one curving within the step
    # (sin(1000 x) under a spread of 3, review R29) shrinks with it: a disagreement is cleared by an agreement at
    # a step 1/32 or 1/1024 as long, not by one lost there in f's round-off (a pseudorange of 2e7 m changes by
    # 2e-7 m over 1e-6 of a spread of 0.1 m, and its dropped slope was missed: review R30; a sine beside 1e8 at a
    # spread of 3000 was taken for a drop where only the shortest step was lost: review R31)
    for move in moves:
        flagged = disagrees(move)
        if flagged is None or not (flagged == 1).any():
            continue
        flagged = flagged == 1
        for shorter in (move / 32, move / 1024):
            again = disagrees(shorter)
            if again is not None:
                flagged &= again != 0
            if not flagged.any():  # (cleared: review R32)
                break
        if flagged.any():
            return True
    return False


_TINY_OUTPUT = 1e-150
"""An output smaller than this at x is measured in its own units (1), not by its size: dividing by a
near-underflow value could overflow where the output is of order 1 a step away."""


def finite_difference_jacobian(name: str, fn: Callable, x: np.ndarray, args: tuple, size: int,
                               vectorized: bool = False, spread: np.ndarray | None = None,
                               angles: np.ndarray | None = None) -> np.ndarray:
    """Adaptive finite-difference Jacobian, shape (size, n); see :func:`jacobian`.

    Outputs that are `angles` are taken as their value at x plus the
    wrapped difference from it: a wrap or arctan2 output stepped across
    ±π would otherwise jump by 2π (a slope of 1e8 for a bearing of 1).

    The steps along component j start at a tenth of its scale: the
    belief's spread, ``spread_j``, where given (not finer than
    ``1e-7 |x_j|``, so that the steps stay above round-off), else ``|x_j|``
    (so domains like log(x) hold, and a component of size 0.3 beside one of
    size 1e6 is not stepped by 1e4). A component with neither (zero, and no
    spread given) takes the state's scale, ``0.1 max_i |x_i|`` (0.01 for a
    state of zeros), so that it is not stepped into round-off; without
    `spread`, that scale is every component's floor. A component whose
    given spread is 0 (known exactly: its row and column of the covariance
    are 0, so the linearisation never reads its column) is not stepped,
    and its column is 0: stepped by the state's scale, a 0 beside 1e6 took
    ``exp`` past the largest float, and the filter failed (audit CC1).

    SciPy then shrinks the steps until its error estimate is within 1e-11
    of the derivative or of :math:`|f_i(x)| / s_j` (:math:`s_j` the
    component's scale; 1 for an output that is 0 at x): the derivative
    that would move the output by that fraction of itself over the
    component's scale. f is differentiated with steps in units of each
    component's scale and outputs in units of their size at x, where both
    tolerances are one number. The second matters for a derivative that is
    0 (an output that does not depend on a component): its estimates are
    round-off, which a relative test never accepts and which grows as the
    steps shrink, up to 1e-3 of the row's largest derivative after SciPy's
    10 iterations. Where an estimate has not converged and its error is
    beyond 1e-3 of its row's largest derivative, f is not smooth on that
    scale (a range to a beacon 10 m away, stepped from 6.4e6 m): that is a
    ModelFunctionError, not a slope to linearise with.
    """
    from scipy.differentiate import jacobian as scipy_jacobian

    n = x.shape[0]
    because = size_reason(name, size)

    def stacked(xi: np.ndarray) -> np.ndarray:
        # scipy passes shape (n, ...) and expects (size, ...).
        flat = xi.reshape(n, -1).T
        if vectorized:
            out = call_checked(name, fn, flat, args, (flat.shape[0], size), because)
        else:
            out = call_each(name, fn, flat, args, size)
        return out.T.reshape(size, *xi.shape[1:])

    scale = _scales(x, spread)
    stepped = scale if spread is None else np.where(spread > 0, scale, 0.0)  # (see above: 0 for a known component)
    at_x = stacked(x[:, None])[:, 0]
    value = np.abs(at_x)
    unit = np.where(value > _TINY_OUTPUT, value, 1.0)
    turning = angles is not None and angles.any()

    def scaled(u: np.ndarray) -> np.ndarray:
        # f at x + scale ⊙ u (angles within π of their value at x), divided by each output's size at x.
        shape = (n,) + (1,) * (u.ndim - 1)
        out = stacked(x.reshape(shape) + stepped.reshape(shape) * u)
        if turning:
            base = at_x[angles].reshape((-1,) + shape[1:])
            out[angles] = base + wrap_angle(out[angles] - base)
        return out / unit.reshape((size,) + shape[1:])

    res = scipy_jacobian(scaled, np.zeros(n), initial_step=0.1, tolerances=dict(rtol=1e-11, atol=1e-11))
    df = np.asarray(res.df).reshape(size, n)
    J = df * unit[:, None] / scale
    if not np.all(np.isfinite(J)):
        raise ModelFunctionError(f"the Jacobian of `{name}` could not be computed at x = {x}.")
    # SciPy stops after its iterations whether or not its error estimate met the tolerance; an estimate
    # beyond 1e-3 of the row's largest derivative (in these units) is not a derivative to linearise with.
    error = np.asarray(res.error).reshape(size, n)
    rows = np.maximum(np.abs(df).max(axis=1, keepdims=True), 1.0)
    if np.any(~np.asarray(res.success).reshape(size, n) & ~(error <= 1e-3 * rows)):
        raise ModelFunctionError(
            f"the finite-difference Jacobian of `{name}` did not converge at x = {x} (its error estimate is "
            f"{float(np.max(error / rows)):.2g} of the derivatives): `{name}` is not smooth on the scale of the "
            f"belief there. Pass `{name}_jacobian` (analytic), or write `{name}` with functions that take "
            "complex input (not np.linalg.norm or math.hypot: np.sqrt of a sum of squares), for exact derivatives.")
    return J


_FULL_CHECKS = 3
"""How many of a function's first complex-step Jacobians :class:`Taylor` checks row by row."""


class Taylor:
    """First-order Taylor linearisation of a NonlinearModel (the EKF's).

    Parameters
    ----------
    model : NonlinearModel
    us : ndarray of shape (T, p), optional
        Controls, passed to f as ``f(x, u_k)``.
    """

    def __init__(self, model, us: np.ndarray | None = None) -> None:
        self.model, self.us = model, us
        self.checks: dict[str, int] = {}
        """For "f" and "h": how many of their first complex-step Jacobians passed the check of every row, or -1
        once one failed a check or was refused (an online filter's strategies for one call share it)."""

    def _affine(self, name, fn, jac, x, spread, args, size, vectorized):
        y = (self.model.transition(x, *args) if name == "f" else self.model.measurement(x))
        if jac is not None:
            A = call_checked(f"{name}_jacobian", jac, x, args, (size, x.shape[0]),
                             size_reason(f"{name}_jacobian", size, x.shape[0]))
        else:
            A = self._jacobian(name, fn, x, args, size, vectorized, spread)
        return A, y - A @ x

    def _jacobian(self, name, fn, x, args, size, vectorized, spread):
        # The first few Jacobians of f (or h) check every row of the complex step against differences
        # (:func:`jacobian`): a function that fails is differenced from then on, and after them only faint rows
        # are checked. A norm inside f drops the imaginary part at every x, but the first x may hide it (|v| at
        # v = 0), and checking every row costs 4 n to 12 n more calls of f.
        passed = self.checks.get(name, 0)
        if passed >= 0:
            try:
                A = complex_step_jacobian(name, fn, x, args, size, vectorized, spread,
                                          "faint" if passed >= _FULL_CHECKS else "all")
                self.checks[name] = min(passed + 1, _FULL_CHECKS)
                return A
            except _RejectsComplex:
                self.checks[name] = -1  # (after the full checks too: review R29)
        angles = self.model.state_angles if name == "f" else self.model.measurement_angles
        return finite_difference_jacobian(name, fn, x, args, size, vectorized, spread, angles)

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray | None):
        """``(A, b, Q)`` with A the Jacobian of f at `mean` (`cov`, if given, only scales finite differences)."""
        return self._transition(k, mean, _deviations(cov))

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray | None):
        """``(H, d, R)`` with H the Jacobian of h at `mean` (`cov` as for :meth:`transition`)."""
        return self._measurement(k, mean, _deviations(cov))

    def transition_sqrt(self, k: int, mean: np.ndarray, factor: np.ndarray, factors):
        """kalman.transition_factors' ``(A, b, L_Q, None)``, finite differences scaled by the rows of `factor`."""
        A, b, Q = self._transition(k, mean, np.linalg.norm(factor, axis=1))
        return A, b, factors("Q", Q), None

    def measurement_sqrt(self, k: int, mean: np.ndarray, factor: np.ndarray, factors):
        """kalman.measurement_factors' ``(H, d, L_R, None)`` (see :meth:`transition_sqrt`)."""
        H, d, R = self._measurement(k, mean, np.linalg.norm(factor, axis=1))
        return H, d, factors("R", R), None

    def _transition(self, k: int, mean: np.ndarray, spread: np.ndarray | None):
        m = self.model
        args = () if self.us is None else (self.us[k],)
        A, b = self._affine("f", m.f, m.f_jacobian, mean, spread, args, m.n, m.vectorized)
        return A, b, m.noise(k)[0]

    def _measurement(self, k: int, mean: np.ndarray, spread: np.ndarray | None):
        m = self.model
        H, d = self._affine("h", m.h, m.h_jacobian, mean, spread, (), m.m, m.vectorized)
        return H, d, m.noise(k)[1]


def _deviations(cov: np.ndarray | None) -> np.ndarray | None:
    """The standard deviations of a belief's components, or None without its covariance."""
    return None if cov is None else marginal_std(cov)

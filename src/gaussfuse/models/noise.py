r"""Discretisation of continuous-time linear models: white-noise accelerations and Van Loan.

A continuous-time linear stochastic differential equation

.. math::

    dx = A x \, dt + L \, d\beta, \qquad E[d\beta \, d\beta^T] = Q_c \, dt,

observed at intervals :math:`\Delta t` is, exactly, the discrete model
:math:`x_k = F x_{k-1} + w_k`, :math:`w_k \sim N(0, Q)` with

.. math::

    F = e^{A \Delta t}, \qquad
    Q = \int_0^{\Delta t} e^{A s} L Q_c L^T e^{A^T s} \, ds .

:func:`van_loan` computes both for any (A, L, Qc);
:func:`continuous_white_noise` is the closed form for a chain of integrators
(random walk, constant velocity, constant acceleration, ...) and
:func:`piecewise_white_noise` the "piecewise constant" alternative in which
the highest derivative is held constant over each step.
"""

from __future__ import annotations

from functools import lru_cache
from math import ceil, factorial, log2

import numpy as np

from .._linalg import symmetrize
from .._validation import as_matrix, check_psd, finite_step, integer, real

__all__ = ["van_loan", "continuous_white_noise", "piecewise_white_noise"]


def sde_arrays(A, L, Qc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate the drift A (n, n), the noise gain L (n, s) and the noise density Qc (s, s)."""
    A = as_matrix("A", A, None, None, row_name="n", time_varying=False)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"`A` must be square, of shape (n, n); got shape {A.shape}.")
    n = A.shape[0]
    L = as_matrix("L", L, n, None, column_vector_ok=True, col_name="s", time_varying=False)
    s = L.shape[1]
    Qc = check_psd("Qc", as_matrix("Qc", Qc, s, s, time_varying=False))
    return A, L, Qc


@finite_step("Q")
def van_loan(A, L, Qc, dt: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Exact discretisation of a linear SDE over a time step (Van Loan's method).

    Parameters
    ----------
    A : array_like of shape (n, n)
        Drift matrix of :math:`dx = A x\,dt + L\,d\beta`.
    L : array_like of shape (n, s)
        Noise gain; a 1-D array of length n is a single column.
    Qc : array_like of shape (s, s)
        Spectral density (diffusion) of the Brownian motion β,
        :math:`E[d\beta\,d\beta^T] = Q_c\,dt`; symmetric positive
        semi-definite; a scalar when s = 1.
    dt : float
        Time step, > 0.

    Returns
    -------
    F : ndarray of shape (n, n)
        Transition matrix :math:`e^{A \Delta t}`.
    Q : ndarray of shape (n, n)
        Process-noise covariance, symmetric positive semi-definite.

    Notes
    -----
    With :math:`W = L Q_c L^T`, the matrix exponential [1]_

    .. math::

        \exp\left(\begin{bmatrix} -A & W \\ 0 & A^T \end{bmatrix} h\right)
        = \begin{bmatrix} \cdot & G \\ 0 & \Phi_h^T \end{bmatrix}
        \quad\text{gives}\quad
        F_h = \Phi_h = e^{A h}, \qquad Q_h = \Phi_h G ,

    and it is computed here by the power series of both integrals over a
    step :math:`h = \Delta t / 2^j` with :math:`\alpha h \le 1/2`, where
    :math:`\alpha = \min_{p < 9} \max(d_p, d_{p+1})`,
    :math:`d_p = \|A^p\|_1^{1/p}` [2]_ (at most :math:`\|A\|_1`; 0 where
    :math:`A^p = 0` for a p up to 9, as for a chain of up to 8 integrators,
    whose series end):

    .. math::

        F_h = \sum_{N \ge 0} \frac{(A h)^N}{N!}, \qquad
        Q_h = \sum_{N \ge 0} \frac{h^{N+1}}{(N+1)!} T_N, \quad
        T_0 = W, \quad T_{N+1} = A T_N + T_N A^T,

    each summed until every entry has converged (a chain of integrators ends
    exactly), then doubled j times with the exact rule
    :math:`F_{2h} = F_h^2`, :math:`Q_{2h} = F_h Q_h F_h^T + Q_h`. A matrix
    exponential of the block matrix (``scipy.linalg.expm``) is accurate only
    relative to its norm: a large W (a density in small units) spoiled F, and
    the small entries of Q over a short step (position variances growing
    like :math:`h^7` under white jerk) lost all their digits. The series
    keeps each entry to its own round-off; Q is linear in W and F does not
    depend on it. That holds for drifts that are not stiff: the halvings are
    set by the fastest rate, and a mode's :math:`1 + a h` carries the
    round-off of 1, so :math:`\log F` is off by about
    :math:`\epsilon \alpha \Delta t`. Rates 1e9 and 1e-3 over 1e4 s leave
    the slow mode's F 4.5e-8 off, and rates 1e12 and 1e-4 over 1e5 s lose it
    (F = 1 for 4.5e-5, Q = 1e5 for 5000); SciPy's ``expm`` of
    :math:`A \Delta t` alone, exact on a triangular A's diagonal, is the
    better F there. A density whose :math:`W = L Q_c L^T` lies near or
    below the smallest normal float is scaled into the normal ones by a
    power of 2 and Q back (a q of 1e-320 is within 2.2e-13 where its Q
    grows to 1e107), but an entry of W below the normal floats beside a
    far larger one keeps only the digits its float has, and can lose them
    (W = diag(1, 1e-320) gives a Q that should be 1e107 as 0); and a
    subnormal W and a Q more than about 8e609 apart (W = 1e-340 grown to
    2.7e289; less for a fast rate, 3e598 at a rate of 1e11 and 5e589 at
    1e20, where the last ones computed are within 1.2e-12) are refused as
    an overflow. A fast rate before an integrator spreads the sub-step's
    entries over powers of h: :math:`W h` to :math:`W h^3` for one
    integrator, whose smallest underflow first (``A = [[0, 1], [0, -1e110]]``
    with W = 1 over 1 s gives a position variance of 0 for 1e-220, where
    its other entries are exact; :class:`~gaussfuse.models.motion.Singer`
    refuses σ·τ below 1e-150 for that reason). A coupling is not a rate: against a 700-digit
    oracle, Singer's model at :math:`\tau = \Delta t` = 1e9 s is within 2.5e-14
    (7.4e-9 when the halvings were set by :math:`\|A\|_1`, which counts
    each integrator's 1), and the triangular drift in mixed units
    ``[[-1e-3, 1e6], [0, -2e-3]]`` over 1e3 s within 3.6e-15 (1.5e-8).

    References
    ----------
    .. [1] C. F. Van Loan, "Computing integrals involving the matrix
       exponential", IEEE Trans. Automatic Control 23(3), 1978.
    .. [2] A. H. Al-Mohy and N. J. Higham, "A new scaling and squaring
       algorithm for the matrix exponential", SIAM J. Matrix Anal. Appl.
       31(3), 2009.

    Examples
    --------
    The constant-velocity model (white-noise acceleration of density q):

    >>> import numpy as np
    >>> from gaussfuse.models.noise import van_loan
    >>> F, Q = van_loan([[0, 1], [0, 0]], [0, 1], 3.0, dt=2.0)
    >>> F
    array([[1., 2.],
           [0., 1.]])
    >>> np.round(Q, 12)  # 3 * [[dt^3/3, dt^2/2], [dt^2/2, dt]]
    array([[8., 6.],
           [6., 6.]])
    """
    A, L, Qc = sde_arrays(A, L, Qc)
    dt = real("dt", dt, positive=True)
    rate = _rate(A)
    halvings = max(0, ceil(log2(rate) + log2(dt)) + 1) if rate > 0 else 0  # (rate * dt may overflow)
    h = float(np.ldexp(dt, -halvings))  # (dt / 2.0**halvings overflows for a rate dt past 2**1024)
    F = Q = None
    for a, b in _density_scales(L, Qc, h):
        La = np.ldexp(L, a)
        W = symmetrize(La @ np.ldexp(Qc, b) @ La.T)
        # the scaled tries overflowed, and unscaled, W h keeps fewer than 42 bits: W h and Q are further apart
        # than float64 holds, an overflow, not a Q of subnormal digits or 0 (reviews R23, R25, R27)
        if (a, b) == (0, 0) and Q is not None and np.max(np.abs(W)) * min(1.0, h) < 2.0**-1032:
            return F, np.full_like(W, np.inf)
        F, Q = _series(A, W, h)
        for _ in range(halvings):
            Q = symmetrize(F @ Q @ F.T + Q)
            F = F @ F
        if np.all(np.isfinite(Q)):
            break
    return F, Q if 2 * a + b == 0 else np.ldexp(Q, -(2 * a + b))


def _density_scales(L: np.ndarray, Qc: np.ndarray, h: float) -> list[tuple[int, int]]:
    """The powers of 2 (a, b) to scale L and Qc by, tried in turn until Q is finite (Q scales by 2^-(2a + b)).

    Q is linear in W = L Qc Lᵀ, and the series' first term is W h. Where W h is below 2^-1000, it has lost
    digits, or would lose them in the series, so W is taken to 2^-511 (L to about 1, Qc to the rest: neither
    overflows), or higher where h is that small, which leaves Q room to grow by about 2^1534; where it grows
    more, to the least that keeps W h at 2^-1000, then W at 2^-1000; each only where W h keeps 42 bits (at
    least 2^-1032); and last, as it is, which :func:`van_loan` refuses as an overflow where W h keeps fewer (a
    Q of lost digits, or 0, is not one). Scaling by a power of 2 is exact, and Q is rounded once on the way
    back (reviews R21-R27: a subnormal W lost 80 ulps, a scaled Q overflowed, a retry left W h subnormal or 0).
    """
    tops = [float(np.max(np.abs(M), initial=0.0)) for M in (L, Qc)]
    if min(tops) == 0.0:
        return [(0, 0)]
    eL, eQ = (int(np.frexp(top)[1]) for top in tops)
    natural = 2 * eL + eQ  # about log2 of W's largest entry, from above
    eh = min(0, int(np.frexp(h)[1]))
    least = -1000 - eh  # the least exponent of W that keeps W h at 2^-1000
    targets = sorted({t for t in (max(-511, least), least, -1000) if t + eh >= -1032}, reverse=True)  # (W at
    # 2^-1000 too, for a few steps' more growth, review R26, where W h keeps 42 bits: review R27)
    return [(-eL, target - eQ) for target in targets if natural < target] + [(0, 0)]


def _rate(A: np.ndarray) -> float:
    """:func:`_rate_of` A, remembered for the last matrices (a motion's A is discretised for step after step)."""
    return _rate_of(A.shape, A.tobytes())


@lru_cache(maxsize=64)
def _rate_of(shape: tuple, data: bytes, most: int = 9) -> float:
    r"""How fast the series of :math:`e^{Ah}` grows with h: :math:`\min_{p < 9} \max(d_p, d_{p+1})`, with
    :math:`d_p = \|A^p\|_1^{1/p}` (Al-Mohy and Higham's :math:`\alpha_p`), at most :math:`\|A\|_1`; 0 when
    a power up to the 9th is exactly 0 (a chain of up to 8 integrators), as every higher one then is.

    The powers are taken of :math:`A / \|A\|_1`, each scaled to norm 1 on the way (its size kept in
    logarithms), so that none overflows or underflows.
    """
    A = np.frombuffer(data, dtype=np.float64).reshape(shape)
    norm = float(np.max(np.sum(np.abs(A), axis=0)))
    if norm == 0.0:
        return 0.0
    B = A / norm
    power, logs = B, [0.0]  # log ||B^p||_1, p = 1, 2, ...
    for _ in range(2, most + 1):
        power = B @ power
        size = float(np.max(np.sum(np.abs(power), axis=0)))
        if size == 0.0:  # and so every higher power: d_p = d_{p+1} = 0 (review R19: the second was not formed)
            logs += [-np.inf, -np.inf]
            break
        logs.append(logs[-1] + np.log(size))
        power = power / size
    d = np.exp(np.array(logs) / np.arange(1, len(logs) + 1))
    return norm * float(min(np.maximum(d[:-1], d[1:]), default=1.0))


def _series(A: np.ndarray, W: np.ndarray, h: float, most: int = 80) -> tuple[np.ndarray, np.ndarray]:
    r""":math:`e^{A h}` and :math:`\int_0^h e^{As} W e^{A^T s} ds` by their power series (see van_loan), alpha h <= 1/2.

    Sums until the next terms change no entry (to half an ulp of it), or `most` terms.
    """
    n = A.shape[0]
    Ah = A * h
    term = np.hstack([np.eye(n), W * h])  # [(A h)^N / N!, h^{N+1} T_N / (N + 1)!], N = 0
    total = term.copy()
    for N in range(1, most):
        term[:, :n] /= N  # divided before the product: over a whole step (a chain), a product near the largest
        term[:, n:] /= N + 1  # float overflowed before its division (review R20)
        term = Ah @ term
        term[:, n:] += term[:, n:].T.copy()
        grown = total + term
        if (grown == total).all():
            break
        total = grown
    return total[:, :n], total[:, n:]


def _order(order) -> int:
    """An integrator chain's `order`, checked: an integer in [0, 170] (171! overflows float64)."""
    K = integer("order", order, minimum=0)
    if K > 170:
        raise ValueError(f"`order` must be at most 170 (the factorial of 171 overflows float64); got {K}.")
    return K


@finite_step("Q")
def continuous_white_noise(order: int, dt: float, q: float) -> np.ndarray:
    r"""Process noise of an integrator chain driven by continuous white noise, for one axis.

    Parameters
    ----------
    order : int
        K, the derivative driven by the noise: 0 for a random walk, 1 for
        constant velocity (white-noise acceleration), 2 for constant
        acceleration (white-noise jerk), ...
    dt : float
        Time step, > 0.
    q : float
        Spectral density of the white noise, >= 0.

    Returns
    -------
    ndarray of shape (K + 1, K + 1)
        Covariance of (position, velocity, ...) accumulated over `dt`.

    Notes
    -----
    The state is the position and its first K derivatives, and the K-th is
    :math:`d x^{(K)} = d\beta` with :math:`E[d\beta^2] = q\,dt`. With
    :math:`F_{ij} = \Delta t^{j-i} / (j-i)!`, the integral
    :math:`\int_0^{\Delta t} e^{As} L q L^T e^{A^T s} ds` is

    .. math::

        Q_{ij} = q \, \frac{\Delta t^{2K+1-i-j}}{(2K+1-i-j)\,(K-i)!\,(K-j)!},
        \qquad i, j = 0, \dots, K.

    Examples
    --------
    >>> from gaussfuse.models.noise import continuous_white_noise
    >>> continuous_white_noise(1, dt=2.0, q=3.0)
    array([[8., 6.],
           [6., 6.]])
    """
    K = _order(order)
    dt = real("dt", dt, positive=True)
    q = real("q", q, nonnegative=True)
    return white_noise_chains(K, np.array([dt]), q)[0]


def white_noise_chains(K: int, dts: np.ndarray, q: float) -> np.ndarray:
    """:func:`continuous_white_noise` of checked arguments for each step of `dts` (k,): (k, K + 1, K + 1), inf
    where it overflows."""
    idx = np.arange(K + 1)
    i, j = np.meshgrid(idx, idx, indexing="ij")
    power = 2 * K + 1 - i - j
    fm, fe = _FACTORIALS[0][K - i] * _FACTORIALS[0][K - j], _FACTORIALS[1][K - i] + _FACTORIALS[1][K - j]
    mq, eq = np.frexp(q)
    md, ed = np.frexp(dts[:, None, None])
    with np.errstate(over="ignore", under="ignore"):  # (an overflow is the caller's to name)
        return np.ldexp(mq * md**power / power / fm, eq + ed * power - fe)


_FACTORIALS = (np.array([factorial(k) / (1 << factorial(k).bit_length()) for k in range(172)]),
               np.array([factorial(k).bit_length() for k in range(172)]))
"""0! .. 171! as mantissas in [0.5, 1] and powers of 2 (171! overflows float64, but not its mantissa; Python
divides integers correctly rounded).

The noise matrices are products of powers of dt, factorials and an
intensity, whose factors overflow or underflow where the product need
not (dt^p for q = 1e-300, dt = 1e110; the two factorials' product past
order 98): they are multiplied as mantissas, and their powers of 2 added
(``numpy.frexp``, ``numpy.ldexp``), so an entry is rounded a few times, to
a few ulps, at any scale. (The logarithm of an entry, exponentiated, was
off by 1e-13 at q = 1e300: audit BB1.) The products are written so that
Q[i, j] and Q[j, i] are computed alike: Q is exactly symmetric.
"""


@finite_step("Q")
def piecewise_white_noise(order: int, dt: float, var: float) -> np.ndarray:
    r"""Process noise of an integrator chain whose (K+1)-th derivative jumps once per step, for one axis.

    Parameters
    ----------
    order : int
        K, the highest derivative in the state (1 for a constant-velocity
        model: position and velocity). The next derivative (the
        acceleration, for constant velocity) is constant over each step,
        with independent values of variance `var` from step to step.
    dt : float
        Time step, > 0.
    var : float
        Variance of the per-step value of that derivative, >= 0.

    Returns
    -------
    ndarray of shape (K + 1, K + 1)
        :math:`\mathrm{var} \cdot g g^T`.

    Notes
    -----
    A constant (K+1)-th derivative a over the step moves the i-th derivative
    (i = 0 the position) by :math:`g_i a` with

    .. math::

        g_i = \frac{\Delta t^{K+1-i}}{(K+1-i)!}, \qquad Q = \mathrm{var}\; g g^T,

    so :math:`g = [\Delta t^2/2, \Delta t]` for constant velocity. Q has
    rank one. For K >= 2 this differs from the discrete Wiener process
    acceleration model of Bar-Shalom et al. (filterpy's
    ``Q_discrete_white_noise(3)``), whose acceleration takes a random step
    each step, :math:`g = [\Delta t^2/2, \Delta t, 1]`; the two agree for
    constant velocity.

    Examples
    --------
    >>> from gaussfuse.models.noise import piecewise_white_noise
    >>> piecewise_white_noise(1, dt=2.0, var=0.5)
    array([[2., 2.],
           [2., 2.]])
    """
    K = _order(order)
    dt = real("dt", dt, positive=True)
    var = real("var", var, nonnegative=True)
    power = K + 1 - np.arange(K + 1)  # g_i = dt^power_i / power_i!, as mantissa and power of 2 (_FACTORIALS)
    md, ed = np.frexp(dt)
    mg, eg = md**power / _FACTORIALS[0][power], ed * power - _FACTORIALS[1][power]
    mv, ev = np.frexp(var)
    with np.errstate(over="ignore", under="ignore"):  # (an overflow is finite_step's to name)
        return np.ldexp(mv * np.outer(mg, mg), ev + eg[:, None] + eg[None, :])

r"""Linear algebra for covariances: the one home of matrix factorisations.

Every covariance that gaussfuse inverts is factorised here, by Cholesky, and
used through its factor :math:`L` (:math:`C = L L^\top`): a solve is two
triangular solves, never an explicit inverse; a quadratic form is the squared
norm of a whitened vector :math:`L^{-1} x`; a log-determinant is
:math:`2 \sum \log L_{ii}`. Functions take a single matrix or a stack of them
(a leading axis), as NumPy's do.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "LOG_2PI", "marginal_std", "symmetrize", "eye", "cholesky", "is_positive_definite", "semidefinite_cholesky", "cho_solve",
    "psd_solve", "sqrt_cov", "tria", "pivot_order", "in_pivot_order", "downdate", "zero_pivots", "factor_solve", "back_solve", "weighted_mean", "circular_mean", "whiten", "log_density", "log_det",
    "observed_gram", "step_cholesky", "shown", "wrap_angle", "wrap_components", "near", "unresolved", "negative_weight", "indefinite_error", "weighed", "factorable", "indefinite", "unseen_directions", "with_slopes",
]

LOG_2PI = float(np.log(2.0 * np.pi))

try:  # NumPy's LAPACK gufuncs, without the Python wrapper of np.linalg (a fifth of its cost on small matrices)
    from numpy.linalg._umath_linalg import cholesky_lo as _potrf, solve as _gesv, solve1 as _gesv1
except ImportError:  # pragma: no cover - every NumPy since 1.8 has them
    _potrf = _gesv = _gesv1 = None


def marginal_std(cov: np.ndarray) -> np.ndarray:
    """The standard deviations on a covariance's diagonal (a stack too), a variance of -0 to round-off as 0.

    A variance that is 0 in exact arithmetic can come out of a product of
    covariances as -1e-18: its standard deviation is 0, not NaN.
    """
    return np.sqrt(np.maximum(np.diagonal(cov, axis1=-2, axis2=-1), 0.0))


def symmetrize(cov: np.ndarray) -> np.ndarray:
    """``P / 2 + Pᵀ / 2``: removes round-off asymmetry (a stack too).

    Halving first is exact (bar the last bit of a subnormal number), so
    this is ``(P + Pᵀ) / 2`` without the overflow of ``P + Pᵀ`` for entries
    above half the largest float: a variance of 1e308 stays finite.
    """
    half = 0.5 * cov
    return half + half.swapaxes(-1, -2)


def clip_variances(cov: np.ndarray, magnitude, zero: bool = False) -> np.ndarray:
    """`cov` (..., n, n) with the row and column of each variance that is zero to round-off, but below 0, set to 0.

    `cov` is a sum of congruences, ``A X Aᵀ + Y`` (the prediction, both
    terms of the Joseph form, the RTS step), which gives variances of at
    least 0 in exact arithmetic; ``magnitude()`` gives the diagonal t
    (..., n) of the same sum of the terms' absolute values,
    ``|A| |X| |A|ᵀ + |Y|``, on which each entry's round-off is at most about
    ``n ε √(t_i t_j)``. A row j whose entries are all within
    ``16 n ε √(t_i t_j)`` of 0, with ``cov[j, j] < 0``, is a zero variance
    (a state measured exactly through a singular R came out at -2e-17, and
    a smoother's gains of 14 magnified such a -1e-18 step by step), and a
    component of zero variance has zero covariances; left negative, the
    result was refused as a prior, by ``forecast`` and by
    ``sample_posterior``. A variance further below 0 than its own terms'
    round-off (a sigma-point rule's negative weight) is kept, for the checks
    that name it. `magnitude` is called only where a variance is negative
    (with `zero`, also where one is 0: its covariances of round-off are
    then set to 0 too).
    """
    d = np.diagonal(cov, axis1=-2, axis2=-1)
    low = d <= 0.0 if zero else d < 0.0
    if not low.any() or not np.isfinite(cov).all():  # an overflow is not hidden
        return cov
    root = np.sqrt(magnitude())
    quiet = (np.abs(cov) <= 16 * d.shape[-1] * _EPS * root[..., :, None] * root[..., None, :]).all(axis=-1)
    keep = ~(low & quiet)
    if keep.all():
        return cov
    return np.where(keep[..., :, None] & keep[..., None, :], cov, 0.0)


def abs_congruence_diagonal(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """The diagonal of ``|A| |X| |A|ᵀ`` (stacks broadcast): the size of the terms of ``A X Aᵀ`` (:func:`clip_variances`)."""
    A = np.abs(A)
    return np.einsum("...ij,...jk,...ik->...i", A, np.abs(X), A)


PSD_RTOL = 1e-9
"""How far a covariance may miss being positive semi-definite on its components' own scales (its correlation
matrix's eigenvalues, a factor's residual) and still be one: round-off in a matrix computed from others."""


def unit_diagonal(mat: np.ndarray) -> np.ndarray:
    r"""`mat` (a stack too) on its diagonal's scale, :math:`D^{-1/2} M D^{-1/2}` with D its diagonal (divided
    twice: the product of two scales may overflow); a row and column whose diagonal entry is not positive are
    left as they are. The correlation matrix of a covariance; an information matrix whose eigenvalues no longer
    span its components' units."""
    diag = np.diagonal(mat, axis1=-2, axis2=-1)
    scale = np.sqrt(np.where(diag > 0.0, diag, 1.0))
    return mat / scale[..., :, None] / scale[..., None, :]


def correlation_root(cov: np.ndarray) -> np.ndarray:
    r"""A lower-triangular L with :math:`L L^\top` = `cov` to round-off on each component's own scale.

    With :math:`D = \mathrm{diag}(\sqrt{c_{ii}})` and the correlation
    matrix :math:`C = D^{-1} c D^{-1} = V \Lambda V^\top`, the root is
    :math:`D V \Lambda_+^{1/2}` (negative eigenvalues, of round-off, taken as
    0), made triangular by :func:`tria`; components of zero variance have
    zero rows. Unlike the semi-definite Cholesky factorisation, whose pivot
    after a nearly dependent leading block carries that block's conditioning,
    its error does not grow with how nearly the components depend on each
    other (a rank-2 ``G Gᵀ`` of 3 × 3 left a pivot of -1.2e-13 for 0, 56 ε
    of its variance).
    """
    n = cov.shape[0]
    d = np.sqrt(np.maximum(np.diagonal(cov), 0.0))
    live = np.flatnonzero(d > 0.0)
    L = np.zeros((n, n))
    if live.size:
        C = cov[np.ix_(live, live)] / d[live, None] / d[None, live]
        vals, vecs = np.linalg.eigh(symmetrize(C))
        L[np.ix_(live, live)] = tria(d[live, None] * vecs * np.sqrt(np.maximum(vals, 0.0)))
    return L


_MADE: dict[tuple, np.ndarray] = {}


def _made_once(key: tuple, make) -> np.ndarray:
    """``make()``, read-only, made once for each `key` (constants that filter steps need every time)."""
    out = _MADE.get(key)
    if out is None:
        out = _MADE[key] = make()
        out.setflags(write=False)
    return out


def eye(n: int) -> np.ndarray:
    """The n × n identity, read-only and made once (a filter step needs it every time)."""
    return _made_once(("eye", n), lambda: np.eye(n))


def cholesky(mat: np.ndarray, name: str = "the matrix", resolved: bool = False) -> np.ndarray:
    r"""Lower Cholesky factor of `mat` (or of each of a stack).

    With `resolved`, a pivot of round-off counts as zero
    (:func:`roundoff_pivot`, the test of :func:`sqrt_cov` and
    :func:`semidefinite_cholesky`). There the factorisation of a matrix that is singular
    in exact arithmetic can succeed or fail by one rounding, and a pivot
    that just succeeds is about √ε of its row with no digit right: whatever
    is solved with it is round-off divided by round-off.

    Raises
    ------
    numpy.linalg.LinAlgError
        When `mat` is not positive definite (with `resolved`, to round-off);
        the message names `name` and shows the matrix, so that a driver can
        prefix the time step.

    Notes
    -----
    LAPACK's ``potrf`` through NumPy's gufunc, which leaves NaN where the
    factorisation fails (the wrapper ``np.linalg.cholesky`` costs five times
    as much on the small matrices of a filter step).
    """
    if not mat.shape[-1]:  # no measurement: nothing to factorise (audit OO3: LAPACK's corner was indexed)
        return np.zeros(mat.shape)
    if _potrf is None:
        try:
            L = np.linalg.cholesky(mat)
            if not resolved or not roundoff_pivot(L, mat):
                return L
        except np.linalg.LinAlgError:
            pass
    else:
        with np.errstate(invalid="ignore"):
            L = _potrf(mat)
        corner = L[-1, -1] if L.ndim == 2 else L[..., -1, -1]
        if corner.ndim == 0 and corner == corner or corner.ndim and (corner == corner).all():
            if not resolved or not roundoff_pivot(L, mat):
                return L  # (NaN marks a failed factorisation)
    raise np.linalg.LinAlgError(f"{name} is not positive definite, so it cannot be factorised: {shown(mat)}")


def shown(mat) -> str:
    """A matrix as an error message shows it: on one line, to 4 digits, elided past 144 entries (12 × 12; at 36, a
    7 × 7 Q's one bad entry was elided from the message that blamed it: review R46)."""
    with np.printoptions(precision=4, threshold=144):
        return np.array2string(np.asarray(mat), separator=", ").replace("\n", "")


def roundoff_pivot(L: np.ndarray, mat: np.ndarray) -> bool:
    r"""Whether a Cholesky factor L of `mat` has a pivot of round-off: :math:`L_{jj}^2 \le 2 (j + 1) \epsilon\, \mathrm{mat}_{jj}`.

    The pivot squared is the variance of component j left after the j
    earlier ones, :math:`\mathrm{mat}_{jj} - \sum_{k<j} L_{jk}^2`: a sum of
    j + 1 terms of size at most :math:`\mathrm{mat}_{jj}`, whose rounding
    error is at most about :math:`(j + 1) \epsilon\, \mathrm{mat}_{jj}`
    (twice that, for the error already in the :math:`L_{jk}`). The bound
    grows with j, not with the size of the matrix: a pair of nearly
    dependent components is judged alike among 2 or 64. On Python floats:
    on the few entries of a diagonal they cost a fifth of NumPy's calls,
    and a product that would overflow is inf, with no warning.
    """
    if L.ndim > 2:  # (a loop over a stack cost 1 s per 1e5 matrices: review R47)
        j = np.arange(1, L.shape[-1] + 1)
        with np.errstate(over="ignore"):
            pivots = np.diagonal(L, axis1=-2, axis2=-1) ** 2
        return bool((pivots <= 2 * j * _EPS * np.diagonal(mat, axis1=-2, axis2=-1)).any())
    return any(p * p <= _roundoff(j, v) for j, (p, v) in enumerate(zip(L.diagonal().tolist(), mat.diagonal().tolist())))


def _roundoff(j: int, variance: float) -> float:
    """The round-off of pivot j's square in a Cholesky factor, beside that component's `variance` (see roundoff_pivot)."""
    return 2 * (j + 1) * _EPS * variance


def is_positive_definite(mat: np.ndarray) -> bool:
    """Whether `mat` (each of a stack) has a (finite) Cholesky factor."""
    if not np.isfinite(mat).all():  # numpy's Cholesky of [[inf, 1], [1, 2]] succeeds, with nan in its factor
        return False
    try:
        cholesky(mat)
    except np.linalg.LinAlgError:
        return False
    return True


def semidefinite_cholesky(cov: np.ndarray) -> np.ndarray:
    r"""Lower-triangular L with ``L Lᵀ = cov`` for a positive semi-definite `cov`.

    The Cholesky recursion, column by column, in which a pivot (the variance
    of component j left after conditioning on components 0..j-1) at most
    ``2 (j + 1) ε cov[j, j]`` (:func:`roundoff_pivot`) is zero: component j is, to round-off, an affine
    function of the earlier ones, and column j of L is zero. The test is
    relative to each component's own variance, so it does not depend on
    units.

    Where ``numpy.linalg.cholesky`` just succeeds or just fails (a pivot at
    round-off level, of either sign), the two factors differ only in that
    column, by about the square root of the round-off: sigma points drawn
    from either agree to second order. (A root from the eigendecomposition
    would turn every point.) For a positive definite `cov` it is the
    Cholesky factor.

    Raises
    ------
    numpy.linalg.LinAlgError
        When `cov` has an eigenvalue below ``-1e-9 λ_max``: it is not
        positive semi-definite.
    """
    vals = np.linalg.eigvalsh(cov)
    top = max(vals[-1], 0.0)
    if vals[0] < -1e-9 * max(top, 1e-300):
        raise np.linalg.LinAlgError(
            f"the covariance is not positive semi-definite (smallest eigenvalue {vals[0]:.3g}), "
            "so it has no square root"
        )
    n = cov.shape[0]
    L = np.zeros_like(cov, dtype=np.float64)
    for j in range(n):
        pivot = cov[j, j] - L[j, :j] @ L[j, :j]
        if pivot <= _roundoff(j, cov[j, j]):
            continue
        L[j, j] = np.sqrt(pivot)
        L[j + 1:, j] = (cov[j + 1:, j] - L[j + 1:, :j] @ L[j, :j]) / L[j, j]
    return L


_EPS = float(np.finfo(np.float64).eps)
UNRESOLVED = 8 * _EPS
"""A standard deviation at most this times the mean's size is below what sigma points resolve (:func:`sqrt_cov`)."""


def sqrt_cov(cov: np.ndarray, mean: np.ndarray | None = None, name: str = "the covariance",
             weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The square root that draws sigma points: lower-triangular ``L Lᵀ = cov``, and its nonzero columns.

    Cholesky when `cov` is positive definite, else :func:`semidefinite_cholesky`,
    which also takes over where Cholesky succeeds with a pivot of round-off
    (at most ``2 (j + 1) ε cov[j, j]``, :func:`roundoff_pivot`): an exactly singular matrix in
    exact arithmetic, such as ``g gᵀ``, otherwise gets a factor with about
    √ε of spread where it has none (1e-8 of noise in a direction it cannot
    move).
    With the belief's `mean`, a component whose standard deviation is at
    most :data:`UNRESOLVED` times its mean's size is taken as known exactly
    (its row and column of `cov` as 0): points cannot spread around such a
    mean (they round to it, or one unit in the last place off), and what
    they would measure is round-off. A sensor with zero variance leaves
    such a variance (1e-32, round-off of 0), with round-off correlations
    that, divided by its square root, made the regression's slope 1e16.
    `name` says what `cov` is in the error when it is not positive
    semi-definite; with the sigma-point rule's covariance `weights`, the
    error says when one is negative, which can make a regression's
    residual spread, and the covariances it adds to, indefinite.

    Returns
    -------
    L : ndarray of shape (n, n)
    keep : ndarray of bool, shape (n,)
        The columns of L that are not zero.
    """
    if mean is not None:
        flat = unresolved(cov.diagonal().tolist(), mean)
        if flat:
            cov = cov.copy()
            cov[flat], cov[:, flat] = 0.0, 0.0
    try:
        L = cholesky(cov, resolved=True)  # a pivot of round-off: semidefinite_cholesky's zero, not √ε of noise
    except np.linalg.LinAlgError:
        try:
            L = semidefinite_cholesky(cov)
        except np.linalg.LinAlgError as exc:  # named: which covariance the points are drawn from, say
            raise np.linalg.LinAlgError(str(exc).replace("the covariance", name, 1) + negative_weight(weights)) from None
        return L, np.diag(L) > 0.0
    return L, _made_once(("every", cov.shape[0]), lambda: np.ones(cov.shape[0], dtype=bool))


def indefinite_error(message: str, S: np.ndarray, singular: str, negative: str) -> np.linalg.LinAlgError:
    """The LinAlgError for a matrix `S` that has no Cholesky factor: `message`, then why, `negative` when S is
    indefinite (a negative variance, or an eigenvalue below round-off on the components' own scales: review R15)
    and `singular` when it is singular to round-off. The error's ``.indefinite`` says which, for
    :func:`weighed`: a negative sigma-point weight can make S indefinite, not singular."""
    flag = bool(np.isfinite(S).all() and ((np.diagonal(S) < 0.0).any() or indefinite(unit_diagonal(S)[None])[0]))
    exc = np.linalg.LinAlgError(f"{message} {negative if flag else singular}")
    exc.indefinite = flag
    return exc


def weighed(exc: Exception, weights: np.ndarray | None) -> Exception:
    """`exc`, or, for an :func:`indefinite_error` of a sigma-point rule whose covariance `weights` has a negative
    one, the same error naming that weight as its likely cause (audit Z4: the innovation covariance's error
    blamed S = H P Hᵀ + R and advised a larger R; a singular S is not a weight's doing: review R14)."""
    hint = negative_weight(weights) if getattr(exc, "indefinite", False) else ""
    return type(exc)(f"{exc}{hint}") if hint else exc


def negative_weight(weights: np.ndarray | None) -> str:
    """What to add to the error of a covariance that is not positive semi-definite, when a sigma-point rule's
    covariance `weights` has a negative one (or nothing)."""
    if weights is None or weights.min() >= 0.0:
        return ""
    return (f". The rule weighs a point negatively ({weights.min():.3g}), so a regression's residual spread, and a "
            f"covariance it adds to, can be indefinite: {_POSITIVE_RULES}")


_POSITIVE_RULES = ("the unscented rule's weights are all positive with alpha = 1 and kappa >= 0 (its default, 3 - n, "
                   "is negative past three states), and the cubature rule's always are (method='ckf')")


def factorable(mats: np.ndarray) -> np.ndarray:
    """Which matrices of a stack (k, n, n) have a Cholesky factor, as a bool array (k,)."""
    if not mats.shape[-1]:
        return np.ones(mats.shape[0], dtype=bool)
    if _potrf is None:
        return np.array([is_positive_definite(M) for M in mats], dtype=bool)
    with np.errstate(invalid="ignore"):
        return ~np.isnan(_potrf(mats)[:, -1, -1])  # (NaN marks a failed factorisation)


def indefinite(covs: np.ndarray) -> np.ndarray:
    """Which matrices of a stack (..., n, n) are not positive semi-definite: an eigenvalue below ``-1e-9 λ_max``
    (:func:`semidefinite_cholesky`'s test), as a bool array (...).

    Only those without a Cholesky factor are decomposed: the test costs a
    Cholesky factorisation of each where all are positive definite.
    """
    flat = covs.reshape(-1, *covs.shape[-2:])
    bad = np.zeros(flat.shape[0], dtype=bool)
    doubt = ~factorable(flat)
    if doubt.any():
        vals = np.linalg.eigvalsh(flat[doubt])
        bad[doubt] = vals[:, 0] < -1e-9 * np.maximum(vals[:, -1], 1e-300)
    return bad.reshape(covs.shape[:-2])


def unresolved(variances: list[float], mean: np.ndarray) -> list[int]:
    """The components whose standard deviation is at most :data:`UNRESOLVED` times their mean's size.

    On Python floats: on the few entries of a diagonal they cost a fifth of
    NumPy's calls, and ``t * t`` is inf, with no warning, where it would
    overflow (for a mean past 1e168 every spread is unresolved).
    """
    spreads = [UNRESOLVED * m for m in mean.tolist()]
    return [j for j, (v, t) in enumerate(zip(variances, spreads)) if v <= t * t]


def unseen_directions(mean: np.ndarray, cov: np.ndarray, scale: np.ndarray) -> np.ndarray | None:
    r"""The projector onto the directions in which a belief has no spread, as a regression at it sees them.

    A regression at a belief (the points of :func:`sqrt_cov`'s factor L)
    sees a function's slope only along the range of L: not along a
    component known exactly, nor along a combination of components (after
    a sensor of :math:`x_0 + x_2` with zero variance the posterior has no
    spread along that sum, though every component has some). For a sensor
    with zero variance, that slope applied to a belief with spread leaves
    :math:`S = H P H^\top + R` singular, or wrong. A caller that linearised
    with spread there before passes that slope to :func:`with_slopes`.

    Parameters
    ----------
    mean : array of shape (n,)
    cov : array of shape (n, n)
        The belief the regression is made at.
    scale : array of shape (n,)
        Standard deviations of a belief with spread (the prediction's): the
        directions are orthogonal to the range of L in these units, so that
        they do not depend on the components' own.

    Returns
    -------
    array of shape (n, n), or None where the belief has spread in every direction
        :math:`M = D N N^\top D^{-1}`, with N an orthonormal basis of the
        complement of the range of :math:`D^{-1} L` and
        :math:`D = \operatorname{diag}(scale)` (1 where a scale is 0):
        :math:`M L = 0`, and M is the identity on :math:`D N`.
    """
    L, keep = sqrt_cov(cov, mean)
    if keep.all():
        return None
    unit = np.where(scale > 0.0, scale, 1.0)
    basis = np.linalg.qr(L[:, keep] / unit[:, None], mode="complete")[0][:, int(keep.sum()):]
    return (basis * unit[:, None]) @ (basis.T / unit[None, :])


def with_slopes(H: np.ndarray, d: np.ndarray, slopes: np.ndarray, mean: np.ndarray,
                unseen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""``(H, d)`` with the slopes `slopes` along the unseen directions, H's elsewhere, still through ``H m + d`` at `mean`.

    With `unseen` the projector M of :func:`unseen_directions`,

    .. math::

        H' = H + (S - H) M, \qquad d' = d - (S - H) M m,

    so that :math:`H' L = H L` (the regression's slope where its belief
    has spread) and :math:`H' = S` on the unseen directions. For a linear
    function, H and S agree along L's range and H' is its matrix.
    """
    change = (slopes - H) @ unseen
    return H + change, d - change @ mean


def tria(M: np.ndarray) -> np.ndarray:
    r"""A lower-triangular square root of ``M Mᵀ``, from an orthogonal transformation of M.

    Parameters
    ----------
    M : ndarray of shape (n, k)
        Any matrix; its rows may be stacked factors (``[A L, L_Q]``).

    Returns
    -------
    ndarray of shape (n, n)
        L, lower triangular with a non-negative diagonal, with
        :math:`L L^\top = M M^\top`.

    Notes
    -----
    With the QR factorisation :math:`M^\top = \Theta R` (Householder, so
    :math:`\Theta` is orthogonal to round-off), :math:`M M^\top = R^\top R`
    and :math:`L = R^\top`. :math:`M M^\top` is never formed: its
    condition number is the square of M's, which is what the square-root
    filters avoid. Columns are flipped where R's diagonal is negative
    (:math:`L L^\top` is unchanged), so the factor of a positive definite
    matrix is its Cholesky factor.

    The nonzero columns of M, the rows of :math:`M^\top`, are taken in
    decreasing order of the binary exponent of their largest entry (a
    stable sort: columns of one binade keep their order; zero columns go
    last). :math:`M M^\top` does not depend on the order, and
    Householder QR of a matrix whose rows differ widely in scale is accurate
    row by row when they are sorted so [1]_ (to within a factor of 2 is
    enough). Unsorted, a prior variance 1e30 times the sensor's lost the
    sensor's information in the update's pre-array (a posterior variance of
    0.41, or 0 from 1e50, where it is 1). The exponent rather than the
    value keeps the factor of a singular :math:`M M^\top`, which is not
    unique, from hanging on round-off. Zero columns first (the zero factor
    of a noise-free Q before :math:`A L_k` in the smoother's joint array)
    made the first reflection one led by a zero, whose vector LAPACK scales
    by a reciprocal: a pivot of 1 under entries of 7e49, the velocity given
    the position after a prior of 1e100, came out as 2e34 of round-off
    (OpenBLAS 0.3.31), and the smoothed variances were 2.4% off at a prior
    of 1e30 without process noise; with them last, exact to round-off.

    References
    ----------
    .. [1] A. J. Cox and N. J. Higham, "Stability of Householder QR
       factorization for weighted least squares problems", in Numerical
       Analysis 1997, Longman, 1998, pp. 57-73.
    """
    n, k = M.shape
    big = np.max(np.abs(M), axis=0)
    nonzero = np.flatnonzero(big > 0.0)  # zero columns last (see the notes); they add nothing to M Mᵀ
    M = M[:, nonzero[np.argsort(-np.frexp(big[nonzero])[1], kind="stable")]]
    if M.shape[1] < n:
        M = np.concatenate([M, np.zeros((n, n - M.shape[1]))], axis=1)
    L = np.linalg.qr(M.T, mode="r").T
    return L * np.where(np.diagonal(L) < 0.0, -1.0, 1.0)


def pivot_order(B: np.ndarray) -> np.ndarray:
    r"""The rows of B in the order of column pivoting for the QR of :math:`B^\top`: each next row the one whose part
    orthogonal to the rows before it is largest (by binary exponent; rows of one binade in their order).

    :func:`tria` sorts the columns of its array, but Householder QR is row-wise stable only with column
    pivoting as well [1]_ (Cox and Higham): the rows of an update's pre-array, two measurements of one state
    and one of another under a prior 1e100 times their noise, triangularised in their own order, left the
    second's small remainder to turn the third's large row, and the third measurement was lost (a variance of
    1.2e68 for 1). The remainders are found by modified Gram-Schmidt, which is enough to choose the order.

    Parameters
    ----------
    B : ndarray of shape (k, c)

    Returns
    -------
    ndarray of int, shape (k,)
        The permutation of the rows.

    References
    ----------
    .. [1] A. J. Cox and N. J. Higham, "Stability of Householder QR
       factorization for weighted least squares problems", in Numerical
       Analysis 1997, Longman, 1998, pp. 57-73.
    """
    k = B.shape[0]
    order = np.arange(k)
    W = np.array(B, dtype=np.float64)
    for i in range(k - 1):  # the last one is last
        rest = W[order[i:]]
        top = np.max(np.abs(rest), axis=1)
        unit = rest / np.where(top > 0.0, top, 1.0)[:, None]
        norms = top * np.sqrt(np.einsum("ij,ij->i", unit, unit))  # without overflow or underflow
        j = int(np.argmax(np.where(norms > 0.0, np.frexp(norms)[1], -(2**31))))  # the first of the largest binade
        if j:
            order[i:] = np.concatenate([order[i + j:i + j + 1], order[i:i + j], order[i + j + 1:]])
        if norms[j] == 0.0:  # the rest are zero too
            break
        q = W[order[i]] / norms[j]
        later = order[i + 1:]
        W[later] -= np.outer(W[later] @ q, q)
    return order


def in_pivot_order(L: np.ndarray) -> bool:
    r"""Whether the rows of a lower-triangular factor came in the order :func:`pivot_order` would choose.

    Row r's part orthogonal to the rows before row i is :math:`L_{r, i:}`, so the order is that of column
    pivoting when each pivot :math:`L_{ii}` is in a binade at least as high as the rest of every later row.
    """
    k = L.shape[0]
    if k < 2:
        return True
    if k <= 8:  # a few measurements: plain floats, where NumPy's cost per call would exceed the arithmetic
        rows = L.tolist()
        for i in range(k - 1):
            for r in range(i + 1, k):
                tail = rows[r][i:]
                top = max(abs(x) for x in tail)
                if top > 0.0 and (rows[i][i] <= 0.0 or math.frexp(top * math.sqrt(sum((x / top) ** 2 for x in tail)))[1]
                                  > math.frexp(rows[i][i])[1]):
                    return False
        return True
    top = np.max(np.abs(L), axis=1)
    top = np.where(top > 0.0, top, 1.0)[:, None]
    tails = top * np.sqrt(np.cumsum(((L / top) ** 2)[:, ::-1], axis=1)[:, ::-1])  # ‖L[r, i:]‖, without overflow
    largest = np.max(np.tril(tails, -1), axis=0)[:-1]  # over the rows after each i
    pivots = np.diagonal(L)[:-1]
    return bool(np.all((largest == 0.0) | ((pivots > 0.0) & (np.frexp(largest)[1] <= np.frexp(pivots)[1]))))


def downdate(L: np.ndarray, V: np.ndarray, name: str | tuple = "the covariance") -> np.ndarray:
    r"""A lower-triangular square root of ``L Lᵀ - V Vᵀ``: Cholesky downdates by hyperbolic rotations.

    Parameters
    ----------
    L : ndarray of shape (n, n)
        Lower triangular with a non-negative diagonal (:func:`tria`).
    V : ndarray of shape (n, r)
        The columns to take away.
    name : str, or tuple of (str, int or sequence of int) pairs
        What ``L Lᵀ - V Vᵀ`` is, for the error; or, for a joint array,
        what each block of its rows is and how many it has, or which
        components they are (an update's observed measurements in their
        order, then its filtered covariance).

    Returns
    -------
    ndarray of shape (n, n)
        :math:`L'` with :math:`L' L'^\top = L L^\top - V V^\top`; a copy.

    Raises
    ------
    numpy.linalg.LinAlgError
        When ``L Lᵀ - V Vᵀ`` is not positive semi-definite.

    Notes
    -----
    For each column v, row k of the pair :math:`(L, v)` is turned by the
    hyperbolic rotation that zeroes :math:`v_k` against :math:`L_{kk}`:
    with :math:`\rho = \sqrt{L_{kk}^2 - v_k^2}`, :math:`c = \rho / L_{kk}`
    and :math:`s = v_k / L_{kk}`,

    .. math::

        L_{kk} \leftarrow \rho, \qquad
        L_{k+1:, k} \leftarrow (L_{k+1:, k} - s\, v_{k+1:}) / c, \qquad
        v_{k+1:} \leftarrow c\, v_{k+1:} - s\, L_{k+1:, k},

    the last with the new column: the "mixed" form, which is stable where
    the downdated matrix is well conditioned (Bojanczyk, Brent, Van Dooren
    and de Hoog, 1987), unlike the plain hyperbolic rotation. A component
    with :math:`v_k = 0` is left as it is, so a zero variance stays zero.

    Where :math:`L L^\top` is singular and v lies in its range, the
    rotations leave round-off in v's components along the zero pivots. So
    a :math:`v_k` at most :math:`8 n \epsilon\, \sigma_k` (:math:`\sigma_k`
    the component's standard deviation, the norm of row k of L) is taken as
    0, and the component is left as it is (a zero variance stays exactly
    zero); that changes its variance by at most :math:`(8 n \epsilon)^2
    \sigma_k^2`.

    A pivot :math:`\rho^2 \le 0` means that the result is singular in a
    direction v touches, or indefinite. The rotations cannot go on there
    (:math:`c = 0`), and a result that is singular in exact arithmetic, such
    as the joint covariance of :math:`x_{k+1} = A x_k` and :math:`x_k`
    without process noise, meets such a pivot by round-off. So the
    difference :math:`\mathrm{sym}(L L^\top - V V^\top)` is then formed and
    factored by :func:`semidefinite_cholesky`, which keeps the lower-triangular
    layout (and so the blocks a joint factor is read in) and raises, naming
    the matrix, when it is not positive semi-definite: an eigenvalue below
    :math:`-10^{-9} \lambda_{max}`. That factor has the covariance form's
    accuracy, not the rotations'.
    """
    L = np.array(L, dtype=np.float64)
    V = np.array(V, dtype=np.float64, ndmin=2)
    given = L.copy()
    floor = 8 * L.shape[0] * np.finfo(np.float64).eps
    for v in V.T.copy():
        for k in range(L.shape[0]):
            if abs(v[k]) <= floor * np.sqrt(L[k, :k + 1] @ L[k, :k + 1]):
                continue
            a = L[k, k]
            rho2 = (a - v[k]) * (a + v[k])
            if not rho2 > 0.0:
                try:
                    return semidefinite_cholesky(symmetrize(given @ given.T - V @ V.T))
                except np.linalg.LinAlgError:
                    what, j, first = _block(name, k)
                    given = "" if first else " given the components before it"
                    raise np.linalg.LinAlgError(
                        f"{what} is not positive semi-definite: taking away a negatively weighted term leaves "
                        f"component {j} a variance of {rho2:.3g}{given}. "
                        f"{_POSITIVE_RULES[0].upper()}{_POSITIVE_RULES[1:]}") from None
            rho = np.sqrt(rho2)
            c, s = rho / a, v[k] / a
            L[k, k] = rho
            L[k + 1:, k] = (L[k + 1:, k] - s * v[k + 1:]) / c
            v[k + 1:] = c * v[k + 1:] - s * L[k + 1:, k]
    return L


def _block(name: str | tuple, k: int) -> tuple[str, int, bool]:
    """The name of the block of :func:`downdate`'s `name` that row k is in, the component that row is, and whether
    it is the block's first row (a joint array's row of the filtered covariance was named as the innovation
    covariance's: audit DD5). A block's second entry is its number of rows, or the components they are."""
    if isinstance(name, str):
        return name, k, k == 0
    for what, rows in name:
        count = rows if isinstance(rows, int) else len(rows)
        if k < count:
            return what, k if isinstance(rows, int) else int(rows[k]), k == 0
        k -= count
    raise IndexError(k)


def zero_pivots(L: np.ndarray) -> np.ndarray:
    r"""Where the pivots of a lower-triangular factor are zero to round-off: :math:`L_{jj} \le 8 n \epsilon \|L_{j,:}\|`.

    :math:`\|L_{j,:}\|` is component j's standard deviation, and a factor
    from an orthogonal triangularisation (:func:`tria`) carries an error of
    about ε times it: a component that is exactly an affine function of the
    earlier ones (a copy of one, say) gets a pivot of that size, not 0. The
    test is relative to each component's own spread, so it does not depend
    on units.
    """
    return np.diagonal(L) <= 8 * L.shape[0] * np.finfo(np.float64).eps * np.linalg.norm(L, axis=1)


def factor_solve(L: np.ndarray, B: np.ndarray, zero: np.ndarray | None = None) -> np.ndarray:
    """``L⁻¹ B`` for a lower-triangular factor L: a forward solve, or least squares where L is singular.

    A factor with a zero pivot (:func:`zero_pivots`, or where the caller's
    `zero` says, when it knows better) is that of a singular
    covariance; the vectors it is applied to lie in its range, where the
    minimum-norm least-squares solution is exact. It is computed with each
    component scaled to unit variance (the rows of L to unit norm), and
    directions below the round-off of :func:`zero_pivots` cut off, so that
    dividing by a round-off pivot does not turn round-off into a step.
    """
    if not (zero_pivots(L) if zero is None else zero).any():
        return whiten(L, B)
    scale = np.linalg.norm(L, axis=1)
    unit = np.where(scale > 0.0, scale, 1.0)[:, None]
    return np.linalg.lstsq(L / unit, B / unit, rcond=8 * L.shape[0] * np.finfo(np.float64).eps)[0]


def back_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``L⁻ᵀ B`` for a lower-triangular factor L: a back substitution, or least squares where L is singular.

    Where L has a zero on its diagonal, the minimum-norm solution of
    ``Lᵀ X = B``, with each component scaled to unit variance (the rows of
    L to unit norm) so that the cut-off of small singular values does not
    depend on units.
    """
    if np.all(np.diagonal(L) > 0.0):
        return back_substitute(L, B)
    scale = np.linalg.norm(L, axis=1)  # √P_jj
    unit = np.where(scale > 0.0, scale, 1.0)
    return np.linalg.lstsq(L.T / unit, B, rcond=None)[0] / unit[:, None]


def weighted_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``Σ_i w_i values_i`` along axis 0, centred on the first row.

    Computed as ``values_0 + Σ_i w_i (values_i - values_0)``: the plain sum
    when the weights sum to 1, but exact for a component that is the same
    at every point. The weights' sum carries round-off, and a constant
    output must keep a mean equal to it and a spread of exactly 0, so that a
    state component known exactly stays known exactly.
    """
    return values[0] + weights @ (values - values[0])


def circular_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean of angles along axis 0: ``atan2(Σ w sin, Σ w cos)``."""
    return np.arctan2(weights @ np.sin(values), weights @ np.cos(values))


def _upper_solve(U: np.ndarray, x: np.ndarray, vector: bool) -> np.ndarray:
    """``U⁻¹ x`` for an upper-triangular U: a back substitution; `x` a (stack of) vector(s) where `vector`.

    LAPACK's LU solve (NumPy's gufunc, without np.linalg's wrapper) finds no
    row to exchange below an upper-triangular matrix's diagonal: for finite
    entries its factors are I and U, and it substitutes back, each row on its
    own scale.
    """
    if _gesv is None:  # pragma: no cover - every NumPy since 1.8 has the gufuncs
        return np.linalg.solve(U, x[..., None])[..., 0] if vector else np.linalg.solve(U, x)
    return _gesv1(U, x) if vector else _gesv(U, x)


def _reversed(x: np.ndarray, vector: bool) -> np.ndarray:
    """`x` with its components (the last axis of vectors, the rows of matrices) in reverse order: a view."""
    return x[..., ::-1] if vector else x[..., ::-1, :]


def whiten(L: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``L⁻¹ x`` for a lower-triangular L: a forward substitution; `x` of shape (k,), (k, r) or a stack of either.

    Solved as the back substitution of the order-reversed system (``J L J``
    is upper triangular, J reversing the order): the LU solve of L itself
    exchanged rows where an entry below the diagonal was larger than the
    pivot, and with a factor of rows on scales 1e17 apart it lost every digit
    of the small one (the covariance form's EKF update raised a variance,
    0.615 to 7.03 for 0.215).
    """
    vector = x.ndim == 1
    return _reversed(_upper_solve(L[..., ::-1, ::-1], _reversed(x, vector), vector), vector)


def back_substitute(L: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``L⁻ᵀ x`` for a lower-triangular L: a back substitution; `x` as for :func:`whiten`."""
    return _upper_solve(np.swapaxes(L, -1, -2), x, x.ndim == 1)


def cho_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``C⁻¹ b`` for ``C = L Lᵀ``: two triangular solves, no inverse (stacks broadcast, a vector b too)."""
    return _upper_solve(np.swapaxes(L, -1, -2), whiten(L, b), b.ndim == 1)  # whiten broadcasts b to L's stack


def general_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """:math:`A^{-1} B` for a square A that is not a covariance (I + G X in the Riccati doubling): LU with pivoting.

    Raises numpy.linalg.LinAlgError when A is singular.
    """
    return np.linalg.solve(A, B)


def psd_solve(C: np.ndarray, B: np.ndarray) -> np.ndarray:
    r"""``C⁺ B`` for a positive semi-definite C: the Cholesky solve, or where C is singular a least-squares
    solution (exact on the range of C, where B is for a conditional). C and B may be stacks (k, n, n) and
    (k, n, r): one Cholesky solve of the stack where every C is positive definite, else one by one.

    The least squares are taken on C scaled to unit diagonal, :math:`D^{-1} C D^{-1}` with
    :math:`D = \operatorname{diag}(C)^{1/2}` (1 where a variance is 0), so that which directions count as
    singular does not depend on the units of the components: unscaled, a variance of 1e-10 beside one of
    1e6 fell below the cut of n ε times the largest singular value and was taken for zero.
    """
    try:
        L = cholesky(C, resolved=True)  # a pivot of round-off: C is singular, and dividing by it is noise
    except np.linalg.LinAlgError:
        if C.ndim > 2:
            return np.stack([psd_solve(c, b) for c, b in zip(C, B)]) if len(C) else np.zeros(B.shape)
        d = np.sqrt(np.diagonal(C).clip(min=0.0))
        d[d == 0.0] = 1.0
        scaled = C / d[:, None] / d[None, :]
        return np.linalg.lstsq(scaled, B / (d[:, None] if B.ndim == 2 else d), rcond=None)[0] / (
            d[:, None] if B.ndim == 2 else d)
    return cho_solve(L, B)


def log_density(white: np.ndarray, L: np.ndarray, logdet: float | None = None) -> float | np.ndarray:
    r"""``log N(x; μ, C)`` from the whitened residual ``L⁻¹ (x - μ)`` and the factor L of C.

    .. math::

        -\tfrac12 \left(\lVert L^{-1} (x - \mu) \rVert^2 + \log\det C + k \log 2\pi\right),
        \qquad \log\det C = 2 \textstyle\sum_i \log L_{ii},

    with k the dimension; over the last axis of `white` (and the last two of
    `L`). `logdet` is :func:`log_det` of L, when already known.
    """
    k = white.shape[-1]
    if logdet is None:
        logdet = log_det(L)
    if white.ndim == 1:  # one density: the common case, without the stack's axis bookkeeping
        return -0.5 * (white @ white + logdet + k * LOG_2PI)
    return -0.5 * (np.sum(white * white, axis=-1) + logdet + k * LOG_2PI)


def log_det(L: np.ndarray) -> float | np.ndarray:
    """``log det C = 2 Σ log L_ii`` for ``C = L Lᵀ`` (each of a stack)."""
    if L.ndim == 2:
        return 2.0 * float(np.log(L.diagonal()).sum())
    return 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)


def step_cholesky(S: np.ndarray, name: str, steps: np.ndarray, where=lambda t: f"at step {t}") -> np.ndarray:
    """The Cholesky factors of a stack `S` (k, n, n) of a series' covariances at `steps` (k,); one that is not
    positive definite is named at its step (audit AA3: a stack's error named none)."""
    try:
        return cholesky(S, name)
    except np.linalg.LinAlgError:
        i = int(np.argmin(factorable(S)))
        cholesky(S[i], f"{where(int(steps[i]))}: {name}")
        raise


def observed_gram(S: np.ndarray, X: np.ndarray, observed: np.ndarray, name: str = "the covariance",
                  where=lambda t: f"at step {t}"):
    r"""``X_oᵀ S_oo⁻¹ X_o`` and ``log|S_oo|`` at each step, over the observed components o.

    Parameters
    ----------
    S : ndarray of shape (T, m, m)
        Covariances.
    X : ndarray of shape (T, m, r)
        Columns to whiten (residuals, sensitivities).
    observed : ndarray of bool, shape (T, m)
        The components that count at each step; a step with none gives zeros.
    name : str
        What S is, for the error when an observed block is not positive definite.
    where : callable, optional
        Step t's place in that error ("at step t"; a batch's caller names the series).

    Returns
    -------
    gram : ndarray of shape (T, r, r)
    logdet : ndarray of shape (T,)

    Notes
    -----
    With :math:`S_{oo} = L L^\top` and :math:`W = L^{-1} X_o`, the gram matrix
    is :math:`W^\top W`. Steps with every component observed are factorised
    together, as one stack.
    """
    T, r = X.shape[0], X.shape[-1]
    gram, logdet = np.zeros((T, r, r)), np.zeros(T)
    full = observed.all(axis=1)
    if full.any():
        L = step_cholesky(S[full], name, np.flatnonzero(full), where)
        W = whiten(L, X[full])
        gram[full] = W.swapaxes(-1, -2) @ W
        logdet[full] = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
    for t in np.flatnonzero(observed.any(axis=1) & ~full):
        o = observed[t]
        L = cholesky(S[t][np.ix_(o, o)], f"{where(t)}: {name}")
        W = whiten(L, X[t][o])
        gram[t], logdet[t] = W.T @ W, 2.0 * np.sum(np.log(np.diag(L)))
    return gram, logdet


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles in radians to [-π, π).

    Parameters
    ----------
    a : array_like
        Angles in radians.

    Returns
    -------
    ndarray
        ``(a + π) mod 2π − π``, elementwise; where that rounds to π (an
        angle within round-off below -π), -π.

    Examples
    --------
    >>> import gaussfuse as gf
    >>> float(gf.wrap_angle(3.5))
    -2.7831853071795862
    """
    w = (a + np.pi) % (2.0 * np.pi) - np.pi
    return np.where(w >= np.pi, w - 2.0 * np.pi, w)[()]  # (of a's float type; a scalar for a scalar)


def near(x: np.ndarray, ref: np.ndarray, angles: np.ndarray | None) -> np.ndarray:
    """`x` with its angle components moved by whole turns to within π of `ref`'s (the others as they are)."""
    if angles is None or not angles.any():
        return x
    x = x.copy()
    x[..., angles] = ref[..., angles] + wrap_angle(x[..., angles] - ref[..., angles])
    return x


def wrap_components(diff: np.ndarray, angles: np.ndarray | None) -> np.ndarray:
    """`diff` with its angle components wrapped (a copy when any are)."""
    if angles is None or not angles.any():
        return diff
    diff = diff.copy()
    diff[..., angles] = wrap_angle(diff[..., angles])
    return diff

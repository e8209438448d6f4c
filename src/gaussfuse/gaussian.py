"""The Gaussian belief, the fusion (product) of two Gaussians, and the moments of a mixture."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kalman
from ._linalg import (circular_mean, cholesky, correlation_root, log_density, marginal_std, symmetrize, whiten,
                      wrap_angle, wrap_components)
from ._validation import as_array, as_matrix, as_vector, check_psd, generator, is_integer

__all__ = ["Gaussian", "fuse", "moment_match"]


def _checked(mean, cov, dim: int | None = None, names: tuple[str, str] = ("mean", "cov")):
    """`mean` (dim,) and `cov` (dim, dim) as float64 arrays, finite, `cov` symmetric PSD; errors name `names`."""
    mean = as_vector(names[0], mean, dim)
    n = mean.shape[0]
    return mean, check_psd(names[1], as_matrix(names[1], cov, n, n, time_varying=False))


@dataclass(frozen=True, eq=False, init=False)
class Gaussian:
    """An immutable multivariate Gaussian ``N(mean, cov)``.

    Parameters
    ----------
    mean : array_like of shape (n,)
        Mean; a scalar is a 1-dimensional Gaussian.
    cov : array_like of shape (n, n)
        Covariance, symmetric positive semi-definite; a scalar is the
        variance of a 1-dimensional Gaussian.

    Attributes
    ----------
    mean : ndarray of shape (n,)
        Read-only float64 mean.
    cov : ndarray of shape (n, n)
        Read-only float64 covariance (symmetrised).

    Examples
    --------
    >>> import gaussfuse as gf
    >>> g = gf.Gaussian([0.0, 1.0], [[2.0, 0.0], [0.0, 3.0]])
    >>> g.dim
    2
    >>> print(gf.Gaussian(1.0, 4.0))
    Gaussian(mean=[1.], cov=[[4.]])
    """

    mean: np.ndarray
    cov: np.ndarray

    def __init__(self, mean, cov) -> None:
        mean, cov = _checked(mean, cov)
        mean.setflags(write=False)
        cov.setflags(write=False)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", cov)

    @classmethod
    def _named(cls, mean, cov, dim: int, names: tuple[str, str]) -> Gaussian:
        """The constructor's checks, with the arguments called `names` (an online filter's ``x`` and ``P``)
        and the dimension `dim` required."""
        return cls._trusted(*_checked(mean, cov, dim, names))

    def __reduce__(self):
        # Pickled and copied by its arguments, made read-only again (which a pickle of protocol < 5 or a deep copy
        # of the arrays would not do) but not checked again: they passed the constructor's checks, or are a belief
        # gaussfuse computed, whose round-off those checks may refuse (a filter's indefinite covariance at
        # -1e-24 did not unpickle: audit GG2).
        return type(self)._trusted, (self.mean, self.cov)

    @classmethod
    def _trusted(cls, mean: np.ndarray, cov: np.ndarray) -> Gaussian:
        """A Gaussian from float64 arrays gaussfuse computed (a filter's belief), made read-only, not re-checked.

        The constructor's checks (shapes, finiteness, a symmetric PSD
        covariance by eigenvalues) are for what users give; repeating them on
        every belief of an online filter would cost ten times the step.
        """
        out = object.__new__(cls)
        mean.setflags(write=False)
        cov.setflags(write=False)
        object.__setattr__(out, "mean", mean)
        object.__setattr__(out, "cov", cov)
        return out

    @property
    def dim(self) -> int:
        """Dimension n of the variable."""
        return self.mean.shape[0]

    @property
    def std(self) -> np.ndarray:
        """Marginal standard deviations, array of shape (n,)."""
        return marginal_std(self.cov)

    def __repr__(self) -> str:
        # both to 6 digits, comma-separated, on one line, a large one summarised as NumPy does (the mean had 6
        # digits and the covariance 17, and a 50-dimensional belief printed 12,774 characters: audit Y3); no
        # suppress: a variance of 1e-300 is not 0
        def text(a: np.ndarray) -> str:
            return np.array2string(a, separator=", ", precision=6, max_line_width=np.inf).replace("\n", "")

        return f"Gaussian(mean={text(self.mean)}, cov={text(self.cov)})"

    def logpdf(self, x) -> np.ndarray | float:
        """Log-density at `x`, array_like of shape (n,) or (k, n).

        Uses a Cholesky factor of the covariance, which must be positive definite.

        Parameters
        ----------
        x : array_like of shape (n,) or (k, n)
            A point, or k points. For n = 1 a scalar is a point too, and a
            1-D array of length k > 1 is k points.

        Returns
        -------
        float or ndarray of shape (k,)
            The log-density at the point, or at each of the k points; -inf
            at a point so far out that its squared distance overflows.
        """
        x = as_array("x", x)
        if x.ndim > 2 or (x.shape[-1:] != (self.dim,) and not (self.dim == 1 and x.ndim <= 1)):
            raise ValueError(f"`x` must have shape ({self.dim},) or (k, {self.dim}); got shape {x.shape}.")
        if self.dim == 1 and x.shape[-1:] != (1,):
            x = x[..., None]
        L = cholesky(self.cov, "`cov`")
        with np.errstate(over="ignore"):  # a squared distance beyond 1.8e308: the log-density is -inf in float64
            out = log_density(whiten(L, (x - self.mean).T).T, L)
        return float(out) if np.ndim(out) == 0 else out

    def sample(self, size: int | None = None, rng=None) -> np.ndarray:
        """Draw samples: array of shape (n,) for ``size=None``, else (size, n).

        `size` is None or a non-negative integer (0 gives an empty (0, n)
        array). The samples are ``mean + z Lᵀ`` with standard normal z and
        the Cholesky factor L of the covariance (NumPy's
        ``multivariate_normal(method="cholesky")``, draw for draw); a
        singular covariance (a belief certain in some direction) has
        :func:`gaussfuse.kalman.cov_factor`'s semi-definite factor, whose
        columns with a pivot of round-off are zero: the samples then obey
        the certainty to round-off. (NumPy's eigendecomposition spread them
        by the square root of the round-off eigenvalues, about 1e-8 of the
        scale. A pivot that the covariance's own round-off leaves above the
        test keeps such a column: in 300 random rank-deficient covariances
        A Aᵀ of 2 to 6 components, 3% to 7% of them (four seeds) leave more
        than 1e-12 of the scale in A's null space, the largest 7e-9 to
        2.2e-8, where 88% to 93% of NumPy's draws did, up to 4.3e-8. A
        covariance accepted to the round-off of its largest entry that the
        factor refuses on its components' own scales is drawn from its
        correlation matrix's eigendecomposition, negative eigenvalues taken
        as 0.)

        Parameters
        ----------
        size : int, optional
            Number of samples, >= 0; None for a single one.
        rng : int, numpy.random.Generator or None, optional
            Seed or generator: anything :func:`numpy.random.default_rng`
            takes (a ``SeedSequence``, a ``RandomState`` too).

        Returns
        -------
        ndarray of shape (n,) or (size, n)
            The samples.

        Raises
        ------
        TypeError
            When `size` is neither None nor an integer, or `rng` is not a seed
            or a Generator.
        ValueError
            When `size` or an integer `rng` is negative.
        """
        if size is not None:
            if not is_integer(size):
                raise TypeError(f"`size` must be None or a non-negative integer; got {size!r}.")
            if size < 0:
                raise ValueError(f"`size` must be None or a non-negative integer; got {size}.")
            size = int(size)
        rng = generator(rng)
        try:
            L = kalman.cov_factor(self.cov)
        except np.linalg.LinAlgError:  # accepted to round-off of its largest entry, refused on its components' own
            L = correlation_root(self.cov)  # scales (reviews R35-R37): its root on those scales
        return self.mean + rng.standard_normal(self.dim if size is None else (size, self.dim)) @ L.T


def fuse(a: Gaussian, b: Gaussian) -> Gaussian:
    r"""Fuse two Gaussian beliefs about the same variable: their normalised product.

    Parameters
    ----------
    a, b : Gaussian
        Two independent Gaussian beliefs of the same dimension n. Their
        covariances may be singular (a belief that is certain in some
        direction), but not both in the same direction (even where their
        means agree in it, as the Kalman update refuses a noise-free
        measurement of a state known exactly).

    Returns
    -------
    Gaussian
        The belief proportional to :math:`N(x; \mu_a, \Sigma_a) N(x; \mu_b, \Sigma_b)`.

    Raises
    ------
    ValueError
        When ``a.cov + b.cov`` is singular.
    FloatingPointError
        When the fused mean or covariance overflows float64.

    Notes
    -----
    In one dimension, with :math:`a = N(\mu_1, \sigma_1^2)` and
    :math:`b = N(\mu_2, \sigma_2^2)`,

    .. math::

        \mu = \mu_1 + \frac{\sigma_1^2 (\mu_2 - \mu_1)}{\sigma_1^2 + \sigma_2^2},
        \qquad
        \sigma^2 = \sigma_1^2 - \frac{\sigma_1^4}{\sigma_1^2 + \sigma_2^2}.

    In n dimensions this is the Kalman update of `a` by the measurement
    ``z = b.mean`` with ``H = I`` and ``R = b.cov`` (see
    :func:`gaussfuse.kalman.fuse_moments`), in the square-root form: no
    inverse, and :math:`\Sigma_a + \Sigma_b` is never formed, so variances
    far apart (1e300 times, or near the largest float) lose nothing. A
    component that one belief knows exactly (a zero variance) comes out
    with a variance of exactly 0 when that belief is the narrower (by
    trace), else of round-off, about :math:`\epsilon^2` of the other's. ``fuse(a, b)`` and ``fuse(b, a)`` are the same
    numbers.

    Examples
    --------
    >>> import gaussfuse as gf
    >>> gf.fuse(gf.Gaussian(0.0, 1.0), gf.Gaussian(2.0, 1.0))
    Gaussian(mean=[1.], cov=[[0.5]])
    """
    for name, g in (("a", a), ("b", b)):
        if not isinstance(g, Gaussian):
            raise TypeError(f"`{name}` must be a gaussfuse.Gaussian; got {type(g).__name__}.")
    if a.dim != b.dim:
        raise ValueError(
            f"`a` and `b` must have the same dimension; got {a.dim} and {b.dim}."
        )
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # the update's log-likelihood term is not used
            mean, cov = kalman.fuse_moments(a.mean, a.cov, b.mean, b.cov)
    except np.linalg.LinAlgError:
        raise ValueError(  # (it said "so their product is not a Gaussian", untrue where they agree: audit CC1)
            "`a.cov + b.cov` must be positive definite: the two beliefs are both certain "
            "in a common direction, where their product is a point if their means agree there and nothing if "
            "not; fuse does not take such pairs: give one of them a variance in that direction."
        ) from None
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        raise FloatingPointError("the fused mean or covariance is not finite (inf or NaN): the computation "
                                 "overflowed; check the scale of `a` and `b`.")
    return Gaussian._trusted(mean, cov)  # L Lᵀ: symmetric, and positive semi-definite to round-off


def moment_match(weights: np.ndarray, means: np.ndarray, covs: np.ndarray,
                 angles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""The Gaussian with the mean and covariance of a Gaussian mixture.

    Parameters
    ----------
    weights : array of shape (M,)
        Mixture weights, summing to 1.
    means : array of shape (M, n)
        Component means.
    covs : array of shape (M, n, n)
        Component covariances.
    angles : array of bool, shape (n,), optional
        Components that are angles: their mean is circular, in [-π, π), and
        their spread is measured with wrapped differences.

    Returns
    -------
    mean : array of shape (n,)
    cov : array of shape (n, n)

    Notes
    -----
    .. math::

        \bar m = \sum_i w_i m_i, \qquad
        \bar P = \sum_i w_i \left[ P_i + (m_i - \bar m)(m_i - \bar m)^\top \right].
    """
    mean = weights @ means
    if angles is not None and angles.any():
        mean[angles] = wrap_angle(circular_mean(means[:, angles], weights))  # atan2's +π is -π
    diff = wrap_components(means - mean, angles)
    cov = np.einsum("i,ijk->jk", weights, covs) + (diff * weights[:, None]).T @ diff
    return mean, symmetrize(cov)

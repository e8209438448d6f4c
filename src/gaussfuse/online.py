"""Online filtering: one predict or update at a time."""

from __future__ import annotations

import numpy as np

from . import kalman
from ._validation import as_array, shape_error
from .diagnostics import DivergenceMonitor
from .errors import STEP_ERRORS, at_step
from .gaussian import Gaussian
from ._linalg import symmetrize
from .inference.registry import FORMS
from .inference.validation import check_prior
from .linearize import Exact
from .models.linear import LinearModel

__all__ = ["KalmanFilter"]


class KalmanFilter:
    """A Kalman filter that takes measurements as they arrive.

    Parameters
    ----------
    model : LinearModel
        The model; for a time-varying one, the k-th call of :meth:`predict`
        uses its matrices at step k (counting from 0), and :meth:`update`
        those of the step last predicted.
    prior : Gaussian
        The belief before the first :meth:`predict`.
    form : {"cov", "sqrt"}, default "cov"
        Propagate the covariance (Joseph form) or its Cholesky factor
        (square-root form: :func:`gaussfuse.kalman.update_sqrt`), as in
        :func:`gaussfuse.filter`.
    check : {"warn", "raise", "off"}, default "warn"
        The divergence test of :func:`gaussfuse.filter`, run over the
        updates as they come (:class:`gaussfuse.diagnostics.DivergenceMonitor`:
        a consistent filter is flagged with probability at most 1e-3 over its
        whole run): a :class:`gaussfuse.DivergenceWarning` naming the steps,
        raised with ``"raise"``.

    Attributes
    ----------
    belief : Gaussian
        The current belief.
    x : ndarray of shape (n,)
        Its mean.
    P : ndarray of shape (n, n)
        Its covariance.
    L : ndarray of shape (n, n)
        A lower-triangular factor of it, ``P = L Lᵀ``: the one the
        square-root form propagates (computed from P for the covariance
        form).
    step : int
        Number of predictions made so far.
    loglik : float
        Sum of the log-likelihood contributions of the updates so far.

    Notes
    -----
    ``predict(u_k)`` then ``update(z_k)`` for k = 0..T-1 is exactly
    :func:`gaussfuse.filter` on the same series: the two halves of
    :func:`gaussfuse.kalman.step`, :func:`~gaussfuse.kalman.forecast` and
    :func:`~gaussfuse.kalman.correct`.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=[[1, 0], [0, 3]], R=10)
    >>> kf = gf.KalmanFilter(model, gf.Gaussian([0, 1], 500 * np.eye(2)))
    >>> for z in [1, 2, 3, 2, 1]:
    ...     _ = kf.predict()
    ...     _ = kf.update(z)
    >>> kf.x.shape, kf.P.shape
    ((2,), (2, 2))
    """

    def __init__(self, model: LinearModel, prior: Gaussian, form: str = "cov", check: str = "warn") -> None:
        if not isinstance(model, LinearModel):
            raise TypeError(f"`model` must be a gaussfuse.LinearModel; got {type(model).__name__}.")
        if not isinstance(form, str) or form not in FORMS:
            raise ValueError(f"`form` must be one of {list(FORMS)}; got {form!r}.")
        self._monitor = DivergenceMonitor.for_check(check)
        self.model = model
        self.form = form
        self.belief = check_prior(prior, model.n)
        self._factor: tuple[Gaussian, np.ndarray] | None = None  # (belief, its factor) in the square-root form
        self._roots = kalman.Factors()
        self.step = 0
        self.loglik = 0.0
        self._controls: dict = {}  # u_k of the step being predicted, for the strategy
        self._lin = Exact(model, self._controls)
        # a time-invariant model's covariances reach a fixed point that steps then reuse, exactly
        self._steady = kalman.SteadyState() if self._lin.invariant else None

    @property
    def x(self) -> np.ndarray:
        return self.belief.mean

    @property
    def P(self) -> np.ndarray:
        return self.belief.cov

    @property
    def L(self) -> np.ndarray:
        if self._factor is None or self._factor[0] is not self.belief:  # a belief set by hand, or the prior
            self._factor = (self.belief, kalman.cov_factor(self.belief.cov, "the belief's covariance"))
        return self._factor[1]

    def _set(self, mean: np.ndarray, factor: np.ndarray) -> Gaussian:
        """Make ``N(mean, L Lᵀ)`` the belief, remembering its factor L."""
        self.belief = Gaussian._trusted(mean, symmetrize(factor @ factor.T))
        self._factor = (self.belief, factor)
        return self.belief

    def _check_step(self, k: int) -> None:
        steps = self.model.steps
        if steps is not None and not 0 <= k < steps:
            raise ValueError(f"the time-varying model has {steps} steps; step {k} is beyond it.")

    def predict(self, u=None) -> Gaussian:
        """Advance the belief one step, with control input `u` of shape (p,) when the model has B."""
        k = self.step
        self._check_step(k)
        p = self.model.p
        if not p and u is not None:
            raise ValueError("`u` was given but the model has no control input; give the model `B`.")
        if p:
            if u is None:
                raise ValueError(f"`u` is required: the model has a control input with p = {p}.")
            u = np.atleast_1d(as_array("u", u))
            if u.shape != (p,):
                raise shape_error("u", f"({p},)", u.shape)
        self._controls.clear()
        self._controls[k] = u
        if self.form == "sqrt":
            self._set(*self._run(kalman.forecast_sqrt, self._lin, k, self.belief.mean, self.L, self._roots,
                                 steady=self._steady))
        else:
            mean, cov = self._run(kalman.forecast, self._lin, k, self.belief.mean, self.belief.cov,
                                  steady=self._steady)
            self.belief = Gaussian._trusted(mean, cov)
        self.step += 1
        return self.belief

    def update(self, z) -> Gaussian:
        """Condition the belief on measurement `z` of shape (m,) (a scalar when m = 1); NaN = missing."""
        k = max(self.step - 1, 0)
        self._check_step(k)
        m = self.model.m
        z = np.atleast_1d(as_array("z", z, allow_nan=True))
        if z.shape != (m,):
            raise shape_error("z", f"({m},)", z.shape)
        if self.form == "sqrt":
            post = self._run(kalman.correct_sqrt, self._lin, k, self.belief.mean, self.L, z, self._roots,
                             steady=self._steady)
            self._set(post.mean, post.factor)
        else:
            post = self._run(kalman.correct, self._lin, k, self.belief.mean, self.belief.cov, z,
                             steady=self._steady)[0]
            self.belief = Gaussian._trusted(post.mean, post.cov)
        self.loglik += post.loglik
        if self._monitor is not None:
            self._monitor.observe(post, k, "steps {}-{}")
        return self.belief

    @staticmethod
    def _run(half, lin, k: int, *args, **kwargs):
        """A half of :func:`gaussfuse.kalman.step`, with the step named in its errors.

        An overflow raises FloatingPointError (the step checks), not NumPy's
        RuntimeWarning on the way.
        """
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                return half(lin, k, *args, **kwargs)
        except STEP_ERRORS as exc:
            raise at_step(exc, k) from exc

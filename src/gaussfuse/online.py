"""Online filtering: one predict or update at a time."""

from __future__ import annotations

import numpy as np

from . import kalman
from ._validation import as_array, shape_error
from .errors import STEP_ERRORS, at_step
from .gaussian import Gaussian
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

    Attributes
    ----------
    belief : Gaussian
        The current belief.
    x : ndarray of shape (n,)
        Its mean.
    P : ndarray of shape (n, n)
        Its covariance.
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

    def __init__(self, model: LinearModel, prior: Gaussian) -> None:
        if not isinstance(model, LinearModel):
            raise TypeError(f"`model` must be a gaussfuse.LinearModel; got {type(model).__name__}.")
        self.model = model
        self.belief = check_prior(prior, model.n)
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
        mean, cov = self._run(kalman.forecast, self._lin, k, self.belief.mean, self.belief.cov, steady=self._steady)
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
        post = self._run(kalman.correct, self._lin, k, self.belief.mean, self.belief.cov, z, steady=self._steady)[0]
        self.belief = Gaussian._trusted(post.mean, post.cov)
        self.loglik += post.loglik
        return self.belief

    @staticmethod
    def _run(half, lin, k: int, *args, **kwargs):
        """A half of :func:`gaussfuse.kalman.step`, with the step named in its errors."""
        try:
            return half(lin, k, *args, **kwargs)
        except STEP_ERRORS as exc:
            raise at_step(exc, k) from exc

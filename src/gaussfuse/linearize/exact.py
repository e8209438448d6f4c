"""Affine maps that need no regression: a linear model's own, and one frozen at a trajectory."""

from __future__ import annotations

import numpy as np

from .._linalg import near, unseen_directions, with_slopes

__all__ = ["Exact", "Nominal"]


class Exact:
    """The exact affine form of a LinearModel: ``A = F_k``, ``b = B_k u_k``, ``H = H_k``.

    Parameters
    ----------
    model : LinearModel
    us : ndarray of shape (T, p), or a mapping from k to u_k, optional
        The controls, when the model has B.

    Attributes
    ----------
    invariant : bool
        Whether F, H, Q and R are the same at every step, so that the
        covariance recursion can reach a fixed point (see
        :class:`gaussfuse.kalman.SteadyState`).
    """

    def __init__(self, model, us=None) -> None:
        self.model, self.us = model, us
        # the matrices, and whether each varies with the step (read once: a step asks for them)
        self._F, self._H, self._Q, self._R, self._B = model.F, model.H, model.Q, model.R, model.B
        self._varies = tuple(a is not None and a.ndim == 3 for a in (model.F, model.H, model.Q, model.R, model.B))
        self.invariant = not any(self._varies[:4])  # A, H, Q, R the same at every step (see kalman.SteadyState)

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        vF, _, vQ, _, vB = self._varies
        B = self._B
        b = None if B is None else (B[k] if vB else B) @ self.us[k]
        return self._F[k] if vF else self._F, b, self._Q[k] if vQ else self._Q

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        _, vH, _, vR, _ = self._varies
        return self._H[k] if vH else self._H, None, self._R[k] if vR else self._R


class Nominal:
    """A strategy frozen at a nominal trajectory, ignoring the belief it is given.

    Parameters
    ----------
    strategy : Taylor or SigmaPoints
        How to linearise.
    means : ndarray of shape (T + 1, n)
        Nominal means at times 0..T, where time 0 is the prior's (one step
        before the first measurement).
    covs : ndarray of shape (T + 1, n, n)
        Nominal covariances (used by sigma-point strategies).
    angles : array of bool, shape (n,), optional
        State components that are angles.

    Notes
    -----
    Step k's transition is linearised at the nominal state at time k (the
    state it starts from) and its measurement at time k + 1, each taken on
    the side of ±π of the belief it is applied to: the affine map is used
    at that belief, and one made 2π away would be off by the jump.
    """

    def __init__(self, strategy, means: np.ndarray, covs: np.ndarray, angles: np.ndarray | None = None) -> None:
        self.strategy, self.means, self.covs, self.angles = strategy, means, covs, angles

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        return self.strategy.transition(k, near(self.means[k], mean, self.angles), self.covs[k])

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        """At the nominal state of time k + 1; a slope it has no spread to see is taken at the belief given (the
        prediction), which has (:func:`gaussfuse._linalg.unseen_directions`)."""
        at = near(self.means[k + 1], mean, self.angles)
        H, d, R = self.strategy.measurement(k, at, self.covs[k + 1])
        if getattr(self.strategy, "needs_spread", False):
            unseen = unseen_directions(at, self.covs[k + 1], np.sqrt(np.diagonal(cov).clip(min=0.0)))
            if unseen is not None:
                H, d = with_slopes(H, d, self.strategy.measurement(k, mean, cov)[0], at, unseen)
        return H, d, R

"""Affine maps that need no regression: a linear model's own, and one frozen at a trajectory."""

from __future__ import annotations

import numpy as np

__all__ = ["Exact", "Nominal"]


class Exact:
    """The exact affine form of a LinearModel: ``A = F_k``, ``b = B_k u_k``, ``H = H_k``.

    Parameters
    ----------
    model : LinearModel
    us : ndarray of shape (T, p), or a mapping from k to u_k, optional
        The controls, when the model has B.
    """

    def __init__(self, model, us: np.ndarray | None = None) -> None:
        self.model, self.us = model, us

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        F, _, Q, _, B = self.model.at(k)
        return F, None if B is None else B @ self.us[k], Q

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        _, H, _, R, _ = self.model.at(k)
        return H, None, R


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

    Notes
    -----
    Step k's transition is linearised at the nominal state at time k (the
    state it starts from) and its measurement at time k + 1.
    """

    def __init__(self, strategy, means: np.ndarray, covs: np.ndarray) -> None:
        self.strategy, self.means, self.covs = strategy, means, covs

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        return self.strategy.transition(k, self.means[k], self.covs[k])

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        return self.strategy.measurement(k, self.means[k + 1], self.covs[k + 1])

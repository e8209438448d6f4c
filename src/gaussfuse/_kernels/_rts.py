r"""The backward pass of every compiled smoother: :func:`gaussfuse.inference.drivers.run_smoother`'s loop.

The forward kernels (:mod:`.linear`, :mod:`.sigma_points`) compute the
smoother gains as they filter: at step k the transition out of the filtered
belief :math:`(m_{k-1}, P_{k-1})` is the affine map :math:`A_k` they have
just used to predict (the regression of f at that belief, for sigma
points: exactly what run_smoother re-linearises at), so
:math:`G_{k-1} = P_{k-1} A_k^\top (P^-_k)^{-1}` (:func:`._step.smoother_gain`).
Where :math:`P^-_k` is singular the Cholesky solve fails; the forward kernel
leaves the cross-covariance's transpose :math:`C_k^\top = A_k P_{k-1}` in place
of the gain, and :func:`least_squares_gains` replaces it, in Python, by the
readable path's minimum-norm solution (:func:`gaussfuse._linalg.psd_solve`).
Then :func:`backward` runs the recursion (:func:`._step.rts_step`) over
each series, in parallel over chunks of series for a batch
(:func:`._jit.launch`); a series that had another's covariances at every
step of the forward pass (:attr:`._step.Outputs.leader`) copies its smoothed
covariances and computes only its means. The square-root smoother's recursion,
:func:`backward_sqrt` (:func:`._step.rts_back`), computes its gains
from the joint factor of each transition as it goes (computed from a
linear model, or stored by the sigma-point forward pass, which has the
regression); a series whose prediction's factor is singular is left to
the readable path.
"""

from __future__ import annotations

import numpy as np

from .._linalg import psd_solve
from ._jit import jit, launch
from ._nrt import borrow
from ._step import (at, copy1, copy2, joint_factor, not_finite_factor, predict_mean, rts_back, rts_mean, rts_step,
                    sqrt_back_workspace, workspace, wrap)

__all__ = ["backward", "backward_sqrt", "least_squares_gains", "smooth"]

_JIT = {"nogil": True, "error_model": "numpy"}


@jit(**_JIT)
def backward(lo, hi, means, covs, pmeans, pcovs, gains, angles, leader, sm_means, sm_covs):
    """The RTS recursion of run_smoother over series ``lo..hi-1``: (N, T, ...) arrays, gains (N, T - 1, n, n).

    A series whose filtered and predicted covariances and gains are those
    of ``leader[s]`` at every step (the forward kernel's
    :attr:`._step.Outputs.leader`) has its smoothed covariances too: when
    that series has been smoothed already in this chunk, they are copied
    and only the means are computed (bitwise :func:`._step.rts_step`'s).
    """
    means, covs, pmeans, pcovs, gains, angles, leader, sm_means, sm_covs = borrow(
        (means, covs, pmeans, pcovs, gains, angles, leader, sm_means, sm_covs))
    T = means.shape[1]
    n = means.shape[2]
    scratch = workspace(n, 1)
    w = borrow(scratch)
    for s in range(lo, hi):
        copy1(sm_means[s, T - 1], means[s, T - 1])
        copy2(sm_covs[s, T - 1], covs[s, T - 1])
        first = leader[s]
        shared = lo <= first < s
        for j in range(T - 2, -1, -1):
            if shared:
                rts_mean(w, means[s, j], pmeans[s, j + 1], sm_means[s, j + 1], gains[s, j], angles, sm_means[s, j])
                copy2(sm_covs[s, j], sm_covs[first, j])
            else:
                rts_step(w, means[s, j], covs[s, j], pmeans[s, j + 1], pcovs[s, j + 1], sm_means[s, j + 1],
                         sm_covs[s, j + 1], gains[s, j], angles, sm_means[s, j], sm_covs[s, j])
            for i in range(n):
                if angles[i]:
                    sm_means[s, j, i] = wrap(sm_means[s, j, i])
    scratch.A1[0, 0] = 0.0  # alive until here


@jit(**_JIT)
def backward_sqrt(lo, hi, means, factors, F, Qf, b, joint, jpm, angles, sm_means, sm_factors, gains, failed):
    """run_smoother on factors over series ``lo..hi-1`` (:func:`._step.rts_back`).

    The joint factor of each transition (:func:`._step.joint_factor`) is
    read from `joint` (N, T - 1, 2n, 2n), with the prediction's mean from
    `jpm` (N, T - 1, n), where a sigma-point forward pass stored them;
    otherwise (`joint` of length 0) it is computed from a linear model's
    `F` and `Qf` (T or 1, n, n), the transitions and the factors of Q, and
    `b` (N or 1, T or 1, n), the offsets. ``failed[s]`` is set where a
    prediction's factor is singular or a smoothed belief is not finite;
    the caller smooths those series on the readable path.
    """
    means, factors, F, Qf, b, joint, jpm, angles, sm_means, sm_factors, gains, failed = borrow(
        (means, factors, F, Qf, b, joint, jpm, angles, sm_means, sm_factors, gains, failed))
    T = means.shape[1]
    n = means.shape[2]
    scratch = sqrt_back_workspace(n)
    bw = borrow(scratch)
    stored = joint.shape[1] > 0
    for s in range(lo, hi):
        failed[s] = False
        copy1(sm_means[s, T - 1], means[s, T - 1])
        copy2(sm_factors[s, T - 1], factors[s, T - 1])
        bs = b[s if b.shape[0] > 1 else 0]
        for j in range(T - 2, -1, -1):  # the transition out of step j is the one into step j + 1
            if stored:
                copy2(bw.T, joint[s, j])
                copy1(bw.pm, jpm[s, j])
            else:
                Lq = at(Qf, j + 1)
                joint_factor(bw, factors[s, j], at(F, j + 1), Lq, Lq[:, :0])
                predict_mean(means[s, j], at(F, j + 1), at(bs, j + 1), bw.pm)
            ok = rts_back(bw, means[s, j], sm_means[s, j + 1], sm_factors[s, j + 1], angles, sm_means[s, j],
                          sm_factors[s, j], gains[s, j])
            if not ok or not_finite_factor(sm_means[s, j], sm_factors[s, j], 0.0):
                failed[s] = True
                break
            for i in range(n):
                if angles[i]:
                    sm_means[s, j, i] = wrap(sm_means[s, j, i])
    scratch.pm[0] = 0.0  # alive until here


def least_squares_gains(gains: np.ndarray, failed: np.ndarray, pcovs: np.ndarray) -> None:
    """Replace, where `failed`, the ``C_kᵀ`` left in `gains` by kalman.rts_step's gain ``(P⁻⁺ Cᵀ)ᵀ``.

    `gains` is (N, T - 1, n, n), `failed` (N, T - 1) and `pcovs` the
    predictions (N, T, n, n): gain ``G_{k-1}`` goes with ``P⁻_k``.
    """
    for s, j in zip(*np.nonzero(failed)):
        gains[s, j] = psd_solve(pcovs[s, j + 1], gains[s, j]).T


def smooth(means, covs, pmeans, pcovs, gains, angles, leader=None):
    """The smoothed means and covariances (N, T, ...) from the forward pass's arrays and gains (see the module notes).

    `leader` (N,) is the forward kernel's :attr:`._step.Outputs.leader`; by default each series its own.
    """
    sm_means, sm_covs = np.empty_like(means), np.empty_like(covs)
    leader = np.arange(means.shape[0]) if leader is None else leader
    launch(backward, means.shape[0], means, covs, pmeans, pcovs, gains, angles, leader, sm_means, sm_covs)
    return sm_means, sm_covs

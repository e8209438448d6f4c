r"""Learning a linear-Gaussian model from data: EM and maximum likelihood.

Both methods stand on the smoothed moments of the states, from the prior's
time 0 to T, and the lag-one covariances
:math:`C_t = \operatorname{Cov}(x_t, x_{t-1} \mid z_{1:T}) = P^s_t G_{t-1}^\top`.
With them every expectation of the complete-data log-likelihood

.. math::

    \ell_c = \log N(x_0; m_0, P_0)
      + \sum_t \log N(x_t; F_t x_{t-1} + B_t u_t, Q_t)
      + \sum_t \log N(z_t; H_t x_t, R_t)

is a quadratic form in the second moments :math:`\Phi_t = E[s_t s_t^\top]` of
:math:`s_t = (x_t, x_{t-1}, u_t, 1)` and :math:`\Psi_t = E[r_t r_t^\top]` of
:math:`r_t = (z_t, x_t, 1)`: the transition residual is
:math:`w_t = [I, -F_t, -B_t, 0]\, s_t` and the measurement residual
:math:`v_t = [I, -H_t, 0]\, r_t`. A missing component of :math:`z_t` is part of
the complete data; its moments given the observed ones are exact:
:math:`z_\mu = (H_\mu - L H_o) x + L z_o + e`,
:math:`L = R_{\mu o} R_{oo}^{-1}`, :math:`e \sim N(0, R_{\mu\mu} - L R_{o\mu})`.

* **EM** (Shumway & Stoffer 1982) maximises :math:`E[\ell_c]`: :math:`[F, B]`
  by regression of :math:`x_t` on :math:`(x_{t-1}, u_t)`,
  :math:`H = \sum E[z x^\top] (\sum E[x x^\top])^{-1}`, then
  :math:`Q = \frac1T \sum E[w w^\top]`, :math:`R = \frac1T \sum E[v v^\top]`,
  :math:`m_0 = E[x_0]`, :math:`P_0 = \operatorname{Cov}[x_0]`. A diagonal
  or scalar covariance keeps the diagonal or its mean. Each step is an
  exact maximisation, so the likelihood never decreases.
* **Maximum likelihood** optimises :math:`\log p(z \mid \theta)` with
  scipy.optimize over unconstrained parameters (a covariance through its
  Cholesky factor with a log diagonal, or log variances). Its gradient is
  exact, by Fisher's identity :math:`\nabla \log p(z) = E[\nabla \ell_c \mid z]`:
  for example :math:`\partial/\partial Q = \tfrac12 Q^{-1}(\sum E[w w^\top] - T Q) Q^{-1}`
  and :math:`\partial/\partial F = Q^{-1} \sum E[w x_{t-1}^\top]`.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import Callable

import numpy as np
from ._frozen import reduce_frozen
from .diffuse import Moments, diffuse_moments
from .gaussian import Gaussian
from .inference import ENGINES, _check_steps, check_controls, check_measurements, check_prior, smooth_from_prior
from .kalman import symmetrize
from .models.linear import LinearModel

__all__ = ["fit", "FitResult", "LEARNABLE", "STRUCTURES"]

LEARNABLE = ("F", "H", "Q", "R", "B", "m0", "P0")
COVARIANCES = ("Q", "R", "P0")
STRUCTURES = ("full", "diagonal", "scalar")
METHODS = ("em", "mle")


@dataclass(frozen=True, eq=False)
class FitResult:
    """The output of :func:`fit`.

    Attributes
    ----------
    model : LinearModel
        The fitted model.
    prior : Gaussian or "diffuse"
        The fitted (or given) prior.
    loglik : float
        Log-likelihood of the data under `model` and `prior`.
    history : ndarray of shape (k,)
        Log-likelihood at each iteration, the last being `loglik`.
    method : str
        "em" or "mle".
    converged : bool
        Whether the tolerance was met (False after `iterations` or Ctrl-C).
    message : str
        How the fit ended.
    standard_errors : dict of str to ndarray, or None
        For "mle": standard errors of every learned matrix (same shape),
        from the inverse of the observed information (the Hessian of the
        log-likelihood at the optimum), or of the user's parameters under
        ``"params"``. None for "em".
    """

    model: LinearModel
    prior: Gaussian | str
    loglik: float
    history: np.ndarray
    method: str
    converged: bool
    message: str
    standard_errors: dict | None = None

    __reduce__ = reduce_frozen


# ---------------------------------------------------------------------------
# The E-step: smoothed moments and expected sufficient statistics
# ---------------------------------------------------------------------------


def moments(model: LinearModel, prior, zs: np.ndarray, us: np.ndarray | None, engine: str = "auto") -> Moments:
    """Smoothed moments of one series from time 0 (the prior's) to T, with lag-one covariances."""
    if isinstance(prior, str):
        return diffuse_moments(model, zs, us, engine)
    means, covs, gains, filt = smooth_from_prior(model, prior, zs, us, engine)
    cross = covs[1:] @ np.swapaxes(gains, -1, -2)
    return Moments(means, covs, cross, filt.loglik, filt, gains)


def _per_step(a: np.ndarray | None, T: int) -> np.ndarray | None:
    """A matrix as a stack over T steps (broadcast when time-invariant)."""
    if a is None:
        return None
    return a if a.ndim == 3 else np.broadcast_to(a, (T, *a.shape))


class Statistics:
    """Expected second moments of one series (see the module notes).

    Attributes
    ----------
    Phi : ndarray of shape (T, d, d)
        ``E[s_t s_tᵀ]``, s_t = (x_t, x_{t-1}, u_t, 1), d = 2n + p + 1.
    Psi : ndarray of shape (T, e, e)
        ``E[r_t r_tᵀ]``, r_t = (z_t, x_t, 1), e = m + n + 1.
    x0_mean, x0_cov : ndarray
        Smoothed moments of x_0.
    """

    def __init__(self, model: LinearModel, mom: Moments, zs: np.ndarray, us: np.ndarray | None):
        T, n, m = zs.shape[0], model.n, model.m
        p = 0 if us is None else us.shape[1]
        mean, cov, cross = mom.means, mom.covs, mom.cross
        d = 2 * n + p + 1
        mu = np.zeros((T, d))
        mu[:, :n], mu[:, n:2 * n], mu[:, 2 * n:2 * n + p], mu[:, -1] = mean[1:], mean[:-1], \
            (us if p else np.zeros((T, 0))), 1.0
        sig = np.zeros((T, d, d))
        sig[:, :n, :n], sig[:, n:2 * n, n:2 * n] = cov[1:], cov[:-1]
        sig[:, :n, n:2 * n] = cross
        sig[:, n:2 * n, :n] = np.swapaxes(cross, -1, -2)
        self.Phi = sig + mu[:, :, None] * mu[:, None, :]

        H, R = _per_step(model.H, T), _per_step(model.R, T)
        e = m + n + 1
        nu = np.zeros((T, e))
        nu[:, :m], nu[:, m:m + n], nu[:, -1] = np.nan_to_num(zs), mean[1:], 1.0
        tau = np.zeros((T, e, e))
        tau[:, m:m + n, m:m + n] = cov[1:]
        for t in np.flatnonzero(np.isnan(zs).any(axis=1)):
            # z = A x + c + noise, A and the noise zero on the observed rows o;
            # the missing rows given the observed: H_μ x + L (z_o - H_o x) + noise.
            o = ~np.isnan(zs[t])
            mis = ~o
            A, c, E = np.zeros((m, n)), np.where(o, zs[t], 0.0), np.zeros((m, m))
            L = np.linalg.solve(R[t][np.ix_(o, o)], R[t][np.ix_(o, mis)]).T if o.any() else np.zeros((mis.sum(), 0))
            A[mis] = H[t][mis] - L @ H[t][o]
            c[mis] = L @ zs[t][o]
            E[np.ix_(mis, mis)] = R[t][np.ix_(mis, mis)] - L @ R[t][np.ix_(o, mis)]
            nu[t, :m] = A @ mean[t + 1] + c
            tau[t, :m, :m] = A @ cov[t + 1] @ A.T + E
            tau[t, :m, m:m + n] = A @ cov[t + 1]
            tau[t, m:m + n, :m] = tau[t, :m, m:m + n].T
        self.Psi = tau + nu[:, :, None] * nu[:, None, :]
        self.x0_mean, self.x0_cov = mean[0], cov[0]
        self.n, self.m, self.p, self.T = n, m, p, T

    # selectors into s_t = (x_t, x_{t-1}, u_t, 1) and r_t = (z_t, x_t, 1)
    def w_map(self, F: np.ndarray, B: np.ndarray | None) -> np.ndarray:
        """``[I, -F_t, -B_t, 0]`` of shape (T, n, d)."""
        n, p, T = self.n, self.p, self.T
        W = np.zeros((T, n, 2 * n + p + 1))
        W[:, :, :n] = np.eye(n)
        W[:, :, n:2 * n] = -_per_step(F, T)
        if p:
            W[:, :, 2 * n:2 * n + p] = -_per_step(B, T)
        return W

    def v_map(self, H: np.ndarray) -> np.ndarray:
        """``[I, -H_t, 0]`` of shape (T, m, e)."""
        m, n, T = self.m, self.n, self.T
        V = np.zeros((T, m, m + n + 1))
        V[:, :, :m] = np.eye(m)
        V[:, :, m:m + n] = -_per_step(H, T)
        return V


def _quad(M: np.ndarray, S: np.ndarray, N: np.ndarray | None = None) -> np.ndarray:
    """``M_t S_t N_tᵀ`` for each t (N defaults to M)."""
    return M @ S @ np.swapaxes(M if N is None else N, -1, -2)


# ---------------------------------------------------------------------------
# EM
# ---------------------------------------------------------------------------


def _structured(cov: np.ndarray, structure: str) -> np.ndarray:
    if structure == "diagonal":
        return np.diag(np.diag(cov))
    if structure == "scalar":
        return np.mean(np.diag(cov)) * np.eye(cov.shape[0])
    return symmetrize(cov)


def _m_step(model: LinearModel, prior, stats: list[Statistics], learn: tuple, structure: dict):
    n, p = model.n, model.p
    F, H, Q, R, B = model.F, model.H, model.Q, model.R, model.B
    T_all = sum(s.T for s in stats)
    Phi = [s.Phi for s in stats]
    if "F" in learn or "B" in learn:
        # Regress x_t on the learned regressors, the known parts moved to the target.
        rows = ([np.arange(n, 2 * n)] if "F" in learn else []) + \
               ([np.arange(2 * n, 2 * n + p)] if "B" in learn else [])
        sel = np.concatenate(rows)
        Fk = np.zeros_like(F) if "F" in learn else F
        Bk = (np.zeros_like(B) if "B" in learn else B) if p else None
        lhs = sum(np.sum((s.w_map(Fk, Bk) @ ph)[:, :, sel], axis=0) for s, ph in zip(stats, Phi))
        gram = sum(np.sum(ph[:, sel][:, :, sel], axis=0) for ph in Phi)
        coef = np.linalg.solve(gram, lhs.T).T
        if "F" in learn:
            F, coef = coef[:, :n], coef[:, n:]
        if "B" in learn:
            B = coef
    if "Q" in learn:
        Q = _structured(sum(np.sum(_quad(s.w_map(F, B), ph), axis=0) for s, ph in zip(stats, Phi)) / T_all,
                        structure["Q"])
    m = model.m
    if "H" in learn:
        zx = sum(np.sum(s.Psi[:, :m, m:m + n], axis=0) for s in stats)
        xx = sum(np.sum(s.Psi[:, m:m + n, m:m + n], axis=0) for s in stats)
        H = np.linalg.solve(xx, zx.T).T
    if "R" in learn:
        R = _structured(sum(np.sum(_quad(s.v_map(H), s.Psi), axis=0) for s in stats) / T_all, structure["R"])
    new_prior = prior
    if "m0" in learn or "P0" in learn:
        m0 = np.mean([s.x0_mean for s in stats], axis=0) if "m0" in learn else prior.mean
        P0 = prior.cov
        if "P0" in learn:
            P0 = np.mean([s.x0_cov + np.outer(s.x0_mean - m0, s.x0_mean - m0) for s in stats], axis=0)
            P0 = _structured(P0, structure["P0"])
        new_prior = Gaussian(m0, P0)
    return LinearModel(F, H, Q, R, B), new_prior


def _e_step(model, prior, zs, us, engine: str = "auto") -> tuple[float, list[Statistics]]:
    loglik, stats = 0.0, []
    for i, z in enumerate(zs):
        u = None if us is None else us[i]
        mom = moments(model, prior, z, u, engine)
        loglik += mom.loglik
        stats.append(Statistics(model, mom, z, u))
    return loglik, stats


def _em(model, prior, zs, us, learn, structure, iterations, tol, callback, engine):
    history: list[float] = []
    best = (model, prior)
    message, converged = f"stopped after {iterations} iterations", False
    try:
        for it in range(iterations + 1):
            loglik, stats = _e_step(model, prior, zs, us, engine)
            history.append(loglik)
            best = (model, prior)
            if callback is not None:
                callback(it, loglik)
            if it > 0 and abs(history[-1] - history[-2]) <= tol * (1.0 + abs(history[-1])):
                message, converged = "converged: the log-likelihood changed by less than `tol`", True
                break
            if it == iterations:
                break
            model, prior = _m_step(model, prior, stats, learn, structure)
    except KeyboardInterrupt:
        if not history:
            raise
        message = "interrupted: the best model so far"
    model, prior = best
    return FitResult(model, prior, history[-1], np.array(history), "em", converged, message)


# ---------------------------------------------------------------------------
# Maximum likelihood
# ---------------------------------------------------------------------------


class _Parametrisation:
    """Unconstrained parameters θ ↔ the learned matrices."""

    def __init__(self, model: LinearModel, prior, learn: tuple, structure: dict):
        self.model, self.prior, self.learn, self.structure = model, prior, learn, structure
        self.sizes = [self._encode(name, self._current(name)).size for name in learn]

    def _current(self, name: str) -> np.ndarray:
        if name == "m0":
            return self.prior.mean
        if name == "P0":
            return self.prior.cov
        return getattr(self.model, name)

    def _encode(self, name: str, value: np.ndarray) -> np.ndarray:
        if name not in COVARIANCES:
            return value.ravel()
        kind = self.structure[name]
        if kind == "scalar":
            return np.array([np.log(np.mean(np.diag(value)))])
        if kind == "diagonal":
            return np.log(np.diag(value))
        L = np.linalg.cholesky(value)
        rows, cols = np.tril_indices(value.shape[0])
        out = L[rows, cols].copy()
        out[rows == cols] = np.log(out[rows == cols])
        return out

    def _decode(self, name: str, theta: np.ndarray) -> np.ndarray:
        shape = self._current(name).shape
        if name not in COVARIANCES:
            return theta.reshape(shape)
        kind, k = self.structure[name], shape[0]
        if kind == "scalar":
            return np.exp(theta[0]) * np.eye(k)
        if kind == "diagonal":
            return np.diag(np.exp(theta))
        L = np.zeros(shape)
        rows, cols = np.tril_indices(k)
        L[rows, cols] = np.where(rows == cols, np.exp(theta), theta)
        return L @ L.T

    def encode(self) -> np.ndarray:
        return np.concatenate([self._encode(n, self._current(n)) for n in self.learn])

    def split(self, theta: np.ndarray) -> dict:
        out, start = {}, 0
        for name, size in zip(self.learn, self.sizes):
            out[name] = theta[start:start + size]
            start += size
        return out

    def __call__(self, theta: np.ndarray):
        parts = {name: self._decode(name, t) for name, t in self.split(theta).items()}
        model = self.model
        mats = {k: parts.get(k, getattr(model, k)) for k in ("F", "H", "Q", "R", "B")}
        prior = self.prior
        if "m0" in parts or "P0" in parts:
            prior = Gaussian(parts.get("m0", prior.mean), parts.get("P0", prior.cov))
        return LinearModel(**mats), prior

    def chain(self, theta: np.ndarray, grads: dict) -> np.ndarray:
        """dℓ/dθ from the matrix gradients dℓ/dM (symmetric for covariances)."""
        out = []
        for name, t in self.split(theta).items():
            G = grads[name]
            if name not in COVARIANCES:
                out.append(G.ravel())
                continue
            kind = self.structure[name]
            if kind == "scalar":
                out.append(np.array([np.trace(G) * np.exp(t[0])]))
            elif kind == "diagonal":
                out.append(np.diag(G) * np.exp(t))
            else:
                k = G.shape[0]
                rows, cols = np.tril_indices(k)
                L = np.zeros((k, k))
                L[rows, cols] = np.where(rows == cols, np.exp(t), t)
                dL = 2.0 * G @ L
                g = dL[rows, cols]
                g[rows == cols] *= np.diag(L)
                out.append(g)
        return np.concatenate(out)


def _matrix_gradients(model: LinearModel, prior, stats: list[Statistics]) -> dict:
    """dℓ/dM for every matrix M, per step (T, ...) summed over series, by Fisher's identity."""
    n, m = model.n, model.m
    T = stats[0].T
    Q, R = _per_step(model.Q, T), _per_step(model.R, T)
    g = {k: 0.0 for k in ("F", "H", "Q", "R", "B")}
    for s in stats:
        W = s.w_map(model.F, model.B)
        g["Q"] = g["Q"] + _covariance_gradient(Q, _quad(W, s.Phi))
        wS = (W @ s.Phi)                                          # E[w sᵀ], (T, n, d)
        g["F"] = g["F"] + np.linalg.solve(Q, wS[:, :, n:2 * n])
        if model.B is not None:
            g["B"] = g["B"] + np.linalg.solve(Q, wS[:, :, 2 * n:2 * n + s.p])
        V = s.v_map(model.H)
        g["R"] = g["R"] + _covariance_gradient(R, _quad(V, s.Psi))
        g["H"] = g["H"] + np.linalg.solve(R, (V @ s.Psi)[:, :, m:m + n])
    if not isinstance(prior, str):
        dev = [s.x0_mean - prior.mean for s in stats]
        g["m0"] = sum(np.linalg.solve(prior.cov, d) for d in dev)
        second = sum(s.x0_cov + np.outer(d, d) for s, d in zip(stats, dev))
        P = prior.cov
        g["P0"] = _covariance_gradient(P, second, count=len(stats))
    return g


def _covariance_gradient(C: np.ndarray, second: np.ndarray, count: int = 1) -> np.ndarray:
    """``½ C⁻¹ (E[e eᵀ] - count·C) C⁻¹``: dℓ/dC of ``count`` Gaussian terms with residual second moment `second`."""
    inner = np.linalg.solve(C, second - count * C)
    return 0.5 * np.linalg.solve(C, np.swapaxes(inner, -1, -2))


def _summed(g: dict, model: LinearModel) -> dict:
    """Per-step gradients summed for the time-invariant matrices."""
    out = dict(g)
    for k in ("F", "H", "Q", "R", "B"):
        a = getattr(model, k)
        if a is not None and a.ndim == 2 and np.ndim(g[k]) == 3:
            out[k] = symmetrize(g[k].sum(axis=0)) if k in COVARIANCES else g[k].sum(axis=0)
    return out


def _mle(model, prior, zs, us, learn, structure, iterations, tol, callback, engine, params=None, x0=None):
    if params is None:
        param = _Parametrisation(model, prior, learn, structure)
        theta0 = param.encode()
        build = param
    else:
        theta0 = np.asarray(x0, dtype=np.float64).ravel()
        build = _UserParams(params, prior)
    n_obs = max(int(np.sum(~np.isnan(zs))), 1)
    cache: dict[bytes, tuple[float, np.ndarray]] = {}

    def evaluate(theta: np.ndarray) -> tuple[float, np.ndarray]:
        key = theta.tobytes()
        if key not in cache:
            mdl, pri = build(theta)
            ll, stats = _e_step(mdl, pri, zs, us, engine)
            g = _matrix_gradients(mdl, pri, stats)
            grad = build.chain(theta, _summed(g, mdl) if params is None else g)
            cache[key] = (ll, grad)
        return cache[key]

    history: list[float] = []
    best = [theta0, -np.inf]

    def objective(theta):
        ll, grad = evaluate(theta)
        if ll > best[1]:
            best[0], best[1] = theta.copy(), ll
        return -ll / n_obs, -grad / n_obs

    def on_iteration(theta):
        history.append(evaluate(theta)[0])
        if callback is not None:
            callback(len(history), history[-1])

    history.append(evaluate(theta0)[0])
    if callback is not None:
        callback(0, history[0])
    from scipy import optimize

    try:
        res = optimize.minimize(objective, theta0, jac=True, method="BFGS", callback=on_iteration,
                                options={"maxiter": iterations, "gtol": tol})
        theta, converged, message = res.x, bool(res.success), str(res.message)
        if evaluate(theta)[0] < best[1]:
            theta = best[0]
    except KeyboardInterrupt:
        theta, converged, message = best[0], False, "interrupted: the best model so far"
    mdl, pri = build(theta)
    ll = evaluate(theta)[0]
    if not history or history[-1] != ll:
        history.append(ll)
    errors = _standard_errors(evaluate, build, theta, learn if params is None else None)
    return FitResult(mdl, pri, ll, np.array(history), "mle", converged, message, errors)


class _UserParams:
    """A user's function θ → model (or (model, prior)), with its chain rule by central differences."""

    def __init__(self, fn: Callable, prior):
        self.fn, self.prior = fn, prior

    def __call__(self, theta: np.ndarray):
        out = self.fn(theta.copy())
        model, prior = (out if isinstance(out, tuple) else (out, self.prior))
        if not isinstance(model, LinearModel):
            raise TypeError(f"`params` must return a LinearModel (or (LinearModel, Gaussian)); "
                            f"got {type(model).__name__}.")
        return model, check_prior(prior, model.n, diffuse_ok=True)

    def chain(self, theta: np.ndarray, grads: dict) -> np.ndarray:
        out = np.zeros_like(theta)
        for j in range(theta.size):
            h = 1e-6 * max(1.0, abs(theta[j]))
            up, down = theta.copy(), theta.copy()
            up[j] += h
            down[j] -= h
            (m1, p1), (m2, p2) = self(up), self(down)
            total = 0.0
            for k in ("F", "H", "Q", "R", "B"):
                a, b = getattr(m1, k), getattr(m2, k)
                if a is not None:
                    G = grads[k]
                    dM = (a - b) / (2 * h)
                    total += np.sum(G * (dM if dM.ndim == np.ndim(G) else np.broadcast_to(dM, np.shape(G))))
            if not isinstance(p1, str) and "m0" in grads:
                total += grads["m0"] @ (p1.mean - p2.mean) / (2 * h)
                total += np.sum(grads["P0"] * (p1.cov - p2.cov)) / (2 * h)
            out[j] = total
        return out


def _standard_errors(evaluate, build, theta: np.ndarray, learn) -> dict | None:
    """Standard errors from the observed information, by central differences of the exact gradient."""
    k = theta.size
    hess = np.zeros((k, k))
    for j in range(k):
        h = 1e-5 * max(1.0, abs(theta[j]))
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        hess[:, j] = (evaluate(up)[1] - evaluate(down)[1]) / (2 * h)
    hess = 0.5 * (hess + hess.T)
    try:
        cov_theta = np.linalg.solve(-hess, np.eye(k))
    except np.linalg.LinAlgError:
        return None
    if learn is None:
        return {"params": np.sqrt(np.clip(np.diag(cov_theta), 0, None))}
    # Delta method: the learned matrices' entries as functions of θ.
    def natural(t):
        mdl, pri = build(t)
        return np.concatenate([(getattr(pri, {"m0": "mean", "P0": "cov"}[n]) if n in ("m0", "P0")
                                else getattr(mdl, n)).ravel() for n in learn])

    J = np.zeros((natural(theta).size, k))
    for j in range(k):
        h = 1e-6 * max(1.0, abs(theta[j]))
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        J[:, j] = (natural(up) - natural(down)) / (2 * h)
    se = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", J, cov_theta, J), 0, None))
    out, start = {}, 0
    mdl, pri = build(theta)
    for name in learn:
        shape = (pri.mean if name == "m0" else pri.cov if name == "P0" else getattr(mdl, name)).shape
        size = int(np.prod(shape))
        out[name] = se[start:start + size].reshape(shape)
        start += size
    return out


# ---------------------------------------------------------------------------
# The front function
# ---------------------------------------------------------------------------


def _check_learn(model: LinearModel, prior, learn, structure) -> tuple[tuple, dict]:
    if isinstance(learn, str):
        learn = (learn,)
    learn = tuple(learn)
    unknown = [k for k in learn if k not in LEARNABLE]
    if unknown or not learn or len(set(learn)) != len(learn):
        raise ValueError(f"`learn` must name distinct entries of {list(LEARNABLE)}; got {list(learn)}.")
    for name in learn:
        if name in ("m0", "P0"):
            if isinstance(prior, str):
                raise ValueError(f"`learn` cannot include {name!r} with a diffuse prior.")
            continue
        a = getattr(model, name)
        if a is None:
            raise ValueError(f"`learn` includes 'B' but the model has no control input; give it an initial `B`.")
        if a.ndim == 3:
            raise ValueError(f"`learn` includes {name!r}, which is time-varying in the model; "
                             "only time-invariant matrices can be learned.")
    if ("F" in learn or "B" in learn) and model.Q.ndim == 3:
        raise ValueError("learning F or B needs a time-invariant `Q`.")
    if "H" in learn and model.R.ndim == 3:
        raise ValueError("learning H needs a time-invariant `R`.")
    structure = {} if structure is None else dict(structure)
    for name, kind in structure.items():
        if name not in COVARIANCES or kind not in STRUCTURES:
            raise ValueError(f"`structure` maps {list(COVARIANCES)} to one of {list(STRUCTURES)}; "
                             f"got {name!r}: {kind!r}.")
    return learn, {k: structure.get(k, "full") for k in COVARIANCES}


def fit(
    model: LinearModel,
    prior: Gaussian | str,
    zs,
    us=None,
    *,
    learn=("Q", "R"),
    method: str = "em",
    structure: dict | None = None,
    iterations: int | None = None,
    tol: float | None = None,
    params: Callable | None = None,
    x0=None,
    callback: Callable[[int, float], None] | None = None,
    engine: str = "auto",
) -> FitResult:
    """Learn a linear-Gaussian model's matrices from measurements.

    Parameters
    ----------
    model : LinearModel
        The starting point; matrices not learned stay as they are (they may
        be time-varying).
    prior : Gaussian or "diffuse"
        The prior, one step before the first measurement (see :func:`filter`).
    zs : array_like of shape (T, m), (T,) or (N, T, m)
        Measurements; NaN = missing. N series share one set of parameters
        and are pooled.
    us : array_like of shape (T, p) or (N, T, p), optional
        Controls, when the model has ``B``.
    learn : sequence of str, default ("Q", "R")
        Which of ``"F", "H", "Q", "R", "B", "m0", "P0"`` to learn (m0 and
        P0 are the prior's mean and covariance).
    method : {"em", "mle"}, default "em"
        Expectation–maximisation, or maximum likelihood by BFGS with the
        exact gradient.
    structure : dict, optional
        ``{"Q" | "R" | "P0": "full" | "diagonal" | "scalar"}``: how a
        learned covariance is constrained (default full). Learned
        covariances stay symmetric positive definite.
    iterations : int, optional
        Maximum iterations (EM: 500; MLE: 1000).
    tol : float, optional
        EM stops when the log-likelihood changes by less than
        ``tol * (1 + |loglik|)`` (default 1e-10); MLE when the gradient norm
        per observation is below `tol` (default 1e-8).
    params : callable, optional
        For structured models (MLE only): ``params(theta) -> LinearModel`` or
        ``(LinearModel, Gaussian)``; `learn` and `structure` are then ignored.
    x0 : array_like, optional
        Starting `theta` for `params`.
    callback : callable, optional
        ``callback(iteration, loglik)`` after each iteration (progress).
    engine : {"auto", "python", "numba"}, default "auto"
        Engine of the filter and smoother runs; "auto" compiles whenever
        numba is installed, since a fit runs them many times.

    Returns
    -------
    FitResult
        ``.model``, ``.prior``, ``.loglik``, ``.history``; Ctrl-C during the
        fit returns the best model so far with ``converged=False``.

    Examples
    --------
    The Nile local level model (Durbin & Koopman, 2012, section 2.10):

    >>> import gaussfuse as gf
    >>> from gaussfuse.datasets import nile
    >>> _, flow = nile()
    >>> start = gf.LinearModel(F=1, H=1, Q=1000.0, R=10000.0)
    >>> res = gf.fit(start, "diffuse", flow, method="mle")
    >>> round(float(res.model.R[0, 0])), round(float(res.model.Q[0, 0]), 1)
    (15099, 1469.1)
    """
    if not isinstance(model, LinearModel):
        raise TypeError(f"`model` must be a gaussfuse.LinearModel; got {type(model).__name__}.")
    if method not in METHODS:
        raise ValueError(f"`method` must be one of {list(METHODS)}; got {method!r}.")
    prior = check_prior(prior, model.n, diffuse_ok=True)
    zs = check_measurements(zs, model.m)
    _check_steps(model, zs.shape[1])
    us = check_controls(us, model, zs.shape[0], zs.shape[1])
    if iterations is None:
        iterations = 500 if method == "em" else 1000
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise ValueError(f"`iterations` must be a positive integer; got {iterations!r}.")
    if engine not in ENGINES:
        raise ValueError(f"`engine` must be one of {list(ENGINES)}; got {engine!r}.")
    if engine == "auto":
        engine = "numba" if importlib.util.find_spec("numba") is not None else "python"
    if tol is None:
        tol = 1e-10 if method == "em" else 1e-8
    if not np.isfinite(tol) or tol < 0:
        raise ValueError(f"`tol` must be a non-negative number; got {tol!r}.")
    if params is not None:
        if method != "mle":
            raise ValueError("`params` (a structured model) needs method='mle'.")
        if x0 is None:
            raise ValueError("`x0`, the starting parameters, is required with `params`.")
        return _mle(model, prior, zs, us, (), {}, iterations, tol, callback, engine, params, x0)
    learn, structure = _check_learn(model, prior, learn, structure)
    run = _em if method == "em" else _mle
    return run(model, prior, zs, us, learn, structure, iterations, tol, callback, engine)

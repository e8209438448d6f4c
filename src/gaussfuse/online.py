"""Online filtering: one predict or update at a time, with filterpy's names where they fit."""

from __future__ import annotations

import copy

import numpy as np

from . import kalman
from ._linalg import symmetrize
from ._validation import as_array, as_matrix, check_psd, integer, real, shape_error
from .diagnostics import DivergenceMonitor
from .errors import STEP_ERRORS, at_step
from .gaussian import Gaussian
from .inference.registry import linearisation, resolve_method
from .inference.validation import check_form, check_model, check_prior, check_semidefinite
from .models.compose import TimedModel, probe_step
from .models.linear import LinearModel
from .models.motion import LinearMotion

__all__ = ["KalmanFilter"]


def _fixed(name: str, read, doc: str) -> property:
    """A setting of a :class:`KalmanFilter` that is read, and whose assignment says where it goes instead.

    filterpy's filters are configured by assignment (``f.Q = ...``); here the
    model is fixed when the filter is made, and an assignment that made an
    unused attribute left the estimates as they were, silently.
    """
    per_call = {"F": "kf.predict(F=...)", "Q": "kf.predict(Q=...)", "H": "kf.update(z, H=...)",
                "R": "kf.update(z, R=...)"}.get(name)

    def refuse(self, value):
        one_call = f"pass it for one step to {per_call}, or " if per_call else ""
        raise AttributeError(f"`{name}` of a KalmanFilter cannot be assigned (the model is fixed when the filter is "
                             f"made): {one_call}make a new KalmanFilter(model, kf.belief, ...) whose model has it.")

    return property(read, refuse, doc=doc)


def _not_offered(name: str, what: str) -> property:
    """A filterpy setting that a :class:`KalmanFilter` does not have: reading or assigning it says so.

    Assigned on a plain object, it would make an attribute nothing reads, and the estimates would go on without
    it, silently (audit LL2: ``kf.alpha = 1.05``, filterpy's fading memory, left P as it was).
    """
    def refuse(self, value=None):
        raise AttributeError(f"a KalmanFilter has no `{name}`: {what}")

    return property(refuse, refuse, doc=f"Not offered (filterpy's `{name}`): {what}")


class KalmanFilter:
    """A Kalman filter that takes measurements as they arrive.

    Parameters
    ----------
    model : LinearModel, NonlinearModel or TimedModel
        The model; for a time-varying one, the k-th call of :meth:`predict`
        uses its matrices at step k (counting from 0), and :meth:`update`
        those of the step last predicted. A TimedModel (built by
        :func:`gaussfuse.model` without dt) is discretised for the `dt` of
        each :meth:`predict`.
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
        whole run), and, for gated updates, its test of a gate that rejects
        at least half (a lost track), itself at most 1e-3 (so 2e-3 for the
        two together, where :func:`gaussfuse.filter`, which knows of its
        gate from the start, halves each): a :class:`gaussfuse.DivergenceWarning`
        naming the steps, raised with ``"raise"``. A window is tested once
        it is full, from the 50th update with an observation on: a shorter
        run is not tested, where :func:`gaussfuse.filter` tests a shorter
        series whole.
    method : str, optional
        How the model is made affine (:data:`gaussfuse.METHODS`): "kf" for
        a LinearModel, "ukf" by default for a NonlinearModel.
    **options
        The method's options (``alpha``, ``order``, ``iterations``, ...).

    Attributes
    ----------
    belief : Gaussian
        The current belief.
    x : ndarray of shape (n,)
        Its mean. Settable; a copy that may also be changed in place
        (``kf.x[0] = 3.0``): the next step starts from what it holds.
    P : ndarray of shape (n, n)
        Its covariance, likewise (``kf.P *= 1000``); checked to be
        symmetric positive semi-definite when the next step reads it.
    L : ndarray of shape (n, n)
        A lower-triangular factor of it, ``P = L Lᵀ``: the one the
        square-root form propagates (computed from P for the covariance
        form).
    model, method, form : LinearModel or NonlinearModel, str, str
        As given (read-only).
    F, H, Q, R, B : ndarray
        The model's matrices (read-only: assigning one is an error that
        says how to change it, as filterpy's ``f.Q = ...`` would not work,
        and so is reading or assigning filterpy's ``alpha``, ``M`` and
        ``inv``, which are not offered);
        for a TimedModel, those of the last step predicted (before the
        first, of a step of 1 s, or shorter where that overflows).
    step : int
        Number of predictions made so far; settable (to a non-negative
        integer), to start a time-varying model's steps again, say.
    loglik : float
        Sum of the log-likelihood contributions of the updates so far.
    x_prior, P_prior : ndarray
        The last prediction (after :meth:`predict`); read-only.
    x_post, P_post : ndarray
        The last posterior (after :meth:`update`); read-only.
    y : ndarray of shape (m,)
        The last update's innovation ``z - (H x + d)``; NaN where missing.
    S : ndarray of shape (m, m)
        Its covariance ``H P Hᵀ + R``; read-only (once the covariances
        settle, every update's S is the same array).
    K : ndarray of shape (n, m)
        The gain applied, with zero columns for missing components.
    log_likelihood : float
        The last update's log-likelihood term.
    mahalanobis : float
        ``sqrt(yᵀ S⁻¹ y)`` over the observed components (NaN when nothing
        was observed).

    Notes
    -----
    ``predict(u_k)`` then ``update(z_k)`` for k = 0..T-1 is exactly
    :func:`gaussfuse.filter` on the same series: the two halves of
    :func:`gaussfuse.kalman.step`, :func:`~gaussfuse.kalman.forecast` and
    :func:`~gaussfuse.kalman.correct`. ``predict(F=..., Q=...)`` and
    ``update(z, H=..., R=...)`` replace the model's matrices for that call
    only (for a NonlinearModel, Q and R); ``update(None)`` skips a missing
    measurement, as filterpy's does.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=[[1, 0], [0, 3]], R=10)
    >>> kf = gf.KalmanFilter(model, gf.Gaussian([0, 1], 500 * np.eye(2)))
    >>> for z in [1, 2, 3, 2, 1]:
    ...     _ = kf.predict()
    ...     _ = kf.update(z)
    >>> kf.x.shape, kf.P.shape, kf.K.shape
    ((2,), (2, 2), (2, 1))
    """

    def __init__(self, model, prior: Gaussian, form: str = "cov", check: str = "warn", method: str | None = None,
                 **options) -> None:
        check_model(model)  # (the registry's message named neither TimedModel nor a motion's mistake: audit WW3)
        self.timed = model if isinstance(model, TimedModel) else None
        if self.timed is not None:
            model, self._timed_p = _one_step(self.timed)
        spec, options = resolve_method(model, method, options, KalmanFilter)
        check_form(spec, form)
        self._monitor = DivergenceMonitor.for_check(check)
        self._model, self._method, self._form = model, spec.name, form
        self._spec, self._options = spec, options
        self._belief = check_prior(prior, model.n)
        self._views: dict[str, np.ndarray] = {}  # x and P as handed out, for in-place changes
        self._factor: tuple[Gaussian, np.ndarray] | None = None  # (belief, its factor) in the square-root form
        self._roots = kalman.Factors()
        self._step = 0
        self.loglik = 0.0
        self._controls: dict = {}  # u_k of the step being predicted, for the strategy
        self._lin, self._iterations, self._tol = linearisation(spec, model, self._controls, options)
        self._angles = tuple(None if a is None or not np.any(a) else np.asarray(a, dtype=bool)
                             for a in (getattr(model, "state_angles", None), getattr(model, "measurement_angles", None)))
        self._steady = self._fresh_steady()
        self.x_prior = self.P_prior = self.x_post = self.P_post = None
        self.y = self.S = self.K = self.rejected = None
        self.log_likelihood = self.mahalanobis = np.nan

    model = _fixed("model", lambda self: self.timed or self._model, "The model as given (read-only).")
    method = _fixed("method", lambda self: self._method, "The method's name (read-only).")
    form = _fixed("form", lambda self: self._form, 'The form, "cov" or "sqrt" (read-only).')
    F, H, Q, R, B = (_fixed(name, lambda self, name=name: getattr(self._model, name), f"The model's {name} (read-only).")
                     for name in "FHQRB")
    alpha = _not_offered("alpha", "filterpy's fading memory (P⁻ = α² F P Fᵀ + Q) is not offered; a larger Q, for "
                                  "one step with kf.predict(Q=...) or in the model, widens the prediction instead.")
    M = _not_offered("M", "filterpy's cross-covariance of the process and measurement noises is not offered; "
                          "correlated noises need the state augmented with the noise they share.")
    inv = _not_offered("inv", "the gain is found by Cholesky solves with S, never by inverting it, so there is no "
                              "inverse to choose.")

    def _fresh_steady(self) -> kalman.SteadyState | None:
        """A time-invariant model's covariances reach a fixed point that steps then reuse, exactly."""
        if self.timed is not None:  # each step its own dt: no fixed point
            return None
        return kalman.SteadyState() if getattr(self._lin, "invariant", False) and self._iterations == 1 else None

    def __getstate__(self) -> dict:
        # pickles and copies keep the read-only arrays (x_prior, y, ...) read-only, and the belief's arrays
        # themselves: the fixed point is held by the very covariance (and factor) object, which a Gaussian,
        # pickled by copying its arrays, lost (audit DD3: a copy then differed from the original by 4e-16)
        state = dict(self.__dict__)
        state["_readonly"] = [name for name, v in state.items() if isinstance(v, np.ndarray) and not v.flags.writeable]
        state["_belief"] = (self._belief.mean, self._belief.cov)
        if self._factor is not None:
            state["_factor"] = self._factor[1] if self._factor[0] is self._belief else None
        return state

    def __copy__(self) -> KalmanFilter:
        # a copy steps on its own: a shallow one would share the handed-out x and P, the divergence monitor,
        # the steady state and the controls with the original
        return copy.deepcopy(self)

    def __setstate__(self, state: dict) -> None:
        readonly = state.pop("_readonly", ())
        if "step" in state:  # (pickled before `step` was a checked property)
            state["_step"] = state.pop("step")
        self.__dict__.update(state)
        self._belief = Gaussian._trusted(*state["_belief"])
        self._factor = None if state["_factor"] is None else (self._belief, state["_factor"])
        for name in readonly:
            self.__dict__[name].setflags(write=False)
        if isinstance(self.__dict__.get("S"), np.ndarray) and self.S.flags.writeable:  # pickled before S was
            S = self.S.view()  # read-only, it may share the steady state's array (review R44)
            S.setflags(write=False)
            self.S = S

    def __repr__(self) -> str:
        return (f"KalmanFilter({self.model!r}, method={self.method!r}, form={self.form!r}, step={self.step}, "
                f"loglik={self.loglik:.6g})")

    @property
    def step(self) -> int:
        """Number of predictions made so far: the step of a time-varying model the next one takes; settable, to a
        non-negative integer."""
        return self._step

    @step.setter
    def step(self, value: int) -> None:
        self._step = integer("step", value, minimum=0)

    # -- the belief, and filterpy's x and P --------------------------------

    @property
    def belief(self) -> Gaussian:
        """The current belief, including changes made in place to :attr:`x` and :attr:`P`; settable."""
        self._adopt_views()
        return self._belief

    @belief.setter
    def belief(self, value: Gaussian) -> None:
        self._belief = check_prior(value, self._model.n, name="belief")
        self._views.clear()
        self._steady = self._fresh_steady()  # the recursion starts again from a belief set by hand

    @property
    def x(self) -> np.ndarray:
        """The belief's mean, shape (n,): a writable copy whose in-place changes count; settable."""
        return self._view("x", self.belief.mean)

    @x.setter
    def x(self, value) -> None:
        self._views.pop("x", None)  # replaced: what the old copy holds no longer counts
        self.belief = self._checked(value, self.belief.cov)

    @property
    def P(self) -> np.ndarray:
        """The belief's covariance, shape (n, n): a writable copy whose in-place changes count; settable."""
        return self._view("P", self.belief.cov)

    @P.setter
    def P(self, value) -> None:
        self._views.pop("P", None)
        self.belief = self._checked(self.belief.mean, value)

    def _checked(self, x, P) -> Gaussian:
        """``Gaussian(x, P)``, its errors naming `x` and `P` (filterpy's names, the ones the user wrote)."""
        return Gaussian._named(x, P, self._model.n, ("x", "P"))

    def _view(self, name: str, value: np.ndarray) -> np.ndarray:
        """A writable copy of the belief's `value`, the same one until the belief changes."""
        if name not in self._views:
            self._views[name] = np.array(value)
        return self._views[name]

    def _adopt_views(self) -> None:
        """Make the belief what the handed-out x and P now hold, if they were changed in place. They stay handed
        out, holding the belief as adopted: a later change to either counts too (audit AA1: reading P took in a
        change to x, and then dropped x, so its next change was lost)."""
        views = dict(self._views)
        x, P = views.get("x"), views.get("P")
        if (x is None or np.array_equal(x, self._belief.mean)) and (P is None or np.array_equal(P, self._belief.cov)):
            return
        self.belief = self._checked(self._belief.mean if x is None else x, self._belief.cov if P is None else P)
        for name, held in views.items():
            np.copyto(held, self._belief.mean if name == "x" else self._belief.cov)
        self._views.update(views)

    @property
    def L(self) -> np.ndarray:
        """A lower-triangular factor of the belief's covariance, ``P = L Lᵀ``, shape (n, n); read-only, as the
        belief's arrays are (the square-root form steps on from it: a write into it changed the next step's
        covariance, while `P` still showed the old one)."""
        view = self._own_factor().view()
        view.setflags(write=False)
        return view

    def _own_factor(self) -> np.ndarray:
        """The belief's factor itself, which the square-root form steps from: the fixed point is held by that very
        object (a view of it, as :attr:`L` hands out, never reused it: audit DD3)."""
        belief = self.belief
        if self._factor is None or self._factor[0] is not belief:  # a belief set by hand, or the prior
            self._factor = (belief, kalman.cov_factor(belief.cov, "the belief's covariance"))
        return self._factor[1]

    def _set(self, mean: np.ndarray, factor: np.ndarray) -> Gaussian:
        """Make ``N(mean, L Lᵀ)`` the belief, remembering its factor L."""
        self._belief = Gaussian._trusted(mean, symmetrize(factor @ factor.T))
        self._factor = (self._belief, factor)
        return self._belief

    def _check_step(self, k: int) -> None:
        steps = getattr(self._model, "steps", None)
        if steps is not None and not 0 <= k < steps:
            raise ValueError(f"the time-varying model has {steps} steps; step {k} is beyond it.")

    # -- predict and update -------------------------------------------------

    def predict(self, u=None, F=None, Q=None, dt: float | None = None) -> Gaussian:
        """Advance the belief one step.

        Parameters
        ----------
        u : array_like of shape (p,), optional
            The control input, when the model has B (or its f takes one).
        F : array_like of shape (n, n), optional
            The transition matrix for this step only (a LinearModel).
        Q : array_like of shape (n, n), optional
            The process noise covariance for this step only.
        dt : float, optional
            The time step, for a model built by :func:`gaussfuse.model`
            without dt (a TimedModel), which it requires: the step is
            discretised for it exactly.

        Returns
        -------
        Gaussian
            The prediction, also in ``x_prior`` and ``P_prior``.
        """
        belief = self.belief
        k = self._step
        self._check_step(k)
        self._functions_not_matrices(F=F)
        # a NonlinearModel's too, when it knows its f's controls (audit AA1); a TimedModel's, its motion's (its
        # nonlinear steps take dt as a control of their own, which the user does not give: audit DD3)
        p = getattr(self._model, "p", None) if self.timed is None else self._timed_p
        if p == 0 and u is not None:
            raise ValueError("`u` was given but the model has no control input"
                             + ("; its motion takes none." if self.timed is not None else "; give the model `B`."
                                if isinstance(self._model, LinearModel) else "."))
        if u is None and p:
            raise ValueError(f"`u` is required: the model has a control input with p = {p}.")
        if u is not None:
            u = np.atleast_1d(as_array("u", u))
            if u.ndim != 1 or (p is not None and u.shape != (p,)):
                raise shape_error("u", f"({p if p is not None else 'p'},)", u.shape)
        last = self._model, self._lin  # a TimedModel's step: kept if this one fails (audit LL4)
        try:
            if dt is not None or self.timed is not None:
                u = self._discretise(dt, u)
            self._predict(k, belief, u, F, Q)
        except BaseException:
            self._model, self._lin = last
            raise
        return self._belief

    def _predict(self, k: int, belief: Gaussian, u, F, Q) -> None:
        """:meth:`predict` of step k from `belief`, once its control `u` is checked (and its TimedModel's step
        made)."""
        self._controls.clear()
        self._controls[k] = u
        lin = self._replaced(F=F, Q=Q)
        # f(x) or f(x, u): a strategy passes u_k when it has controls at all
        lin.us = self._controls if u is not None or isinstance(self._model, LinearModel) else None
        steady = self._steady if lin is self._lin else None
        if self.form == "sqrt":
            self._set(*self._run(kalman.forecast_sqrt, lin, k, belief.mean, self._own_factor(), self._roots,
                                 self._angles[0], steady=steady))
        else:
            mean, cov = self._run(kalman.forecast, lin, k, belief.mean, belief.cov, self._angles[0], steady=steady)
            self._belief = Gaussian._trusted(mean, cov)
        if lin is not self._lin:
            self._steady = self._fresh_steady()
        self._views.clear()
        self.x_prior, self.P_prior = self._belief.mean, self._belief.cov
        self._step += 1

    def update(self, z, R=None, H=None, gate: float | None = None, gate_by: str = "measurement") -> Gaussian:
        """Condition the belief on a measurement.

        Parameters
        ----------
        z : array_like of shape (m,), a scalar when m = 1, or None
            The measurement; NaN components are missing, and None skips the
            update (all missing).
        R : array_like of shape (m, m), optional
            The measurement noise covariance for this update only.
        H : array_like of shape (m', n), optional
            The measurement matrix for this update only (a LinearModel); a
            sensor of another dimension m' then needs its `R`.
        gate, gate_by :
            Outlier gating, as in :func:`gaussfuse.filter`: what the gate
            rejects is treated as missing; ``rejected`` says which
            components (None without a gate).

        Returns
        -------
        Gaussian
            The posterior, also in ``x_post`` and ``P_post``; the innovation
            and its covariance, the gain, the log-likelihood term and the
            Mahalanobis distance in ``y``, ``S``, ``K``, ``log_likelihood``
            and ``mahalanobis``.
        """
        belief = self.belief
        k = max(self._step - 1, 0)
        self._check_step(k)
        self._functions_not_matrices(H=H)
        m = self._model.m if H is None else self._matrix("H", H, None, self._model.n).shape[0]
        if H is not None and m != self._model.m and R is None:
            raise ValueError(f"`R` is required with an `H` of {m} rows: the model's R is for {self._model.m}.")
        z = np.full(m, np.nan) if z is None else np.atleast_1d(as_array("z", z, allow_nan=True))
        if z.shape != (m,):
            raise shape_error("z", f"({m},)", z.shape)
        lin = self._replaced(H=H, R=R, m=m)
        steady = self._steady if lin is self._lin else None
        xa, za = self._angles
        checked_gate = kalman.Gate.of(gate, gate_by)
        if self.form == "sqrt":
            post = self._run(kalman.correct_sqrt, lin, k, belief.mean, self._own_factor(), z, self._roots, xa, za,
                             steady=steady, gate=checked_gate)
            self._set(post.mean, post.factor)
        else:
            post = self._run(kalman.correct, lin, k, belief.mean, belief.cov, z, self._iterations, self._tol, xa, za,
                             steady=steady, gate=checked_gate)[0]
            check_semidefinite(lin, post.cov[None], "filtered", lambda _: k)  # as gf.filter (review R30)
            self._belief = Gaussian._trusted(post.mean, post.cov)
        if lin is not self._lin:
            self._steady = self._fresh_steady()
        self._views.clear()
        self.loglik += post.loglik
        observed = ~np.isnan(post.innovation)
        K = np.zeros((self._model.n, m))
        if post.gain is not None:
            K[:, observed] = post.gain
        self.x_post, self.P_post = self._belief.mean, self._belief.cov
        S = post.innovation_cov.view()  # read-only, as x_prior and the others: once the covariances settle it is
        S.setflags(write=False)         # the steady state's own S, which every later update hands out (audit LL1)
        self.y, self.S, self.K = post.innovation, S, K
        self.log_likelihood, self.mahalanobis = float(post.loglik), float(np.sqrt(post.nis))
        self.rejected = post.rejected
        if self._monitor is not None:
            self._monitor.observe(post, k, "steps {}-{}", checked_gate)
        return self._belief

    def _discretise(self, dt, u):
        """Make the model and strategy those of a step of `dt` (a TimedModel's); the control the step passes f."""
        if self.timed is None:
            raise ValueError("`dt` is for a model built by gf.model(motion, sensor) without dt; this model's matrices "
                             "are for a fixed step.")
        if dt is None:
            raise ValueError("`dt` is required: the model was built by gf.model(motion, sensor) without dt, so each "
                             "step is discretised for its own time step.")
        self._model, controls = self.timed.at(np.array([real("dt", dt, positive=True)]), None if u is None else u[None])
        self._lin = self._sharing(linearisation(self._spec, self._model, self._controls, self._options)[0])
        return None if controls is None else controls[0]

    # -- one call's matrices ------------------------------------------------

    def _matrix(self, name: str, value, rows: int | None, cols: int | None) -> np.ndarray:
        mat = as_matrix(name, value, rows, cols, time_varying=False, row_vector_ok=name == "H")
        return check_psd(name, mat) if name in ("Q", "R") else mat

    def _replaced(self, m: int | None = None, **given):
        """The strategy, or one over the model with the matrices `given` (not None) in place of its own."""
        given = {name: value for name, value in given.items() if value is not None}
        if not given:
            return self._lin
        n = self._model.n
        shapes = {"F": (n, n), "Q": (n, n), "H": (None, n), "R": (m, m)}
        checked = {name: self._matrix(name, value, *shapes[name]) for name, value in given.items()}
        return self._sharing(linearisation(self._spec, _Replaced(self._model, checked), self._controls,
                                           self._options)[0])

    def _functions_not_matrices(self, **given) -> None:
        """Refuse an F or H `given` to :meth:`predict` or :meth:`update` for a NonlinearModel, before anything is
        checked against it (audit LL3: an H of two rows was first told to bring its R, then a z of two
        components)."""
        if not isinstance(self._model, LinearModel):
            for name in ("F", "H"):
                if given.get(name) is not None:
                    raise TypeError(f"`{name}` replaces a LinearModel's matrix; a NonlinearModel's f and h are "
                                    "functions (replace Q and R only).")

    def _sharing(self, lin):
        """`lin`, keeping the record of the automatic Jacobians' checks (:class:`gaussfuse.linearize.Taylor`) of
        the filter's strategy: each call's own strategy checked every row again (review R28)."""
        if hasattr(lin, "checks") and hasattr(self._lin, "checks"):
            lin.checks = self._lin.checks
        return lin

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


def _one_step(timed: TimedModel) -> tuple:
    """A TimedModel's model over one step (:func:`~.models.compose.probe_step`), for the method, dimensions and
    angles, and the number of controls its motion takes (its nonlinear steps take dt too, which the user does not
    give)."""
    def over(dt: float) -> tuple:
        B = timed.motion.control(dt) if isinstance(timed.motion, LinearMotion) else None
        return timed.at(np.array([dt]))[0], 0 if B is None else B.shape[1]

    return probe_step(over)[0]


class _Replaced:
    """A model seen with some matrices replaced, for one predict or update (filterpy's ``F=``, ``Q=``, ...).

    A LinearModel's strategy reads ``F``, ``H``, ``Q``, ``R`` and ``B``; a
    NonlinearModel's reads its noise through :meth:`noise`.
    """

    def __init__(self, model, given: dict[str, np.ndarray]) -> None:
        self._model, self._given = model, given

    def __getattr__(self, name: str):
        given = self.__dict__["_given"]
        return given[name] if name in given else getattr(self.__dict__["_model"], name)

    def noise(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        Q, R = self._model.noise(k)
        return self._given.get("Q", Q), self._given.get("R", R)

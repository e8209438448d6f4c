"""The drivers: run a method over series, on the readable path or a compiled engine.

The readable path is a loop of :func:`gaussfuse.kalman.step` (forward) and
:func:`gaussfuse.kalman.rts_step` (backward) over one series, through the
method's linearisation strategy; the compiled engines
(:mod:`gaussfuse._kernels`) run the same equations over a batch of series.
:func:`filter_batch` and :func:`smooth_batch` pick the engine and return
results with a leading series axis.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import warnings
from typing import Callable

import numpy as np

from .. import kalman
from .. import _kernels
from .._kernels import jitted_loop_state, kernel_states, kernels
from .._linalg import symmetrize, weighed, wrap_components
from .. import diagnostics
from ..errors import (STEP_ERRORS, ConvergenceWarning, DivergenceWarning, ReadablePath, at_step, average_text, diverging,
                      gate_lost)
from ..gaussian import Gaussian
from ..linearize import Nominal
from ..steady import steady_state
from .registry import METHODS, Method, linearisation
from .results import FilterResult, SmoothResult, stack
from .validation import check_semidefinite

__all__ = ["run_filter", "run_smoother", "each_series", "filter_batch", "smooth_batch", "ENGINES", "compiled_engine",
           "start_seconds",
           "CHECKS", "checked", "check_divergence", "divergence_message"]

ENGINES = ("auto", "python", "numba")
CHECKS = ("warn", "raise", "off")
"""What `check` can ask of the divergence test: a DivergenceWarning, the same raised, or nothing."""

# What engine="auto" weighs, in seconds on a 2-core machine (see compiled_engine):
AUTO_NUMBA_STEPS = 1000
"""Calls of fewer steps (all series together) stay on the readable path whatever is compiled,
so that a short call gives the same numbers, to the bit, in every process."""
START = {"loaded": 0.0, "cached": 1.0}
"""Starting the compiled kernels: already in this process, or loaded from numba's disk cache by a new
process (numba's import and the load; ``benchmarks/first_call.py``, warm: 0.6-1.1 s)."""
COMPILE = {"linear.forward": 14.0, "_rts.backward": 5.0, "sigma_points.advance": 28.0, "sigma_points.hold": 4.0,
           "sigma_points.run": 1.0}
"""Compiling each kernel with an empty cache, at the upper end of what this 2-core machine measured
(numba's compile events, one fresh process and cache per call, 2026-12-01): the linear filter's loop
11-12.5 s, the backward pass 3-5.4 s (a batch of series runs them too, on a pool of threads); the
sigma-point engine's step 24-27.5 s and the structure holding its arguments 3-3.6 s; the loop compiled
around numba-jitted f and h, which calls that step, 0.44-0.45 s for each of their signatures
(2026-12-06: a first call with the step cached and the loop not, less the call with both cached)."""
READABLE_STEP = {"linear": 2e-5, "sigma_points": 6e-5}
"""What the readable path spends on a filter step beyond the compiled one, at the low end of what was
measured for small states (a smoother counts as two passes): the linear filter 18.5-42 µs a step
(``benchmarks/run.py``, W1 and W5 at n = 2: 54k and 47k steps/s; 34-42 µs for n = 1, 2 and 4 on a
busier day), the compiled one under 1.5 µs; an unscented or cubature filter with plain Python f and h
82-104 µs (n = 2 and 4, 2026-12-02), its compiled Python mode 13-34 µs. Low estimates of the readable
cost and high ones of :data:`COMPILE` make "auto" compile only where that clearly pays."""
_SPENT: dict[str, float] = {}
"""What this process's calls that "auto" kept readable were expected to spend beyond the compiled path,
per compiled module (calls of at least :data:`AUTO_NUMBA_STEPS` steps): the kernels are started once
that and the next call's share reach what starting them costs, as one rents skis until the rent would
buy them. A process of many calls then pays at most about twice what the better choice in hindsight
would have cost, and a process of one call never waits for kernels the call could not win back."""

def _angles(model):
    """The model's angle masks, None where it has none (so that nothing is wrapped)."""
    out = []
    for name in ("state_angles", "measurement_angles"):
        mask = getattr(model, name, None)
        out.append(mask if mask is not None and mask.any() else None)
    return out


# ---------------------------------------------------------------------------
# The readable path: one series
# ---------------------------------------------------------------------------


def run_filter(lin, prior: Gaussian, zs: np.ndarray, *, iterations: int = 1, tol: float | None = None,
               state_angles=None, measurement_angles=None, keep: str = "all",
               form: str = "cov", target: np.ndarray | None = None,
               gains: bool = False, gate: kalman.Gate | None = None) -> tuple[FilterResult, int]:
    """Filter one series (T, m): :func:`gaussfuse.kalman.step` at each step, through the strategy `lin`.

    Returns the result and the number of steps whose iterated update made
    `iterations` passes without meeting `tol`. `keep` is one of
    :data:`gaussfuse.inference.results.KEEP`. With ``form="sqrt"`` the
    steps are :func:`gaussfuse.kalman.step_sqrt`, on Cholesky factors; the
    result holds the factors and, as always, the covariances. With
    `target`, the stationary filtered covariance, the steady-state filter
    (:class:`gaussfuse.kalman.SteadyState`). With `gains`, the result
    holds the gain of each step (zero columns for missing components).
    With `gate` (:class:`gaussfuse.kalman.Gate`), the components it rejects
    are missing, and ``rejected`` says which. With `tol` (the iterated
    methods), ``iterations`` holds each step's passes.
    """
    T, n, m = zs.shape[0], prior.dim, zs.shape[1]
    rows = 0 if keep == "last" else T
    crows = T if keep == "all" else 0
    sqrt = form == "sqrt"
    means, covs = np.empty((rows, n)), np.empty((crows, n, n))
    pmeans, pcovs = np.empty((rows, n)), np.empty((crows, n, n))
    innov, icovs = np.empty((rows, m)), np.empty((crows, m, m))
    factors, pfactors = np.empty((crows if sqrt else 0, n, n)), np.empty((crows if sqrt else 0, n, n))
    used = np.empty(rows if tol is not None else 0, dtype=np.int64)  # an iterated method's passes, even 1
    K = np.zeros((rows if gains else 0, n, m))
    rejected = np.zeros((rows if gate is not None else 0, m), dtype=bool)
    nis = np.empty(rows)
    unconverged, loglik = 0, 0.0
    mean, cov = prior.mean, prior.cov
    if sqrt:
        cov, roots = kalman.cov_factor(prior.cov, "the prior covariance"), kalman.Factors()
    steady = None
    if getattr(lin, "invariant", False) and iterations == 1:
        steady = kalman.SteadyState() if target is None else kalman.SteadyState(target, kalman.STEADY_TOL)
    k = 0
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised by the step
            for k in range(T):
                if sqrt:
                    st = kalman.step_sqrt(lin, k, mean, cov, zs[k], roots, state_angles, measurement_angles, steady,
                                          gate)
                    mean, cov = st.update.mean, st.update.factor
                else:
                    st = kalman.step(lin, k, mean, cov, zs[k], iterations, tol, state_angles, measurement_angles,
                                     steady, gate)
                    mean, cov = st.update.mean, st.update.cov
                post = st.update
                if rows:
                    if post.rejected is not None:
                        rejected[k] = post.rejected
                    pmeans[k], means[k], innov[k], nis[k] = st.predicted_mean, mean, post.innovation, post.nis
                    if used.shape[0]:
                        used[k] = st.passes
                    if gains and post.gain is not None:
                        K[k][:, ~np.isnan(post.innovation)] = post.gain
                if crows:
                    icovs[k] = post.innovation_cov
                    if sqrt:
                        pfactors[k], factors[k] = st.predicted_cov, cov
                        pcovs[k], covs[k] = _square(st.predicted_cov), _square(cov)
                    else:
                        pcovs[k], covs[k] = st.predicted_cov, cov
                loglik += post.loglik
                unconverged += not st.converged
    except STEP_ERRORS as exc:
        raise at_step(weighed(exc, getattr(getattr(lin, "rule", None), "wc", None)), k) from exc
    per_step = (means, covs, pmeans, pcovs, innov, icovs)
    result = FilterResult(*(a if a.shape[0] else None for a in per_step), loglik, mean,
                          _square(cov) if sqrt else cov, used if used.shape[0] else None,
                          factors if factors.shape[0] else None, pfactors if pfactors.shape[0] else None,
                          K if K.shape[0] else None, nis if rows else None, rejected if rejected.shape[0] else None)
    return result, unconverged


def _square(factor: np.ndarray) -> np.ndarray:
    """The covariance ``L Lᵀ`` of a factor, exactly symmetric."""
    return symmetrize(factor @ factor.T)


def run_smoother(lin, filt: FilterResult, prior: Gaussian | None = None, *, state_angles=None,
                 ending: Gaussian | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The RTS backward pass over a filtered series, with transitions from `lin`.

    The transition out of each filtered belief is re-linearised at that
    belief (for sigma-point smoothers: points re-drawn from ``(m_k, P_k)``),
    so ``A``, the prediction and the cross-covariance ``P_k Aᵀ`` agree. With
    `prior`, the pass continues back to the prior's time. A square-root
    filter's result (its ``cov_factors`` set) is smoothed on factors
    (:func:`gaussfuse.kalman.rts_step_sqrt`).

    Returns
    -------
    means : ndarray of shape (T, n), or (T + 1, n) with `prior`
    covs : ndarray of shape (T, n, n), or (T + 1, n, n) with `prior`
    gains : ndarray of shape (T - 1, n, n), or (T, n, n) with `prior`
    factors : ndarray of shape (T, n, n), or (T + 1, n, n) with `prior`; or None
        The smoothed covariances' factors, for a square-root filter's result.
    """
    sqrt = filt.cov_factors is not None
    means, covs = filt.means, filt.cov_factors if sqrt else filt.covs
    first = 1
    if prior is not None:
        means = np.concatenate([prior.mean[None], means])
        start = kalman.cov_factor(prior.cov, "the prior covariance") if sqrt else prior.cov
        covs = np.concatenate([start[None], covs])
        first = 0
    sm_means, sm_covs = means.copy(), covs.copy()
    if ending is not None:
        sm_means[-1] = ending.mean
        sm_covs[-1] = kalman.cov_factor(ending.cov, "the ending covariance") if sqrt else ending.cov
    gains = np.empty((max(means.shape[0] - 1, 0), *covs.shape[1:]))
    roots = kalman.Factors()
    j = means.shape[0] - 2
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            for j in range(means.shape[0] - 2, -1, -1):
                if sqrt:
                    A, b, LQ, DQ = kalman.transition_factors(lin, j + first, means[j], covs[j], roots)
                    sm_means[j], sm_covs[j], gains[j] = kalman.rts_step_sqrt(
                        means[j], covs[j], sm_means[j + 1], sm_covs[j + 1], A, LQ, b, state_angles, DQ)
                else:
                    A, b, Q = lin.transition(j + first, means[j], covs[j])
                    pred_mean, pred_cov = kalman.predict(means[j], covs[j], A, Q, b)
                    sm_means[j], sm_covs[j], gains[j] = kalman.rts_step(
                        means[j], covs[j], wrap_components(pred_mean, state_angles), pred_cov,
                        sm_means[j + 1], sm_covs[j + 1], covs[j] @ A.T, angles=state_angles,
                    )
                sm_means[j] = wrap_components(sm_means[j], state_angles)
                kalman.check_finite("smoothed", sm_means[j], sm_covs[j], factor=sqrt)
    except STEP_ERRORS as exc:
        raise at_step(exc, j + first) from exc
    if sqrt:
        return sm_means, symmetrize(sm_covs @ sm_covs.swapaxes(-1, -2)), gains, sm_covs
    return sm_means, sm_covs, gains, None


def _method_filter(spec: Method, model, prior, zs, us, options, keep: str = "all", form: str = "cov",
                   target: np.ndarray | None = None, gains: bool = False,
                   gate: kalman.Gate | None = None, lin=None) -> tuple[FilterResult, int]:
    """The filter for one series, and how many of its steps stopped at the iteration limit; through `lin`, the
    linearisation :func:`gaussfuse.inference.registry.linearisation` makes, if given."""
    made, iterations, tol = linearisation(spec, model, us, options)
    lin = made if lin is None else lin
    xa, za = _angles(model)
    return run_filter(lin, prior, zs, iterations=iterations, tol=tol, state_angles=xa, measurement_angles=za,
                      keep=keep, form=form, target=target, gains=gains, gate=gate)


_SETTLED_PASSES = 1e-10
"""An iterated smoother's passes are at their fixed point when one changes the trajectory by at most this (in
standard deviations) and no less than the pass before: each pass re-filters the whole series, and its round-off,
some 1e-14 standard deviations, kept `tol=0` from ever being met (50 passes and a warning: audit DD4). Below the
default `tol` (1e-9), so it can end the passes early only for a `tol` below it (review R29)."""


def _method_smooth(spec: Method, model, prior, zs, us, options, to_prior: bool = False,
                   form: str = "cov", gate: kalman.Gate | None = None,
                   ending: Gaussian | None = None) -> tuple[SmoothResult, int, bool]:
    """The smoother for one series; its filter's steps at the iteration limit; whether its passes were.

    With `to_prior`, the smoothed beliefs and gains start at the prior's
    time 0 (T + 1 beliefs, T gains). `ending` is :func:`run_smoother`'s (not
    for the iterated smoothers, whose passes re-filter).
    """
    # one strategy for both passes, so that its record of the Jacobians' checks (Taylor.checks) is the run's
    lin, passes, tol = linearisation(spec, model, us, options)  # (each pass had its own: review R33)
    filt, unconverged = _method_filter(spec, model, prior, zs, us, options, form=form, gate=gate, lin=lin)
    if filt.rejected is not None:  # the iterated smoother's passes leave out what the filter's gate rejected
        zs = np.where(filt.rejected, np.nan, zs)
    xa, za = _angles(model)
    if ending is not None and spec.iterated and passes > 1:
        raise ValueError(f"`ending` is not available for the iterated smoother {spec.name!r}.")
    if not spec.iterated or passes == 1:  # (one iteration: the plain filter, and its smoother: audit DD4)
        means, covs, gains, factors = run_smoother(lin, filt, prior if to_prior else None, state_angles=xa,
                                                   ending=ending)
        return (SmoothResult(means, covs, gains, filt, 1 if spec.iterated else None, cov_factors=factors),
                unconverged, False)
    # Iterated smoothers: each pass linearises about the previous pass's smoothed
    # trajectory (the first about the iterated filter's), from the prior's time on,
    # until the trajectory moves by at most `tol` (in the pass's predicted covariances),
    # or by round-off (_SETTLED_PASSES).
    means = np.concatenate([prior.mean[None], filt.means])
    covs = np.concatenate([prior.cov[None], filt.covs])
    converged, before = False, np.inf
    for used in range(1, passes + 1):
        nominal = Nominal(lin, means, covs, xa)
        last = run_filter(nominal, prior, zs, state_angles=xa, measurement_angles=za)[0]
        new_means, covs, gains, _ = run_smoother(nominal, last, prior, state_angles=xa)
        norms = (prior.cov, *last.predicted_covs)
        change = max(kalman.iterate_changed(P)(new, old, xa) for P, new, old in zip(norms, new_means, means))
        means = new_means
        if change <= tol or before <= change <= _SETTLED_PASSES:
            converged = True
            break
        before = change
    first = 0 if to_prior else 1
    return SmoothResult(means[first:], covs[first:], gains[first:], filt, used), unconverged, not converged


def warn_unconverged(spec: Method, options: dict, steps: int, total: int, passes: int = 0, series: int = 1, *,
                     where: str = "", stacklevel: int = 4) -> None:
    """One ConvergenceWarning for a call: the steps (and smoother passes) that stopped at the limit, `where` (as
    "in `models[1]`", else nothing) and for the caller `stacklevel` frames up."""
    if not steps and not passes:
        return
    limit, tol = options["iterations"], options["tol"]
    what = []
    if steps:
        what.append(f"{steps} of {total} steps of the filter made {limit} iterations")
    if passes:
        among = f" in {passes} of {series} series" if series > 1 else ""  # (as `where`, it was told twice: review R54)
        what.append(f"the smoother made {limit} passes{among}")
    warnings.warn(
        f"method {spec.name!r}{' ' + where if where else ''}: {' and '.join(what)} (the limit, `iterations`={limit}) "
        f"without the change falling to `tol`={tol:g}; raise `iterations` or `tol`, or check the model.",
        ConvergenceWarning, stacklevel=stacklevel,
    )


# ---------------------------------------------------------------------------
# Batches of series, and the choice of engine
# ---------------------------------------------------------------------------


def compiled_engine(spec: Method, engine: str, steps: int, passes: float = 1.0, smoothing: bool = False,
                    readable: str | None = None, loop: Callable[[], str | None] | None = None):
    """The compiled module to run `steps` steps (all series together) with, or None for the readable path.

    With ``engine="auto"`` the compiled path is taken only for
    :data:`AUTO_NUMBA_STEPS` steps or more, and only when it is expected to
    cost less: starting the kernels the call runs (:data:`START` for those
    loaded or cached, :data:`COMPILE` for each that must be compiled:
    :func:`gaussfuse._kernels.kernel_states` tells which, without importing
    numba) against what the readable path would spend on
    ``steps * passes`` steps beyond it (:data:`READABLE_STEP`).
    `passes` is how many times the caller will run the steps (a fit's
    filter passes); `smoothing` says that the backward pass runs too; `readable` names an option that only the
    readable path has (then ``engine="numba"`` is an error); `loop`, when
    given, is asked (once a sigma-point call is long enough to weigh) for the
    state of the loop compiled around numba-jitted f and h, None when the
    call would not run it (:func:`gaussfuse._kernels.jitted_loop_state`).

    Raises
    ------
    ValueError
        For an unknown `engine`, or ``engine="numba"`` where it cannot run.
    """
    if engine not in ENGINES:
        raise ValueError(f"`engine` must be one of {list(ENGINES)}; got {engine!r}.")
    if engine == "python":
        return None
    if readable is not None:  # an option the compiled engines do not have
        if engine == "numba":
            raise ValueError(f"`engine='numba'` cannot run {readable}, which the readable path runs: pass "
                             "engine='python' or 'auto'.")
        return None
    available = importlib.util.find_spec("numba") is not None
    if engine == "numba":
        if spec.compiled is None:
            fits = sorted(k for k, v in METHODS.items() if v.compiled)
            raise ValueError(f"`engine='numba'` is not available for method {spec.name!r}; it is for {fits}.")
        if not available:
            raise ValueError("`engine='numba'` needs numba: pip install numba.")
    elif spec.compiled is None or not available or not _worth_compiling(spec.compiled, steps, passes, smoothing, loop):
        return None
    return importlib.import_module(f".._kernels.{spec.compiled}", __package__)


def start_seconds(states: dict) -> float:
    """What starting kernels in these states (:func:`gaussfuse._kernels.kernel_states`) is expected to cost, in s.

    Each cold kernel's :data:`COMPILE`, plus :data:`START` ``["cached"]``
    once when any is to be loaded from the cache.
    """
    cold = sum(COMPILE[f"{module}.{name}"] for (module, name), state in states.items() if state == "cold")
    return cold + (START["cached"] if "cached" in states.values() else START["loaded"])


def switch_step(module: str, smoothing: bool, steps: int) -> int | None:
    """For a loop whose every round runs `steps` steps (all series and passes together), the first round
    (0-based) that "auto" runs compiled: once the readable rounds before it and it would have paid for starting
    `module`'s kernels (:func:`start_seconds` against :data:`READABLE_STEP`), as :data:`_SPENT` does across
    calls, and not before the readable rounds have run :data:`AUTO_NUMBA_STEPS` steps. None without numba.

    Counted, not timed: the same data and cache give the same rounds on each engine, on any machine. (A
    caller whose whole loop is expected to run fewer than :data:`AUTO_NUMBA_STEPS` steps does not ask.)
    """
    if importlib.util.find_spec("numba") is None or steps <= 0:
        return None
    start = start_seconds(kernel_states(module, smoothing))
    return max(int(np.ceil(AUTO_NUMBA_STEPS / steps)), int(np.ceil(start / (steps * READABLE_STEP[module]))) - 1)


def _worth_compiling(module: str, steps: int, passes: float, smoothing: bool,
                     loop: Callable[[], str | None] | None) -> bool:
    """Whether starting `module`'s kernels costs less than the readable path would spend on its passes
    and has spent on earlier calls in this process (:data:`_SPENT`); a call kept readable adds its share."""
    if steps < AUTO_NUMBA_STEPS:
        return False
    readable = steps * passes * READABLE_STEP[module] + _SPENT.get(module, 0.0)
    if readable <= START["cached"] and not any(f"{_kernels.__name__}.{mod}" in sys.modules
                                               for mod, _ in kernels(module, smoothing)):
        worth = False  # nothing is loaded, and loading alone would cost more: no need to look at the disk
    else:
        jitted = loop() if loop is not None and module == "sigma_points" else None
        worth = start_seconds(kernel_states(module, smoothing, jitted)) < readable
    if not worth:
        _SPENT[module] = readable
    return worth


def each_series(run, N: int) -> list:
    """``[run(i) for i in range(N)]``; an error of one of several series names it, as the compiled kernels do.

    "in series 2, at step 0: ..." (the message of :func:`gaussfuse._kernels._step.raise_failure`).
    """
    out = []
    for i in range(N):
        try:
            out.append(run(i))
        except (ValueError, FloatingPointError) as exc:  # LinAlgError and ModelFunctionError are ValueErrors
            if N == 1:
                raise
            raise type(exc)(f"in series {i}, {exc}") from exc
    return out


def filter_batch(spec: Method, model, prior: Gaussian, zs: np.ndarray, us, options: dict, engine: str,
                 keep: str, form: str = "cov", steady: bool = False, gains: bool = False,
                 gate: kalman.Gate | None = None) -> FilterResult:
    """Filter N series `zs` (N, T, m), with controls `us` (N, T, p) or None; the result has the N axis.

    With `steady`, the steady-state filter: the covariance is held once
    within ``kalman.STEADY_TOL`` of the stationary one (:func:`gaussfuse.steady_state`).
    With `gains`, the Kalman gain of each step (readable path).
    """
    target = steady_state(model).cov if steady else None
    engine, readable = _readable_only(spec, engine, form, gate, "gains=True" if gains else None)
    compiled = compiled_engine(spec, engine, zs.shape[0] * zs.shape[1], readable=readable,
                               loop=lambda: jitted_loop_state(model, prior, us, form))
    if compiled is not None:
        lin = linearisation(spec, model, None, options)[0]
        if form == "sqrt":
            try:
                return compiled.filter(lin, model, prior, zs, us, keep, form="sqrt")
            except ReadablePath:  # a singular factor or a failed downdate: the readable steps decide
                return filter_batch(spec, model, prior, zs, us, options, "python", keep, form)
        result = compiled.filter(lin, model, prior, zs, us, keep, *(() if target is None else (target,)))
        return _filtered_checked(lin, result, zs.shape[1])
    runs = each_series(lambda i: _method_filter(spec, model, prior, zs[i], None if us is None else us[i], options,
                                                keep, form, target, gains, gate), zs.shape[0])
    if spec.iterated:
        warn_unconverged(spec, options, sum(r[1] for r in runs), zs.shape[0] * zs.shape[1])
    result = stack([r[0] for r in runs])
    return _filtered_checked(linearisation(spec, model, None, options)[0], result, zs.shape[1]) if form == "cov" \
        else result


def _readable_only(spec: Method, engine: str, form: str, gate, option: str | None = None) -> tuple[str, str | None]:
    """The engine to ask for, and the option (if any) that only the readable path runs.

    ``engine="auto"`` does not pick the compiled square-root kernels (they
    are compiled apart); a gate, and `option` when given, are the readable
    path's.
    """
    sqrt_compiled = form == "sqrt" and spec.compiled is not None and option is None
    if sqrt_compiled and engine == "auto":
        engine = "python"
    if option is None and gate is not None:
        option = f"gate={gate.probability!r}"
    if option is None and form != "cov" and not sqrt_compiled and spec.compiled is not None:
        option = f"form={form!r}"  # (a method with no compiled kernel at all is named as such by compiled_engine)
    return engine, option


def smooth_batch(spec: Method, model, prior: Gaussian, zs: np.ndarray, us, options: dict, engine: str,
                 to_prior: bool = False, form: str = "cov", gate: kalman.Gate | None = None,
                 ending: Gaussian | None = None) -> SmoothResult:
    """Smooth N series (see :func:`filter_batch`); with `to_prior`, from the prior's time 0 on.

    With `ending`, every series' backward pass starts from that smoothed
    belief at its last step (:func:`run_smoother`).
    """
    why = ("form='sqrt' to the prior's time" if to_prior and form == "sqrt"
           else "an ending" if ending is not None and (form == "sqrt" or spec.compiled != "linear") else None)
    engine, readable = _readable_only(spec, engine, form, gate, why)
    compiled = compiled_engine(spec, engine, zs.shape[0] * zs.shape[1], 2.0, smoothing=True,
                               readable=readable, loop=lambda: jitted_loop_state(model, prior, us, form))
    if compiled is not None:
        lin = linearisation(spec, model, None, options)[0]
        if form == "sqrt":
            try:
                result, failed = compiled.smooth_sqrt(lin, model, prior, zs, us)
            except ReadablePath:  # a singular factor or a failed downdate: the readable steps decide
                return smooth_batch(spec, model, prior, zs, us, options, "python", to_prior, form)
            for s in np.flatnonzero(failed):  # a singular prediction or an overflow: the readable step decides
                one = _method_smooth(spec, model, prior, zs[s], None if us is None else us[s], options, False, form)[0]
                result.means[s], result.covs[s], result.gains[s], result.cov_factors[s] = (
                    one.means, one.covs, one.gains, one.cov_factors)
            return result
        result = compiled.smooth(lin, model, prior, zs, us) if ending is None else \
            compiled.smooth(lin, model, prior, zs, us, ending)
        _filtered_checked(lin, result.filtered, zs.shape[1])
        return _spread_checked(lin, _back_to_prior(model, prior, result) if to_prior else result, to_prior)
    runs = each_series(lambda i: _method_smooth(spec, model, prior, zs[i], None if us is None else us[i], options,
                                                to_prior, form, gate, ending), zs.shape[0])
    if spec.iterated:
        warn_unconverged(spec, options, sum(r[1] for r in runs), zs.shape[0] * zs.shape[1],
                          passes=sum(r[2] for r in runs), series=zs.shape[0])
    result = stack([r[0] for r in runs])
    if form == "cov" and not spec.iterated:
        lin = linearisation(spec, model, None, options)[0]
        _filtered_checked(lin, result.filtered, zs.shape[1])
        _spread_checked(lin, result, to_prior)
    return result


def _spread_checked(lin, result: SmoothResult, to_prior: bool) -> SmoothResult:
    r"""`result`, after raising LinAlgError where a sigma-point rule that weighs a point negatively left a smoothed
    covariance that is not positive semi-definite (the square-root form raises there too).

    The covariance form's RTS step, :math:`P + G (P^s - P^-) G^\top`, keeps what the filter hands it; a
    negative weight can make the regression's residual spread indefinite, and a smoothed covariance with it.
    Named by the backward step's transition, as run_smoother's errors, and the first the backward pass meets.
    """
    check_semidefinite(lin, result.covs, "smoothed", lambda k: k if to_prior else k + 1, last=True)
    return result


def _filtered_checked(lin, result: FilterResult, T: int) -> FilterResult:
    """`result` of T steps, after raising LinAlgError where a sigma-point rule that weighs a point negatively left
    a filtered covariance that is not positive semi-definite, as the square-root form does; the covariance form
    returned it (a variance of -0.047 from kappa = -4.5: audit DD5). Those it keeps: all, or the last."""
    if result.covs is not None:
        check_semidefinite(lin, result.covs, "filtered", lambda k: k)
    elif result.last_cov is not None:
        check_semidefinite(lin, result.last_cov[..., None, :, :], "filtered", lambda k: T - 1)
    return result


def _back_to_prior(model, prior: Gaussian, sm: SmoothResult) -> SmoothResult:
    """A compiled linear smoother's result, continued one RTS step back to the prior's time 0."""
    F = model.at(0)[0]
    filt = sm.filtered
    pcov = filt.predicted_covs[:, 0]
    N, n = sm.means.shape[0], model.n
    if (pcov == pcov[0]).all():  # one model and prior: every series shares P⁻_1, so one step does all
        m0, P0, G0 = kalman.rts_step(prior.mean, prior.cov, filt.predicted_means[:, 0], pcov[0], sm.means[:, 0],
                                     sm.covs[:, 0], prior.cov @ F.T)
        G0 = np.broadcast_to(G0, (N, n, n))
    else:
        m0, P0, G0 = (np.stack(a) for a in zip(*(
            kalman.rts_step(prior.mean, prior.cov, filt.predicted_means[i, 0], pcov[i], sm.means[i, 0],
                            sm.covs[i, 0], prior.cov @ F.T) for i in range(N))))
    back = (np.concatenate([first[:, None], rest], axis=1) for first, rest in ((m0, sm.means), (P0, sm.covs),
                                                                               (G0, sm.gains)))
    return SmoothResult(*back, filt, sm.iterations)


def divergence_message(ranges: list[str]) -> str:
    """The DivergenceWarning's message for flagged `ranges` ("<average> over steps a-b ..."): the first five, and a count."""
    return diverging(ranges[:5], diagnostics.DIVERGENCE_FALSE_ALARM, max(len(ranges) - 5, 0))


def checked(check) -> str:
    """`check` if it is one of :data:`CHECKS`, else a ValueError naming it."""
    if not isinstance(check, str) or check not in CHECKS:
        raise ValueError(f"`check` must be one of {list(CHECKS)}; got {check!r}.")
    return check


def check_divergence(result: FilterResult, check: str, first_series: int = 0, gate=None, share: float = 1.0) -> None:
    """Warn (or raise) a DivergenceWarning naming the steps where `result`'s innovations fail the χ² test.

    `result` has the series axis, its first series numbered `first_series`
    in the message. See :func:`gaussfuse.diagnostics.divergence`; nothing
    is tested without per-step values (``keep="last"``). With `gate` (the
    :class:`gaussfuse.kalman.Gate` the filter ran with), the steps where it
    rejected more than a consistent filter's share are named too
    (:func:`gaussfuse.diagnostics.rejections`): rejected steps have no
    innovation to test. `share` is this result's part of a call's
    false-alarm rate (a chunk's series among all of a call's).
    """
    gating = gate is not None and getattr(result, "rejected", None) is not None and result.rejected.any()
    false_alarm = diagnostics.DIVERGENCE_FALSE_ALARM * share / (2 if gating else 1)  # shared by the two tests
    if check == "off" or result.nis is None:
        return
    seen = ~np.isnan(result.innovations)
    if seen.all():  # every component of every step: m degrees of freedom at each (no per-step array)
        dof = seen.shape[-1]
    else:
        dof = seen[..., 0].astype(np.float64)
        for j in range(1, seen.shape[-1]):  # m is small: m vector additions beat a reduction over the last axis
            dof += seen[..., j]
    many = result.nis.shape[0] > 1 or share < 1.0  # a chunk of one series among several is named (audit NN4)
    where = [f"{average_text(avg)} over steps {a}-{b}{f' of series {s + first_series}' if many else ''}"
             for s, a, b, avg in diagnostics.divergence(result.nis, dof, false_alarm=false_alarm)]
    if gating:
        lost, there = diagnostics.gate_counts(result.rejected, seen, gate.by)
        gated = [f"{k} of {n} over steps {a}-{b}{f' of series {s + first_series}' if many else ''}"
                 for s, a, b, k, n in diagnostics.rejections(lost, there, gate.probability, false_alarm=false_alarm)]
    else:
        gated = []
    if not where and not gated:
        return
    message = divergence_message(where) if where else ""
    if gated:
        message += (" " if message else "") + gate_lost(gated[:5], gate.by, gate.probability, max(len(gated) - 5, 0),
                                                        diagnostics.DIVERGENCE_WINDOW)
    if check == "raise":
        raise DivergenceWarning(message)
    warnings.warn(message, DivergenceWarning, stacklevel=3)

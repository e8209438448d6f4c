"""The inference methods: one keyword entry each, and how a call's method and options are resolved.

A method is a linearisation strategy (:mod:`gaussfuse.linearize`) for the
models it accepts, its options with their defaults, and optionally a
compiled engine (:mod:`gaussfuse._kernels`). Adding a method is adding an
entry to :data:`METHODS`: the drivers need nothing else.
"""

from __future__ import annotations

from functools import partial
from typing import Callable, NamedTuple

from .._validation import integer, real
from ..linearize import Exact, SigmaPoints, Taylor, cubature, gauss_hermite, unscented
from ..models.linear import LinearModel
from ..models.nonlinear import NonlinearModel

__all__ = ["Method", "METHODS", "FORMS", "DEFAULT_METHOD", "DEFAULT_TOL", "DEFAULT_ITERATIONS", "resolve_method",
           "check_options", "linearisation"]

DEFAULT_TOL = 1e-9
"""Default `tol` of the iterated methods: the iterate moved less than 1e-9 predicted standard deviations."""
DEFAULT_ITERATIONS = 50
"""Default `iterations` of the iterated methods: a limit; Gauss-Newton and posterior linearisation
converge linearly, and on Särkkä and Svensson's pendulum reach `tol` in 3-21 updates per step and
11 smoother passes."""


class Method(NamedTuple):
    """A registered inference method.

    Attributes
    ----------
    name : str
        The method's name, the key in :data:`METHODS`.
    model_types : tuple of type
        The model classes it accepts.
    strategy : callable
        ``(model, us, **options) -> strategy``: how the model is linearised
        (see :mod:`gaussfuse.linearize`); ``iterations`` and ``tol`` are not
        passed.
    description : str
        One line for listings.
    options : dict
        Accepted keyword options and their defaults.
    iterated : bool
        Whether ``iterations`` repeats the update (filter) and the whole
        linearise-filter-smooth pass (smoother), at most that many times:
        the repetition stops when the change is at most ``tol``.
    compiled : str or None
        Module under :mod:`gaussfuse._kernels` with the compiled engine
        (its ``filter`` and ``smooth``; see :mod:`gaussfuse._kernels`).
    forms : tuple of str
        The forms of the algebra it runs in (:data:`FORMS`): ``"cov"``, and
        ``"sqrt"`` for the one-pass methods (an iterated update re-linearises
        at each pass, which the square-root step does not).
    """

    name: str
    model_types: tuple[type, ...]
    strategy: Callable
    description: str
    options: dict = {}
    iterated: bool = False
    compiled: str | None = None
    forms: tuple[str, ...] = ("cov",)


def _regression(rule, model, us, **options) -> SigmaPoints:
    """The sigma-point strategy of a rule (`options` are the rule's)."""
    return SigmaPoints(model, rule(model.n, **options), us)


def _sigma_points(rule):
    return partial(_regression, rule)  # a partial of module functions, so a Method pickles


FORMS = ("cov", "sqrt")
"""The forms of the filters: covariances (Joseph form), or their Cholesky factors (square-root, QR array form)."""

_ITERATED = {"iterations": DEFAULT_ITERATIONS, "tol": DEFAULT_TOL}

METHODS: dict[str, Method] = {m.name: m for m in (
    Method(name="kf", model_types=(LinearModel,), strategy=Exact, compiled="linear", forms=FORMS,
           description="Kalman filter / Rauch-Tung-Striebel smoother (exact for linear models)"),
    Method(name="ekf", model_types=(NonlinearModel,), strategy=Taylor, forms=FORMS,
           description="extended Kalman filter / extended RTS smoother"),
    Method(name="iekf", model_types=(NonlinearModel,), strategy=Taylor, options=_ITERATED, iterated=True,
           description="iterated EKF / iterated extended (Gauss-Newton) smoother"),
    Method(name="ukf", model_types=(NonlinearModel,), strategy=_sigma_points(unscented),
           options={"alpha": 1.0, "beta": 0.0, "kappa": None}, compiled="sigma_points", forms=FORMS,
           description="unscented Kalman filter / unscented RTS smoother"),
    Method(name="ckf", model_types=(NonlinearModel,), strategy=_sigma_points(cubature), compiled="sigma_points", forms=FORMS,
           description="cubature Kalman filter / cubature RTS smoother"),
    Method(name="ghkf", model_types=(NonlinearModel,), strategy=_sigma_points(gauss_hermite),
           options={"order": 3}, compiled="sigma_points", forms=FORMS,
           description="Gauss-Hermite Kalman filter / RTS smoother"),
    Method(name="iplf", model_types=(NonlinearModel,), strategy=_sigma_points(gauss_hermite),
           options={**_ITERATED, "order": 3}, iterated=True,
           description="iterated posterior-linearisation filter / smoother (Gauss-Hermite)"),
)}

DEFAULT_METHOD: dict[type, str] = {LinearModel: "kf", NonlinearModel: "ukf"}

OPTION_CHECKS: dict[str, Callable] = {
    "iterations": integer,
    "order": integer,
    "alpha": lambda name, v: real(name, v, positive=True),
    "beta": real,
    "kappa": lambda name, v: real(name, v, optional=True),
    "tol": lambda name, v: real(name, v, nonnegative=True),
}


def resolve_method(model, method: str | None, options: dict, caller: Callable | None = None) -> tuple[Method, dict]:
    """The method for `model` (the default for its type when None) and its checked options, defaults filled in.

    `caller`, the function the user called with `options` as its keyword
    arguments, is named in the message for an unknown one.

    Raises
    ------
    TypeError
        For a model no method accepts, a method that does not apply to the
        model, an unknown option, or an option of the wrong type.
    ValueError
        For an unknown method or an option out of range.
    """
    if method is None:
        for cls, name in DEFAULT_METHOD.items():
            if isinstance(model, cls):
                method = name
                break
        else:
            *most, last = (f"gaussfuse.{c.__name__}" for c in DEFAULT_METHOD)
            raise TypeError(f"`model` must be a {', '.join(most)} or {last}; got {type(model).__name__}.")
    spec, options = check_options(method, options, caller)
    if not isinstance(model, spec.model_types):
        fits = sorted(k for k, v in METHODS.items() if isinstance(model, v.model_types))
        raise TypeError(f"method {method!r} does not apply to a {type(model).__name__}; valid methods for it are {fits}.")
    return spec, {**spec.options, **options}


def check_options(method: str, options: dict, caller: Callable | None = None) -> tuple[Method, dict]:
    """The method named `method` and its `options`, checked (an unknown name or option raises, see above)."""
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"`method` must be one of {sorted(METHODS)}; got {method!r}.")
    spec = METHODS[method]
    unknown = sorted(set(options) - set(spec.options))
    if unknown:
        raise TypeError(_unknown(spec, unknown, caller))
    return spec, {name: OPTION_CHECKS[name](name, value) for name, value in options.items()}


def _unknown(spec: Method, unknown: list[str], caller: Callable | None) -> str:
    """The message for keyword arguments that are not options of `spec`'s method: whose options they are, or the
    argument of `caller` (the function the user called) a misspelt one is close to, or that `caller` has no such
    argument (audit Y3: ``smooth(keep=...)`` and ``filter(gatee=...)`` said only that 'kf' takes no options)."""
    import difflib
    import inspect

    valid = sorted(spec.options) or "none"
    text = f"unknown option(s) {unknown} for method {spec.name!r}; valid options are {valid}."
    arguments = [] if caller is None else [name for name, p in inspect.signature(caller).parameters.items()
                                           if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    notes = []
    for name in unknown:
        owners = sorted(m.name for m in METHODS.values() if name in m.options)
        close = difflib.get_close_matches(name, arguments + sorted(spec.options), n=1)
        if owners:
            notes.append(f"`{name}` is an option of method(s) {owners}")
        elif close:
            notes.append(f"did you mean `{close[0]}` for `{name}`?")
        elif caller is not None:
            notes.append(f"`{caller.__name__}` has no argument `{name}`")
    return text if not notes else f"{text} ({'; '.join(notes)})"


def linearisation(spec: Method, model, us, options: dict):
    """The method's strategy for one series, its ``iterations`` (1 if it has none) and ``tol`` (None)."""
    options = dict(options)
    iterations, tol = options.pop("iterations", 1), options.pop("tol", None)
    return spec.strategy(model, us, **options), iterations, tol

"""The warnings and errors of gaussfuse that are not Python's own."""

from __future__ import annotations

import tempfile

import numpy as np

__all__ = ["ConvergenceWarning", "DivergenceWarning", "ModelFunctionError", "not_finite", "diverging", "STEP_ERRORS",
           "at_step", "spooled"]


class ConvergenceWarning(UserWarning):
    """An iterative computation stopped at its iteration limit before meeting its tolerance.

    The result it returns is the best one found, but it may not be
    trustworthy: raise the iteration limit, loosen the tolerance, or check
    the model.
    """


class DivergenceWarning(UserWarning):
    """A filter's innovations are too large for its own covariances: it may be diverging.

    Issued (or, with ``check="raise"``, raised) by :func:`gaussfuse.filter`
    and :func:`gaussfuse.smooth` when the normalised innovations of a window
    of steps fail a χ² test (:func:`gaussfuse.diagnostics.divergence`); the
    message names the steps. The estimates there should not be trusted:
    check Q, R and the prior, or try another method.
    """


class ReadablePath(Exception):
    """Raised by a compiled kernel for a step that only the readable path takes (not for users).

    The square-root sigma-point kernels meet it at a singular factor, whose
    regression is the readable path's least-squares solve, and at a failed
    downdate, whose error the readable path raises; the drivers then run
    the call there.
    """


class ModelFunctionError(ValueError):
    """A model function (f, h or a Jacobian) raised, or returned a bad value.

    The message names the function, the input's shape and, from a filter,
    the step.
    """


def not_finite(stage: str) -> str:
    """The message for a belief that overflowed, the same from every engine.

    `stage` is "predicted", "filtered" (whose log-likelihood term is checked
    too) or "smoothed"; the caller prefixes where (the step, the series).
    """
    what = "mean, covariance or log-likelihood" if stage == "filtered" else "mean or covariance"
    return (f"the {stage} {what} is not finite (inf or NaN): the computation overflowed; "
            "check the scale of the model, the prior and the measurements.")


def fixed_text(value: float, decimals: int) -> str:
    """`value` with `decimals` decimals, or in scientific notation from 1e12 on: a log-likelihood of -5e307 with
    six decimals was 315 characters (audit EE2)."""
    return f"{value:.{decimals}f}" if not abs(value) >= 1e12 else f"{value:.{decimals + 2}e}"


def average_text(value: float) -> str:
    """A window's average NIS as the messages show it: two decimals, or three digits and an exponent past 1e6
    (a series scaled by 1e150 made a 150-digit number)."""
    return f"{value:.2f}" if abs(value) < 1e6 else f"{value:.3g}"


def diverging(where: list[str], false_alarm: float, more: int = 0) -> str:
    """The DivergenceWarning's message: `where` says, for each flagged range, its average NIS and its steps."""
    extra = f" (and {more} more ranges)" if more else ""
    return (f"the filter may be diverging: its normalised innovations average, per observed component, "
            f"{'; '.join(where)}{extra} (1 expected; a chi-square test that a consistent filter fails with "
            f"probability {false_alarm:g}). Its covariances do not cover its errors there: check Q, R and the prior, or try "
            "another method; check='off' turns this test off.")


def gate_lost(where: list[str], by: str, probability: float, more: int, window: int) -> str:
    """The DivergenceWarning's sentence on a gate that rejected at least half of each flagged `window` of steps
    (`where`: "K of N over ...", per range of merged windows, which may hold less than half)."""
    extra = f" (and {more} more ranges)" if more else ""
    kind = "measurements" if by == "measurement" else "components"
    return (f"The gate rejected {'; '.join(where)}{extra} of the {kind} it was given, at least half in each "
            f"flagged window of {window} steps, where against a "
            f"consistent prediction it rejects {1 - probability:.2g} of them: the filter may have lost the data (its "
            "covariances no longer cover its errors, and the gate keeps them from showing); gate=None keeps every "
            "measurement.")


STEP_ERRORS = (np.linalg.LinAlgError, ModelFunctionError, FloatingPointError)
"""What a step of a filter or smoother can raise on valid input: named with its step by :func:`at_step`."""


def at_step(exc: Exception, k: int) -> Exception:
    """`exc` again, with the step it happened at in front of its message."""
    return type(exc)(f"at step {k}: {exc}")



def spooled(call, *args, folder: str | None = None, **kwargs):
    """``call(*args, **kwargs)``, a write or read of a temporary file in `folder` (default TMPDIR's), whose
    OSError (a full disk) names the folder.

    Python's says only "[Errno 28] No space left on device", which does not
    tell a full temporary folder from a full output disk (audit BB2).
    """
    try:
        return call(*args, **kwargs)
    except OSError as exc:
        if exc.filename is not None:
            raise
        where = tempfile.gettempdir() if folder is None else folder
        raise type(exc)(exc.errno, f"{exc.strerror} (in a temporary file of the work in progress; TMPDIR chooses "
                                   "another folder)", where) from None

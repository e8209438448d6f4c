"""Warnings that gaussfuse emits."""

from __future__ import annotations

__all__ = ["ConvergenceWarning"]


class ConvergenceWarning(UserWarning):
    """An iterative computation stopped at its iteration limit before meeting its tolerance.

    The result it returns is the best one found, but it may not be
    trustworthy: raise the iteration limit, loosen the tolerance, or check
    the model.
    """

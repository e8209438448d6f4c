"""Warnings and errors of gaussfuse that are not the built-in ones."""

from __future__ import annotations

__all__ = ["ConvergenceWarning"]


class ConvergenceWarning(UserWarning):
    """An iterative computation stopped at its iteration limit before meeting its tolerance.

    The result may not be trustworthy.
    """

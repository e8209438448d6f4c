"""Example data sets shipped with gaussfuse."""

from __future__ import annotations

from importlib.resources import files

import numpy as np

__all__ = ["nile"]


def nile() -> tuple[np.ndarray, np.ndarray]:
    """Annual flow of the Nile at Aswan, 1871–1970 (100 values, 10⁸ m³).

    Public-domain data first analysed by Cobb (1978); the running example of
    Durbin & Koopman, *Time Series Analysis by State Space Methods*
    (2nd ed., 2012), whose local level model it fits.

    Returns
    -------
    years : ndarray of shape (100,)
    flow : ndarray of shape (100,)

    Examples
    --------
    >>> from gaussfuse.datasets import nile
    >>> years, flow = nile()
    >>> int(years[0]), float(flow[0]), flow.shape
    (1871, 1120.0, (100,))
    """
    text = files(__package__).joinpath("nile.csv").read_text(encoding="utf-8")
    data = np.loadtxt(text.splitlines(), delimiter=",", comments="#", skiprows=3)
    return data[:, 0].astype(int), data[:, 1]

"""gaussfuse: Kalman filtering and Gaussian state estimation.

A belief is a Gaussian; the Kalman update is the fusion (product) of two
Gaussians. The equations live in :mod:`gaussfuse.kalman`; the drivers in
:mod:`gaussfuse.inference`.
"""

from .gaussian import Gaussian, fuse
from .inference import METHODS, FilterResult, SmoothResult, filter, smooth
from .models import LinearModel, NonlinearModel, constant_acceleration, constant_velocity
from .online import KalmanFilter

__version__ = "0.1.0"

__all__ = [
    "Gaussian",
    "fuse",
    "LinearModel",
    "NonlinearModel",
    "constant_velocity",
    "constant_acceleration",
    "filter",
    "smooth",
    "FilterResult",
    "SmoothResult",
    "METHODS",
    "KalmanFilter",
]

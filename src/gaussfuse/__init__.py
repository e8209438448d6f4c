"""gaussfuse: Kalman filtering and Gaussian state estimation.

A belief is a Gaussian; the Kalman update is the fusion (product) of two
Gaussians. The equations live in :mod:`gaussfuse.kalman`; the filters and
smoothers in :mod:`gaussfuse.inference`.
"""

from . import models
from ._linalg import wrap_angle
from .errors import ConvergenceWarning, DivergenceWarning, ModelFunctionError
from .forecasting import Forecast, forecast
from .fusion import Fused, Fuser, Measurement, fuse_timeline
from .gaussian import Gaussian, fuse
from .imm import IMMResult, imm_filter
from .inference import METHODS, FilterResult, SmoothResult, filter, smooth
from .learning import FitResult, fit
from .models import *  # noqa: F403
from .online import KalmanFilter
from .simulation import Simulation, sample_posterior, simulate
from .steady import Stationary, steady_state

__version__ = "0.1.0"

__all__ = [
    "Gaussian", "fuse",
    *models.__all__,
    "filter", "smooth", "FilterResult", "SmoothResult", "METHODS",
    "KalmanFilter", "steady_state", "Stationary",
    "Measurement", "fuse_timeline", "Fused", "Fuser",
    "imm_filter", "IMMResult",
    "fit", "FitResult",
    "forecast", "Forecast", "simulate", "Simulation", "sample_posterior",
    "ConvergenceWarning", "DivergenceWarning", "ModelFunctionError",
    "wrap_angle",
]

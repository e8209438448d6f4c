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
from .models import (BearingOnly, ConstantAcceleration, ConstantPosition, ConstantVelocity, CoordinatedTurn,
                     ForceInput, LinearModel, LinearMotion, LinearSDE, LinearSensor, LocalLevel, LocalLinearTrend,
                     NonlinearModel, NonlinearMotion, NonlinearSensor, Position, RandomWalk, RangeBearing,
                     RangeBearingElevation, Singer, Stacked, TimedModel, constant_acceleration, constant_velocity,
                     continuous_white_noise, model, piecewise_white_noise, stack_sensors, van_loan)
from .online import KalmanFilter
from .simulation import Simulation, sample_posterior, simulate
from .steady import Stationary, steady_state

__version__ = "0.1.0"

# Written out (not *models.__all__), so that type checkers see every name re-exported;
# tests/test_layout.py checks that it holds all of models.__all__.
__all__ = [
    "Gaussian", "fuse",
    "LinearModel", "NonlinearModel", "model", "TimedModel", "constant_velocity", "constant_acceleration",
    "stack_sensors", "Stacked", "van_loan", "continuous_white_noise", "piecewise_white_noise",
    "LinearMotion", "NonlinearMotion", "ConstantPosition", "ConstantVelocity", "ConstantAcceleration",
    "ForceInput", "Singer", "RandomWalk", "LocalLevel", "LocalLinearTrend", "LinearSDE", "CoordinatedTurn",
    "LinearSensor", "Position", "NonlinearSensor", "RangeBearing", "RangeBearingElevation", "BearingOnly",
    "filter", "smooth", "FilterResult", "SmoothResult", "METHODS",
    "KalmanFilter", "steady_state", "Stationary",
    "Measurement", "fuse_timeline", "Fused", "Fuser",
    "imm_filter", "IMMResult",
    "fit", "FitResult",
    "forecast", "Forecast", "simulate", "Simulation", "sample_posterior",
    "ConvergenceWarning", "DivergenceWarning", "ModelFunctionError",
    "wrap_angle",
]

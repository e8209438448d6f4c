"""gaussfuse: Kalman filtering and Gaussian state estimation.

A belief is a Gaussian; the Kalman update is the fusion (product) of two
Gaussians. The equations live in :mod:`gaussfuse.kalman`; the drivers in
:mod:`gaussfuse.inference`.
"""

from .errors import ConvergenceWarning
from .gaussian import Gaussian, fuse
from .inference import METHODS, FilterResult, SmoothResult, filter, smooth
from .learning import FitResult, fit
from .models import (
    BearingOnly,
    ConstantAcceleration,
    ConstantPosition,
    ConstantVelocity,
    CoordinatedTurn,
    ForceInput,
    LinearModel,
    LinearMotion,
    LinearSDE,
    LinearSensor,
    LocalLevel,
    LocalLinearTrend,
    NonlinearModel,
    NonlinearMotion,
    NonlinearSensor,
    Position,
    RandomWalk,
    RangeBearing,
    RangeBearingElevation,
    Singer,
    constant_acceleration,
    constant_velocity,
    model,
    van_loan,
)
from .online import KalmanFilter
from .fusion import Fused, Fuser, Measurement, fuse_timeline
from .imm import IMMResult, imm_filter
from .errors import ConvergenceWarning

__version__ = "0.1.0"

__all__ = [
    "Gaussian",
    "fuse",
    "LinearModel",
    "NonlinearModel",
    "constant_velocity",
    "constant_acceleration",
    "model",
    "van_loan",
    "LinearMotion",
    "NonlinearMotion",
    "ConstantPosition",
    "ConstantVelocity",
    "ConstantAcceleration",
    "ForceInput",
    "Singer",
    "RandomWalk",
    "LocalLevel",
    "LocalLinearTrend",
    "LinearSDE",
    "CoordinatedTurn",
    "LinearSensor",
    "Position",
    "NonlinearSensor",
    "RangeBearing",
    "RangeBearingElevation",
    "BearingOnly",
    "filter",
    "smooth",
    "FilterResult",
    "SmoothResult",
    "METHODS",
    "KalmanFilter",
    "Measurement",
    "fuse_timeline",
    "Fused",
    "Fuser",
    "imm_filter",
    "IMMResult",
    "fit",
    "FitResult",
    "ConvergenceWarning",
]

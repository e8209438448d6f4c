"""Models: what the world does (dynamics) and what the sensors see.

- :mod:`~gaussfuse.models.linear` and :mod:`~gaussfuse.models.nonlinear`: the
  state-space models the filters run on;
- :mod:`~gaussfuse.models.motion`: motion models (constant velocity, Singer,
  coordinated turn, ...), :mod:`~gaussfuse.models.sensors`: sensor models
  (position, range-bearing, ...), :mod:`~gaussfuse.models.noise`: their
  discretisation; :func:`model` combines a motion and a sensor.
"""

from .linear import LinearModel
from .nonlinear import NonlinearModel
from .noise import continuous_white_noise, piecewise_white_noise, van_loan
from .motion import (
    ConstantAcceleration,
    ConstantPosition,
    ConstantVelocity,
    CoordinatedTurn,
    ForceInput,
    LinearMotion,
    LinearSDE,
    LocalLevel,
    LocalLinearTrend,
    NonlinearMotion,
    RandomWalk,
    Singer,
    constant_acceleration,
    constant_velocity,
)
from .sensors import (
    BearingOnly,
    LinearSensor,
    NonlinearSensor,
    Position,
    RangeBearing,
    RangeBearingElevation,
)
from .build import model

__all__ = [
    "LinearModel",
    "NonlinearModel",
    "constant_velocity",
    "constant_acceleration",
    "model",
    "van_loan",
    "continuous_white_noise",
    "piecewise_white_noise",
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
]

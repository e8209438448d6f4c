"""Models: what the world does (dynamics) and what the sensors see."""

from .linear import LinearModel
from .nonlinear import NonlinearModel
from .motion import constant_acceleration, constant_velocity

__all__ = ["LinearModel", "NonlinearModel", "constant_velocity", "constant_acceleration"]

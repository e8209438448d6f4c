"""Models: what the world does (dynamics) and what the sensors see."""

from .linear import LinearModel
from .motion import constant_acceleration, constant_velocity

__all__ = ["LinearModel", "constant_velocity", "constant_acceleration"]

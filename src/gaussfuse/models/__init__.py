"""Models: what the world does (dynamics) and what the sensors see.

- :mod:`~gaussfuse.models.linear` and :mod:`~gaussfuse.models.nonlinear`: the
  state-space models the filters run on;
- :mod:`~gaussfuse.models.motion`: motion models (constant velocity, Singer,
  coordinated turn, ...), :mod:`~gaussfuse.models.sensors`: sensor models
  (position, range-bearing, ...), :mod:`~gaussfuse.models.noise`: their
  discretisation; :mod:`~gaussfuse.models.compose`: :func:`model` combines a
  motion and a sensor.
"""

from . import compose, linear, motion, noise, nonlinear, sensors
from .compose import *  # noqa: F403
from .linear import *  # noqa: F403
from .motion import *  # noqa: F403
from .noise import *  # noqa: F403
from .nonlinear import *  # noqa: F403
from .sensors import *  # noqa: F403

__all__ = [*linear.__all__, *nonlinear.__all__, *compose.__all__, *noise.__all__, *motion.__all__, *sensors.__all__]

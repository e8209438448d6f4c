"""Särkkä & Svensson's (2023) pendulum: the model functions the nonlinear tests share.

The state is (angle, angular velocity), the measurement the sine of the
angle; one point per call, or a stack of points (``_vec``).
"""

from __future__ import annotations

import numpy as np

DT, G = 0.01, 9.81
PENDULUM_Q = 0.01 * np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]])


def pendulum_f(x):
    return np.array([x[0] + DT * x[1], x[1] - G * np.sin(x[0]) * DT])


def pendulum_h(x):
    return np.array([np.sin(x[0])])


def pendulum_f_vec(X):
    return np.stack([X[:, 0] + DT * X[:, 1], X[:, 1] - G * np.sin(X[:, 0]) * DT], axis=-1)


def pendulum_h_vec(X):
    return np.sin(X[:, :1])

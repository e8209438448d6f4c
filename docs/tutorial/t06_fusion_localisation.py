"""
Sensor fusion and localisation
==============================

Each measurement is a Gaussian statement about some function of the state:
the update fuses it with the current belief, and the motion model carries
the belief from one measurement time to the next. Sensors that report at
different rates, or measure different things, are fused by the same predict
and update. This page fuses a slow position sensor with a fast velocity
sensor, then localises a robot among known landmarks, with its wheel
odometry as the control input.
"""

# %%
# Two sensors, two rates
# ----------------------
#
# A target moves in the plane with a constant-velocity motion model, state
# :math:`[x, y, v_x, v_y]` (``gf.ConstantVelocity``, white-noise
# acceleration of spectral density 0.5 m²/s³). A GPS-like sensor reports the
# position once a second with a standard deviation of 3 m; a velocity sensor
# (a Doppler log, say) reports the velocity ten times a second with 0.2 m/s.
# ``gf.fuse_timeline`` takes ``gf.Measurement(t, sensor, z)`` items, sorts
# them by time, predicts over each gap with the motion discretised for it,
# and updates with whichever sensors report; ``times=`` adds output times.

import matplotlib.pyplot as plt
import numpy as np

import gaussfuse as gf
from gaussfuse.diagnostics import rmse
from gaussfuse.plotting import plot_series, plot_trajectory

rng = np.random.default_rng(3)
motion = gf.ConstantVelocity(dim=2, q=0.5)
sensors = {"gps": gf.Position(dim=2, r=3.0**2),
           "velocity": gf.LinearSensor(H=[[0, 0, 1, 0], [0, 0, 0, 1]], R=0.2**2 * np.eye(2))}

dt, T = 0.1, 600  # 60 s on a 10 Hz grid
t = dt * np.arange(1, T + 1)
start = gf.Gaussian([0, 0, 2, 1], np.diag([1, 1, 0.1, 0.1]))
truth = gf.simulate(gf.model(motion, sensors["gps"], dt), start, T, rng=rng).states  # (T, 4)
gps = [gf.Measurement(tk, "gps", truth[k, :2] + 3.0 * rng.standard_normal(2)) for k, tk in enumerate(t) if k % 10 == 9]
velocity = [gf.Measurement(tk, "velocity", truth[k, 2:] + 0.2 * rng.standard_normal(2)) for k, tk in enumerate(t)]
print(f"{len(gps)} GPS fixes, {len(velocity)} velocity readings; first: {gps[0].sensor} at t = {gps[0].t:.1f} s")

prior = gf.Gaussian([0, 0, 0, 0], np.diag([25.0, 25.0, 4.0, 4.0]))
runs = {}
for name, measurements in (("GPS only", gps), ("velocity only", velocity), ("both", gps + velocity)):
    fused = gf.fuse_timeline(motion, sensors, prior, 0.0, measurements, times=t)
    runs[name] = fused.at(t)  # (means, covs) at every 0.1 s

position = {name: rmse(means[:, :2], truth[:, :2]) for name, (means, _) in runs.items()}
print(f"{'sensors':<14} {'position RMSE':>14} {'velocity RMSE':>14}")
for name, (means, covs) in runs.items():
    print(f"{name:<14} {position[name]:>11.2f} m {rmse(means[:, 2:], truth[:, 2:]):>10.3f} m/s")
assert position["both"] < min(position["GPS only"], position["velocity only"])

# %%
# Fusing both gives a smaller position error than either sensor alone
# (checked above). The two are complementary. The velocity sensor alone
# knows how the target moves but not where it is: its position error is the
# prior's, plus a random walk as the velocity errors add up. The GPS alone
# fixes the position, but between fixes the filter must guess the motion.
# Together, the velocity readings carry the position accurately from one
# fix to the next, and the fixes stop the drift. The error over time shows
# it: the GPS-only error jumps at each fix, the velocity-only one wanders.

fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6.5), layout="constrained")
fixes = np.full((T, 2), np.nan)
fixes[9::10] = [m.z for m in gps]
means, covs = runs["both"]
plot_series(t[:150], means[:150], covs[:150], zs=fixes[:150], truth=truth[:150], ax=top, label="fused (both)",
            ylabel="x", unit="m", time_unit="s")  # the first 15 s, where the band is visible
top.set_title("x position over the first 15 s: GPS fixes and the fused estimate")
for name, (means, covs) in runs.items():
    bottom.plot(t, np.hypot(*(means[:, :2] - truth[:, :2]).T), lw=1, label=name)
bottom.set(xlabel="time (s)", ylabel="position error (m)", title="Error of each estimate")
bottom.legend(fontsize="small")

# %%
# For measurements that arrive one at a time (a live system), ``gf.Fuser``
# takes them in time order, ``fuser.update(t, sensor, z)``. Its final belief
# is the one ``fuse_timeline`` gave (checked to 1e-8).

fuser = gf.Fuser(motion, sensors, prior, t0=0.0)
for m in sorted(gps + velocity, key=lambda m: m.t):
    fuser.update(m.t, m.sensor, m.z)
print(f"Fuser at t = {fuser.t:.1f} s: position {fuser.belief.mean[:2].round(2)}")
assert np.allclose(fuser.belief.mean, runs["both"][0][-1], atol=1e-8)
assert np.allclose(fuser.belief.cov, runs["both"][1][-1], atol=1e-8)

# %%
# A robot among known landmarks
# -----------------------------
#
# A wheeled robot's pose is :math:`[x, y, \theta]`. Its wheel odometry
# reports its speed :math:`v` and turn rate :math:`\omega`, and the filter
# uses those readings as the control input :math:`u_k` of the unicycle model
#
# .. math::
#
#    f(x, u) = x + \Delta t \begin{bmatrix} v \cos\bar\theta \\ v \sin\bar\theta \\ \omega \end{bmatrix},
#    \qquad \bar\theta = \theta + \omega \Delta t / 2.
#
# Odometry errors add up: integrating the readings alone (dead reckoning)
# drifts. Once a second a range-bearing sensor measures the distance and
# the bearing (relative to the heading) of four landmarks at known places.
# The measurement stacks :math:`[r_1, b_1, \dots, r_4, b_4]`, and it is NaN
# (missing) between the sensor's readings. The bearings and the heading are
# angles: ``measurement_angles`` and ``state_angles`` make the filter wrap
# their differences to :math:`[-\pi, \pi)`.

landmarks = np.array([[8.0, -6.0], [9.0, 7.0], [-7.0, 9.0], [-9.0, -5.0]])
sd_v, sd_w, sd_range, sd_bearing = 0.15, 0.08, 0.3, 0.05  # m/s, rad/s, m, rad


def f(x, u):
    mid = x[2] + 0.5 * u[1] * dt
    return x + dt * np.array([u[0] * np.cos(mid), u[0] * np.sin(mid), u[1]])


def h(x):
    d = landmarks - x[:2]
    return np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - x[2]]).ravel()


def h_jacobian(x):  # arctan2 takes no complex argument, so we give the Jacobian
    d = landmarks - x[:2]
    r2 = np.sum(d**2, axis=1)
    J = np.zeros((len(landmarks), 2, 3))
    J[:, 0, :2] = -d / np.sqrt(r2)[:, None]
    J[:, 1, 0], J[:, 1, 1], J[:, 1, 2] = d[:, 1] / r2, -d[:, 0] / r2, -1.0
    return J.reshape(-1, 3)


# %%
# The odometry noise enters through the motion: over one step a speed error
# moves the robot by :math:`\Delta t\, \delta v` along its heading, and a
# turn-rate error turns it by :math:`\Delta t\, \delta\omega`. A fixed
# :math:`Q` does not know the heading, so the speed error goes into both
# :math:`x` and :math:`y`, which is a little cautious.

robot = gf.NonlinearModel(
    f, h, Q=np.diag([(sd_v * dt) ** 2, (sd_v * dt) ** 2, (sd_w * dt) ** 2]),
    R=np.diag(np.tile([sd_range**2, sd_bearing**2], len(landmarks))), h_jacobian=h_jacobian,
    state_angles=[2], measurement_angles=range(1, 2 * len(landmarks), 2))

rng = np.random.default_rng(6)
commands = np.column_stack([1.2 + 0.3 * np.sin(0.4 * t), 0.15 + 0.04 * np.sin(0.25 * t)])  # (v, omega)
odometry = commands + rng.standard_normal((T, 2)) * [sd_v, sd_w]
pose0 = np.array([0.0, -8.0, 0.0])
path, dead = np.empty((T, 3)), np.empty((T, 3))
x_true, x_dead = pose0, pose0
for k in range(T):
    x_true, x_dead = f(x_true, commands[k]), f(x_dead, odometry[k])
    path[k], dead[k] = x_true, x_dead
zs = np.full((T, robot.m), np.nan)
for k in range(9, T, 10):
    zs[k] = h(path[k]) + rng.standard_normal(robot.m) * np.tile([sd_range, sd_bearing], len(landmarks))

prior = gf.Gaussian(pose0, np.diag([0.1, 0.1, 0.01]))
ekf = gf.filter(robot, prior, zs, odometry, method="ekf")
ukf = gf.filter(robot, prior, zs, odometry, method="ukf")
errors = {name: rmse(means[:, :2], path[:, :2]) for name, means in (("dead reckoning", dead), ("EKF", ekf.means),
                                                                     ("UKF", ukf.means))}
print("position RMSE: " + ", ".join(f"{name} {value:.3f} m" for name, value in errors.items()))
assert max(errors["EKF"], errors["UKF"]) < 0.5 * errors["dead reckoning"]
gap = np.abs(ekf.means[:, :2] - ukf.means[:, :2]).max()
print(f"largest EKF-UKF difference in position: {gap:.4f} m")
assert gap < 0.1 * errors["EKF"]
assert np.argmax(np.trace(ekf.covs[::50, :2, :2], axis1=1, axis2=2)) == 0  # the first ellipse drawn is the widest

# %%
# Both filters keep the robot within a fraction of the dead-reckoning error
# (checked: less than half of it). The EKF and the UKF differ by less than
# a tenth of their own error (checked): with a landmark sighting every
# second the beliefs stay narrow, and over a narrow belief the two
# linearisations are nearly the same (see :doc:`t05_nonlinear`). The
# ellipses are the EKF's 2σ regions of the position every 5 s; the first,
# one step after the start and before any sighting, is the widest.

fig, ax = plt.subplots(figsize=(7, 6.5), layout="constrained")
ax.plot(dead[:, 0], dead[:, 1], ":", color="0.4", label="dead reckoning")
ax.plot(*landmarks.T, "k*", markersize=12, label="landmark")
plot_trajectory(ekf.means, ekf.covs, truth=path, every=50, ax=ax, label="EKF", unit="m")
ax.plot(ukf.means[:, 0], ukf.means[:, 1], "--", lw=1, label="UKF")
ax.legend(loc="center", fontsize="small")
ax.set_title("Localisation: truth, dead reckoning and the filters")

# %%
# Mapping while localising: EKF-SLAM
# ----------------------------------
#
# Here the landmarks' positions were known. When they are not, they can go
# into the state beside the pose, with no process noise and a wide prior:
# each sighting then corrects both the pose and the map, through the
# correlations the filter builds between them. That is simultaneous
# localisation and mapping (SLAM), with the same kind of model and the same
# filter call; the gallery example :doc:`../auto_examples/ekf_slam` does it.

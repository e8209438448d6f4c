"""Localise a differential-drive robot among known landmarks with an EKF and a UKF
===============================================================================

The robot's state is its pose [x, y, heading]. It drives on velocity
commands; its wheel odometry reports the speed and turn rate u_k = [v, ω]
with noise, and the filters use those readings as the control input of the
unicycle model

    x_k = x + v dt cos(θ + ω dt / 2),  y_k = y + v dt sin(θ + ω dt / 2),  θ_k = θ + ω dt.

Integrating the odometry alone (dead reckoning) drifts without bound. A
range-bearing sensor sees the landmarks within 10 m (the others are NaN in
the stacked measurement vector [r_1, b_1, ..., r_K, b_K]), and the filters
correct the drift with them.

Run ``python robot_localization.py --plot robot.png`` to also draw the paths.
"""

import argparse

import numpy as np

import gaussfuse as gf
from gaussfuse.diagnostics import consistency, rmse
from gaussfuse import wrap_angle

DT = 0.1  # s
STEPS = 600  # 60 s
LANDMARKS = 12.0 * np.column_stack([np.cos(np.radians([10, 82, 154, 226, 298])),
                                    np.sin(np.radians([10, 82, 154, 226, 298]))])
MAX_RANGE = 10.0  # m
SIGMA_V, SIGMA_W = 0.15, 0.08  # odometry noise: m/s, rad/s
SIGMA_R, SIGMA_B = 0.2, 0.03  # sensor noise: m, rad
PRIOR = gf.Gaussian([0.0, -8.0, 0.0], np.diag([0.3**2, 0.3**2, 0.05**2]))  # the pose at the start


def f(x, u):
    """Unicycle motion over DT; x of shape (..., 3), u = [v, ω]."""
    v, w = u[0], u[1]
    mid = x[..., 2] + 0.5 * w * DT
    return np.stack([x[..., 0] + v * DT * np.cos(mid), x[..., 1] + v * DT * np.sin(mid),
                     x[..., 2] + w * DT], axis=-1)


def f_jacobian(x, u):
    v, w = u
    mid = x[2] + 0.5 * w * DT
    return np.array([[1.0, 0.0, -v * DT * np.sin(mid)],
                     [0.0, 1.0, v * DT * np.cos(mid)],
                     [0.0, 0.0, 1.0]])


def h(x):
    """Range and bearing to every landmark, stacked [r_1, b_1, ..., r_K, b_K]; x of shape (..., 3)."""
    dx = LANDMARKS[:, 0] - x[..., 0, None]
    dy = LANDMARKS[:, 1] - x[..., 1, None]
    bearing = wrap_angle(np.arctan2(dy, dx) - x[..., 2, None])
    return np.stack([np.hypot(dx, dy), bearing], axis=-1).reshape(*x.shape[:-1], -1)


def h_jacobian(x):
    dx, dy = LANDMARKS[:, 0] - x[0], LANDMARKS[:, 1] - x[1]
    r2 = dx**2 + dy**2
    r = np.sqrt(r2)
    J = np.zeros((2 * len(LANDMARKS), 3))
    J[0::2, 0], J[0::2, 1] = -dx / r, -dy / r
    J[1::2, 0], J[1::2, 1], J[1::2, 2] = dy / r2, -dx / r2, -1.0
    return J


def simulate(rng):
    """True poses, odometry readings and measurements (NaN beyond MAX_RANGE)."""
    t = DT * np.arange(1, STEPS + 1)
    speed = 1.2 + 0.3 * np.sin(0.5 * t)
    commands = np.column_stack([speed, speed / 8.0 + 0.1 * np.sin(0.3 * t)])  # loops of radius ~8 m
    x = PRIOR.sample(rng=rng)
    truth = np.empty((STEPS, 3))
    for k in range(STEPS):
        x = f(x, commands[k])
        x[2] = wrap_angle(x[2])
        truth[k] = x
    odometry = commands + rng.normal(size=commands.shape) * [SIGMA_V, SIGMA_W]
    zs = h(truth) + rng.normal(size=(STEPS, 2 * len(LANDMARKS))) * np.tile([SIGMA_R, SIGMA_B], len(LANDMARKS))
    zs[:, 1::2] = wrap_angle(zs[:, 1::2])
    far = np.repeat(zs[:, 0::2] > MAX_RANGE, 2, axis=1)
    zs[far] = np.nan
    return truth, odometry, zs


# The odometry noise enters through the motion: a speed error moves the robot
# along its heading by DT·δv, a turn-rate error turns it by DT·δω. Q takes the
# speed error in every direction (a little more than along the heading only).
model = gf.NonlinearModel(
    f, h,
    Q=np.diag([(SIGMA_V * DT) ** 2, (SIGMA_V * DT) ** 2, (SIGMA_W * DT) ** 2]),
    R=np.diag(np.tile([SIGMA_R**2, SIGMA_B**2], len(LANDMARKS))),
    f_jacobian=f_jacobian, h_jacobian=h_jacobian, vectorized=True,
    state_angles=[2], measurement_angles=range(1, 2 * len(LANDMARKS), 2),
)


def _check(value, interval):
    """'2.90, interval [2.78, 3.18]: consistent' (an average against its 95% interval; none for one run's NEES)."""
    if interval is None:  # one run's NEES are correlated over time: no interval follows from them
        return f"{value:.2f} (one run: no interval)"
    low, high = interval
    word = "consistent" if low <= value <= high else ("overconfident" if value > high else "cautious")
    return f"{value:.2f}, interval [{low:.2f}, {high:.2f}]: {word}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--plot", metavar="PATH", help="save a figure of the paths to PATH")
    args = parser.parse_args(argv)

    truth, odometry, zs = simulate(np.random.default_rng(7))

    dead = np.empty_like(truth)  # dead reckoning: the odometry integrated from the prior mean
    x = PRIOR.mean
    for k in range(STEPS):
        x = f(x, odometry[k])
        dead[k] = x

    seen = np.sum(~np.isnan(zs[:, 0::2]), axis=1)
    print(f"{STEPS} steps of {DT} s, {len(LANDMARKS)} landmarks, "
          f"{seen.mean():.1f} in range on average ({np.sum(seen == 0)} steps with none)")
    results = {name: gf.filter(model, PRIOR, zs, odometry, method=name) for name in ("ekf", "ukf")}

    print(f"{'estimate':<16} {'position RMSE':>14} {'final error':>12}")
    for name, means in [("dead reckoning", dead), *((n.upper(), r.means) for n, r in results.items())]:
        final = np.hypot(*(means[-1, :2] - truth[-1, :2]))
        print(f"{name:<16} {rmse(means[:, :2], truth[:, :2]):>11.3f} m {final:>10.3f} m")

    print("average NIS and NEES per step, with their 95% intervals where one run gives them:")
    for name, res in results.items():
        report = consistency(res, truth, angles=model.state_angles)  # the heading's error wrapped to [-π, π)
        print(f"{name.upper()}: NIS {_check(report.nis, report.nis_interval)}; "
              f"NEES {_check(report.nees, report.nees_interval)}")
    print("(Q takes the odometry's speed error in every direction, not only along the heading,\n"
          " so the estimation errors come out a little smaller than the filters say.)")

    if args.plot:
        import matplotlib.pyplot as plt  # a pyplot figure: shown by notebooks and the docs gallery, saved here

        from gaussfuse.diagnostics import chi2_interval, nees
        from gaussfuse.plotting import plot_consistency, plot_trajectory, save_figure

        ekf = results["ekf"]
        fig = plt.figure(figsize=(12.0, 5.0), layout="constrained")
        track, check = fig.subplots(1, 2, width_ratios=[1.0, 1.3])
        track.plot(dead[:, 0], dead[:, 1], ":", color="0.5", label="dead reckoning")
        track.plot(*LANDMARKS.T, "k*", markersize=10, label="landmark")
        plot_trajectory(ekf.means, ekf.covs, truth=truth, every=50, k=3.0, ax=track, label="EKF")
        errors = truth - ekf.means
        errors[:, 2] = wrap_angle(errors[:, 2])
        # each step's NEES against its own 95% χ²₃ band: a run's NEES are correlated over time, so no interval
        # of their time average follows from one run
        plot_consistency(nees(errors, ekf.covs), chi2_interval(3), kind="NEES", ax=check)
        save_figure(fig, args.plot)
        print(f"figure: {args.plot}")


if __name__ == "__main__":
    main()

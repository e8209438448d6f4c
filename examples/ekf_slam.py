"""EKF-SLAM: map unknown landmarks while localising the robot among them
=====================================================================

The state holds the robot's pose and the landmarks' positions,

    [x, y, heading, l1x, l1y, ..., lKx, lKy],

the robot moves by its noisy odometry u_k = [v, ω] (the unicycle model of
robot_localization.py) and the landmarks stay put (no process noise). A
range-bearing sensor sees the landmarks within 9 m and knows which is which
(known data association); the others are NaN in the stacked measurement
[r_1, b_1, ..., r_K, b_K].

The robot's first pose defines the map's frame (a tight prior); about the
landmarks the prior knows nothing (standard deviation 100 m). Its means are
only the points where the EKF first linearises the sensor: each is put where
the dead-reckoned robot first sees that landmark, so the first update
linearises near the truth and does all the work. (With every landmark
guessed at the origin instead, the first updates linearise far from the
truth and the EKF never recovers; the iterated EKF, method="iekf", does: the
script prints both.) The correlations the EKF builds between the pose and
the map then let every sighting correct both.

Run ``python ekf_slam.py --plot slam.png`` to also draw the map.
"""

import argparse
import warnings

import numpy as np

import gaussfuse as gf
from gaussfuse.diagnostics import rmse
from gaussfuse import wrap_angle

DT = 0.1  # s
STEPS = 800  # 80 s, about two loops
LANDMARKS = np.array([[9.0, 4.0], [2.0, 11.0], [-9.0, 6.0], [-8.0, -7.0], [3.0, -12.0]])
K = len(LANDMARKS)
N = 3 + 2 * K
MAX_RANGE = 9.0  # m
SIGMA_V, SIGMA_W = 0.15, 0.08  # odometry noise: m/s, rad/s
SIGMA_R, SIGMA_B = 0.2, 0.03  # sensor noise: m, rad
PRIOR_STD = 100.0  # m, of every landmark coordinate
START = np.array([0.0, -8.0, 0.0])


def move(pose, u):
    """Unicycle motion of a pose [x, y, heading] over DT."""
    v, w = u
    mid = pose[2] + 0.5 * w * DT
    return np.array([pose[0] + v * DT * np.cos(mid), pose[1] + v * DT * np.sin(mid), pose[2] + w * DT])


def f(x, u):
    """The robot moves; the landmarks stay."""
    return np.concatenate([move(x[:3], u), x[3:]])


def f_jacobian(x, u):
    v, w = u
    mid = x[2] + 0.5 * w * DT
    J = np.eye(N)
    J[0, 2], J[1, 2] = -v * DT * np.sin(mid), v * DT * np.cos(mid)
    return J


def h(x):
    """Range and bearing from the robot to every landmark of the state, [r_1, b_1, ..., r_K, b_K]."""
    d = x[3:].reshape(K, 2) - x[:2]
    bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - x[2])
    return np.column_stack([np.hypot(d[:, 0], d[:, 1]), bearing]).ravel()


def h_jacobian(x):
    d = x[3:].reshape(K, 2) - x[:2]
    r2 = np.sum(d**2, axis=1)
    r = np.sqrt(r2)
    J = np.zeros((2 * K, N))
    for i, ((dx, dy), ri, r2i) in enumerate(zip(d, r, r2)):
        drange = np.array([dx, dy]) / ri  # d range / d landmark
        dbearing = np.array([-dy, dx]) / r2i  # d bearing / d landmark
        J[2 * i, 0:2], J[2 * i, 3 + 2 * i:5 + 2 * i] = -drange, drange
        J[2 * i + 1, 0:2], J[2 * i + 1, 3 + 2 * i:5 + 2 * i] = -dbearing, dbearing
        J[2 * i + 1, 2] = -1.0
    return J


def simulate(rng):
    """True poses, odometry readings and measurements (NaN beyond MAX_RANGE)."""
    t = DT * np.arange(1, STEPS + 1)
    speed = 1.2 + 0.3 * np.sin(0.5 * t)
    commands = np.column_stack([speed, speed / 8.0 + 0.1 * np.sin(0.3 * t)])  # loops of radius ~8 m
    poses = np.empty((STEPS, 3))
    pose = START
    for k in range(STEPS):
        pose = move(pose, commands[k])
        pose[2] = wrap_angle(pose[2])
        poses[k] = pose
    odometry = commands + rng.normal(size=commands.shape) * [SIGMA_V, SIGMA_W]
    truth = np.column_stack([poses, np.tile(LANDMARKS.ravel(), (STEPS, 1))])
    zs = np.array([h(x) for x in truth])
    zs += rng.normal(size=zs.shape) * np.tile([SIGMA_R, SIGMA_B], K)
    zs[:, 1::2] = wrap_angle(zs[:, 1::2])
    zs[np.repeat(zs[:, 0::2] > MAX_RANGE, 2, axis=1)] = np.nan
    return truth, odometry, zs


Q = np.zeros((N, N))
Q[:3, :3] = np.diag([(SIGMA_V * DT) ** 2, (SIGMA_V * DT) ** 2, (SIGMA_W * DT) ** 2])
model = gf.NonlinearModel(
    f, h, Q=Q, R=np.diag(np.tile([SIGMA_R**2, SIGMA_B**2], K)),
    f_jacobian=f_jacobian, h_jacobian=h_jacobian,
    state_angles=[2], measurement_angles=range(1, 2 * K, 2),
)


def first_sightings(dead, zs):
    """Where the dead-reckoned robot first sees each landmark: the landmarks' prior means."""
    guess = np.zeros((K, 2))
    for i in range(K):
        seen = np.flatnonzero(~np.isnan(zs[:, 2 * i]))
        if seen.size:  # a landmark never seen keeps its guess: it is never linearised against data
            k = seen[0]
            r, b = zs[k, 2 * i], zs[k, 2 * i + 1]
            guess[i] = dead[k, :2] + r * np.array([np.cos(dead[k, 2] + b), np.sin(dead[k, 2] + b)])
    return guess


def main(argv=None):
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--plot", metavar="PATH", help="save a figure of the map to PATH")
    args = parser.parse_args(argv)

    truth, odometry, zs = simulate(np.random.default_rng(11))
    dead = np.empty((STEPS, 3))  # dead reckoning: the odometry integrated from the start
    pose = START
    for k in range(STEPS):
        pose = dead[k] = move(pose, odometry[k])

    prior_mean = np.concatenate([START, first_sightings(dead, zs).ravel()])
    prior_cov = np.diag([1e-4, 1e-4, 1e-6] + [PRIOR_STD**2] * (2 * K))
    res = gf.filter(model, gf.Gaussian(prior_mean, prior_cov), zs, odometry, method="ekf")

    seen = np.sum(~np.isnan(zs[:, 0::2]), axis=1)
    print(f"{STEPS} steps of {DT} s, {K} landmarks at unknown positions (prior std {PRIOR_STD:g} m), "
          f"{seen.mean():.1f} in range on average")
    print(f"robot position RMSE: dead reckoning {rmse(dead[:, :2], truth[:, :2]):.3f} m, "
          f"EKF-SLAM {rmse(res.means[:, :2], truth[:, :2]):.3f} m")

    estimate = res.last_mean[3:].reshape(K, 2)
    stds = np.sqrt(np.diagonal(res.last_cov)[3:].reshape(K, 2))
    print(f"{'landmark':>8} {'true x, y':>15} {'estimate x, y':>15} {'error':>9} {'std x, y':>13}")
    for i, (true, est, std) in enumerate(zip(LANDMARKS, estimate, stds), start=1):
        print(f"{i:>8} {true[0]:>7.2f} {true[1]:>7.2f} {est[0]:>7.2f} {est[1]:>7.2f} "
              f"{np.hypot(*(est - true)):>7.3f} m {std[0]:>5.3f} {std[1]:>5.3f} m")
    errors = np.hypot(*(estimate - LANDMARKS).T)
    print(f"landmark errors: max {errors.max():.3f} m, RMS {np.sqrt(np.mean(errors**2)):.3f} m; "
          f"final std at most {stds.max():.3f} m (prior {PRIOR_STD:g} m)")

    origin = gf.Gaussian(np.concatenate([START, np.zeros(2 * K)]), prior_cov)
    naive, flagged = {}, []
    for method in ("ekf", "iekf"):
        with warnings.catch_warnings(record=True) as caught:  # the divergence check's, printed below
            warnings.simplefilter("always", gf.DivergenceWarning)
            naive[method] = gf.filter(model, origin, zs, odometry, method=method)
        flagged += [method.upper()] * any(issubclass(w.category, gf.DivergenceWarning) for w in caught)
    print("every landmark guessed at the origin instead: landmark RMS error "
          + ", ".join(f"{method.upper()} {rmse(r.last_mean[3:].reshape(K, 2), LANDMARKS):.3f} m"
                      for method, r in naive.items()))
    if flagged:
        print(f"  the divergence check flagged {' and '.join(flagged)}: innovations too large for the filter's "
              "own covariances, the sign of a linearisation far from the truth")

    if args.plot:
        import matplotlib.pyplot as plt  # a pyplot figure: shown by notebooks and the docs gallery, saved here

        from gaussfuse.plotting import plot_trajectory, save_figure

        fig = plt.figure(figsize=(7.0, 6.5), layout="constrained")
        ax = fig.add_subplot()
        ax.plot(dead[:, 0], dead[:, 1], ":", color="0.5", label="dead reckoning")
        ax.plot(*LANDMARKS.T, "k*", markersize=12, label="landmark (true)")
        plot_trajectory(res.means, res.covs, truth=truth, every=100, k=3.0, ax=ax, label="EKF-SLAM")
        plot_trajectory(estimate, res.last_cov[3:, 3:].reshape(K, 2, K, 2)[np.arange(K), :, np.arange(K)],
                        every=1, k=3.0, ax=ax, label="landmark estimate")
        ax.lines[-1].set(linestyle="none", marker="+", markersize=10)
        ax.legend(loc="best", fontsize="small")
        save_figure(fig, args.plot)
        print(f"figure: {args.plot}")


if __name__ == "__main__":
    main()

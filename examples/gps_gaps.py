"""GPS fixes with hidden gaps: a smoother that reads the time stamps against one that counts rows
==============================================================================================

A car drives for about eight minutes. Its GPS (4 m noise) gives a fix
every second, except that fixes go missing in silent gaps: the rows of the
log just jump from one time stamp to the next, 2 or 5 seconds later. A
smoother that takes every row as one second (a model with a fixed dt)
stretches the track wherever a gap is; one that reads the time stamps
(``gf.model(motion, sensor)`` without dt, the times from the DataFrame's
DatetimeIndex) discretises each step for its own dt. The command-line
equivalent is ``gaussfuse filter log.csv -m cv2d.toml --smooth`` with a named
model and a time column: it reads the times the same way.

    python examples/gps_gaps.py

prints the RMSE of the raw fixes and of the two smoothers, in metres, and
whether the divergence check (on by default) flags each smoother: it flags
the one that counts rows, whose innovations are far too large for its own
covariances.
"""

import warnings

import numpy as np
import pandas as pd

import gaussfuse as gf

rng = np.random.default_rng(7)
motion, gps = gf.ConstantVelocity(dim=2, q=0.05), gf.Position(dim=2, r=16.0)

# The true track, simulated on a 0.1 s grid, then sampled at the fixes' times.
fine = gf.simulate(gf.model(motion, gf.Position(dim=2, r=1e-12), 0.1),
                   gf.Gaussian([0.0, 0.0, 12.0, 3.0], np.diag([1e-6, 1e-6, 0.1, 0.1])), 6000, rng=rng).states
gaps = rng.choice([1.0, 1.0, 1.0, 1.0, 2.0, 5.0], size=250)
seconds = np.cumsum(gaps)
seconds = seconds[seconds < 599.0]
truth = fine[np.round(seconds * 10).astype(int) - 1, :2]
fixes = truth + rng.normal(scale=4.0, size=truth.shape)
log = pd.DataFrame(fixes, columns=["x", "y"],
                   index=pd.Timestamp("2026-05-01 08:00:00", tz="UTC") + pd.to_timedelta(seconds, unit="s"))

prior = gf.Gaussian([fixes[0, 0], fixes[0, 1], 0.0, 0.0], np.diag([100.0, 100.0, 400.0, 400.0]))
with warnings.catch_warnings(record=True) as flagged:
    warnings.simplefilter("always", gf.DivergenceWarning)
    counted = gf.smooth(gf.model(motion, gps, dt=1.0), prior, fixes)      # every row one second
    counted_flagged = bool(flagged)
    stamped = gf.smooth(gf.model(motion, gps), prior, log)                # each step its own dt
    stamped_flagged = len(flagged) > int(counted_flagged)


def rmse(positions: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((positions - truth) ** 2, axis=1))))


print(f"{len(seconds)} fixes over {seconds[-1]:.0f} s, steps of 1 to {np.diff(seconds).max():.0f} s")
print(f"raw fixes              {rmse(fixes):.2f} m")
print(f"rows as 1 s steps      {rmse(counted.means[:, :2]):.2f} m   divergence check: "
      f"{'flags it' if counted_flagged else 'quiet'}")
print(f"time-stamped steps     {rmse(stamped.means[:, :2]):.2f} m   divergence check: "
      f"{'flags it' if stamped_flagged else 'quiet'}")

"""Learn the Nile's local level model from the data, as Durbin & Koopman (2012, section 2.10) do
=============================================================================================

Maximum likelihood with the exact diffuse prior gives the published
variances sigma²_eps = 15099 and sigma²_eta = 1469.1; EM climbs to the same
optimum, more slowly.
"""

import numpy as np

import gaussfuse as gf
from gaussfuse.datasets import nile

years, flow = nile()
start = gf.LinearModel(F=1, H=1, Q=1000.0, R=10000.0)

mle = gf.fit(start, "diffuse", flow, method="mle")
em = gf.fit(start, "diffuse", flow, method="em")
for res in (mle, em):
    print(f"{res.method}: sigma2_eps = {res.model.R[0, 0]:8.1f}  sigma2_eta = {res.model.Q[0, 0]:7.1f}  "
          f"loglik = {res.loglik:.4f}  ({len(res.history) - 1} iterations)")
se = mle.standard_errors
print(f"standard errors: sigma2_eps {se['R'][0, 0]:.0f}, sigma2_eta {se['Q'][0, 0]:.0f}")

smoothed = gf.smooth(mle.model, "diffuse", flow)
level, band = smoothed.means[:, 0], 1.96 * np.sqrt(smoothed.covs[:, 0, 0])
print(f"smoothed level in {years[0]}: {level[0]:.0f} ± {band[0]:.0f}; in {years[-1]}: {level[-1]:.0f} ± {band[-1]:.0f}")

"""Gross failures left out of `rodo calibrate`'s likelihood fits of the reported covariances' factors.

The factors (`calibrate_velocity`, `calibrate_relative`) are maximum-likelihood fits of Gaussian errors. A scan at
which the estimator failed outright (two cars crawling beside the road taken into the static set for a scan) has
an error hundreds of times its covariance, and one such scan outweighs thousands of ordinary ones: on six 30 s
city drives pooled, one scan at 4,303 times the chi-square level per dof of its window's velocity covariance (a
velocity 0.17 m/s off for a scan) took CA/P's velocity factor's Doppler term from 0.57 to 2.84, and with that
factor the velocity of the verdict's 20 campaign drives was inside its bounds on 54 % of their scans, 88 % with
the scan left out (docs/calibration.md, "Gross failures"). No factor of a Gaussian covariance describes such a
scan; what it can describe is the estimator where it works.

So each fit runs again without the scans whose NEES per dof under its own fitted covariance exceeds
`GROSS_NEES_PER_DOF` (100: errors ten times their claimed sigma, a chi-square(6) tail of 2e-126) at the level the
median scan sets (failures raise a maximum-likelihood level and would hide behind it: 1 % of the scans with
errors 100 times their sigma raise it a hundredfold), until that set of scans no longer changes (at most
`ROUNDS` fits), and never leaves out more than `MAX_OUTLIER_FRACTION` of the scans (the largest NEES first): a
model that is wrong everywhere is not a few failures. The threshold is not a tail probability of the Gaussian
model: at chi-square's 1e-6 tail (6.4 per dof) the one-scan fit also left out the heavy tail of ordinary scans
that high Doppler innovations predict, which recurs in the campaigns, and city CA/P's one-scan cell lost up to
3.6 points; at 100 per dof the verdict's calibration drives have none. The reports name the scans left out.

Checked by: tests/validation/test_gross_failures.py
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.stats import chi2

GROSS_NEES_PER_DOF = 100.0
MAX_OUTLIER_FRACTION = 0.01
ROUNDS = 5


def gross_failures(nees: np.ndarray, dof: int) -> np.ndarray:
    """(K,) bool: the scans whose NEES (K,) exceeds GROSS_NEES_PER_DOF x dof at the level the median scan sets (times
    median(NEES) / median of chi2(dof), so that failures that inflate the fit's level do not hide behind it), at
    most floor(MAX_OUTLIER_FRACTION K) of them (the largest); NaN counts as no failure."""
    nees = np.asarray(nees, dtype=float)
    finite = nees[np.isfinite(nees)]
    if not finite.size:
        return np.zeros(len(nees), bool)
    level = float(np.median(finite)) / float(chi2.median(dof))
    if not level > 0.0:  # a median scan without error: no level to judge the others by
        return np.zeros(len(nees), bool)
    beyond = np.flatnonzero(np.nan_to_num(nees, nan=0.0) > GROSS_NEES_PER_DOF * dof * level)
    cap = int(np.floor(MAX_OUTLIER_FRACTION * len(nees)))
    out = np.zeros(len(nees), bool)
    out[beyond[np.argsort(nees[beyond])[::-1][:cap]]] = True
    return out


def fit_without_gross_failures(fit: Callable[[np.ndarray], object], nees: Callable[[object], np.ndarray], n: int,
                               dof: int):
    """(params, failed (n,) bool, NEES (n,) of every scan under params): `fit(keep)` (keep (n,) bool, the scans to
    fit) refitted without the scans whose NEES under it, `nees(params)` (n,) over every scan, are gross failures
    (`gross_failures`), until the set left out repeats or after ROUNDS fits; params is the fit without the last
    set. Each fit's NEES is evaluated once."""
    failed = np.zeros(n, bool)
    params = fit(~failed)
    scans = nees(params)
    for _ in range(ROUNDS - 1):
        now = gross_failures(scans, dof)
        if np.array_equal(now, failed):
            break
        failed = now
        params = fit(~failed)
        scans = nees(params)
    return params, failed, scans

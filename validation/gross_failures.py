"""Gross failures left out of `rodo calibrate`'s likelihood fits of the reported covariances' factors.

The factors (`calibrate_velocity`, `calibrate_relative`) are maximum-likelihood fits of Gaussian errors. A scan at
which the estimator failed outright (a queue of cars beside the road taken into the static set for a scan or two)
has an error hundreds of times its covariance, and one such scan outweighs thousands of ordinary ones: on six
30 s city drives, one scan at 4303 times its velocity covariance's chi-square level per dof (a velocity 0.17 m/s
off for a scan) took CA/P's Doppler term from 0.37 to 2.84, and the factor learned there held the velocity of 20
campaign drives inside its bounds on 54 % of their scans instead of 95 % (docs/calibration.md, "Gross failures").
No factor of a Gaussian covariance describes such a scan; what it can describe is the estimator where it works.

So each fit runs again without the scans whose NEES under its own fitted covariance lies beyond chi-square's
`OUTLIER_PROBABILITY` tail (1e-6: about one scan in 400 drives of 2,400 scans if the model held), until that set
of scans no longer changes (at most `ROUNDS` fits), and never leaves out more than `MAX_OUTLIER_FRACTION` of the
scans (the largest NEES first): a model that is wrong everywhere is not a few failures. The reports name the
scans left out.

Checked by: tests/validation/test_gross_failures.py
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.stats import chi2

OUTLIER_PROBABILITY = 1e-6
MAX_OUTLIER_FRACTION = 0.01
ROUNDS = 5


def gross_failures(nees: np.ndarray, dof: int, probability: float = OUTLIER_PROBABILITY,
                   max_fraction: float = MAX_OUTLIER_FRACTION) -> np.ndarray:
    """(K,) bool: the scans whose NEES (K,) lies beyond chi2(dof)'s upper `probability` tail, at most
    floor(max_fraction K) of them (the largest); NaN counts as no failure."""
    nees = np.asarray(nees, dtype=float)
    beyond = np.flatnonzero(np.nan_to_num(nees, nan=0.0) > chi2.isf(probability, dof))
    cap = int(np.floor(max_fraction * len(nees)))
    out = np.zeros(len(nees), bool)
    out[beyond[np.argsort(nees[beyond])[::-1][:cap]]] = True
    return out


def fit_without_gross_failures(fit: Callable[[np.ndarray], object], nees: Callable[[object], np.ndarray], n: int,
                               dof: int):
    """(params, failed (n,) bool): `fit(keep)` (keep (n,) bool, the scans to fit) refitted without the scans whose
    NEES under it, `nees(params)` (n,) over every scan, are gross failures (`gross_failures`), until the set left out
    repeats or after ROUNDS fits; params is the fit without the last set."""
    failed = np.zeros(n, bool)
    params = fit(~failed)
    for _ in range(ROUNDS - 1):
        now = gross_failures(nees(params), dof)
        if np.array_equal(now, failed):
            break
        failed = now
        params = fit(~failed)
    return params, failed

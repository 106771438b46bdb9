"""Power series of matrix functions of curlyhat(xi), reduced to degree four.

Any analytic f(S) = sum_n a_n S^n of S = curlyhat(xi) (6x6) can be written as
c_0 I + c_1 S + c_2 S^2 + c_3 S^3 + c_4 S^4, because S satisfies (paper eq. 70)

    S^5 + 2 phi^2 S^3 + phi^4 S = 0,    phi = |rotational part of xi|.

The coefficients c_i are functions of x = phi^2. Closed forms (e.g. paper eq. 72-75 for H) lose
precision for small phi (they divide by phi^6), so below a threshold they are evaluated from their
Taylor series in x, which this module derives exactly (rational arithmetic) from the reduction
S^{n+1} = S S^n and S^5 = -2 x S^3 - x^2 S. The same mechanism gives the SO(3) coefficients from
a^3 = -x a for a = phi^.

Checked by: tests/estimator/test_lie.py::test_taylor_coefficients_match_closed_forms
"""

from __future__ import annotations

from fractions import Fraction
from math import factorial

import numpy as np

_N_TERMS = 60  # terms of the defining series; far more than double precision needs below the threshold
_X_DEGREE = 12  # Taylor degree kept in x = phi^2


def _poly_add(p: list[Fraction], q: list[Fraction]) -> list[Fraction]:
    out = [Fraction(0)] * max(len(p), len(q))
    for i, c in enumerate(p):
        out[i] += c
    for i, c in enumerate(q):
        out[i] += c
    return out[: _X_DEGREE + 1]


def _poly_shift(p: list[Fraction], k: int, scale: Fraction) -> list[Fraction]:
    """scale * x^k * p(x), truncated."""
    return ([Fraction(0)] * k + [scale * c for c in p])[: _X_DEGREE + 1]


def _reduce_se3(a: list[Fraction]) -> np.ndarray:
    """Taylor coefficients (in x) of c_0..c_4 for f(S) = sum_n a[n] S^n on se(3)."""
    # r[i] = polynomial (in x) coefficient of S^i in the reduced form of the current power S^n.
    r = [[Fraction(0)] for _ in range(5)]
    r[0] = [Fraction(1)]
    acc = [[Fraction(0)] for _ in range(5)]
    for n in range(len(a)):
        for i in range(5):
            acc[i] = _poly_add(acc[i], [a[n] * c for c in r[i]])
        # multiply by S: S^i -> S^{i+1}, S^5 = -2x S^3 - x^2 S
        s5 = r[4]
        r = [
            [Fraction(0)],
            _poly_add(r[0], _poly_shift(s5, 2, Fraction(-1))),
            r[1],
            _poly_add(r[2], _poly_shift(s5, 1, Fraction(-2))),
            r[3],
        ]
    out = np.zeros((5, _X_DEGREE + 1))
    for i in range(5):
        for k, c in enumerate(acc[i][: _X_DEGREE + 1]):
            out[i, k] = float(c)
    return out


def _reduce_so3(a: list[Fraction]) -> np.ndarray:
    """Taylor coefficients (in x) of c_0..c_2 for f(A) = sum_n a[n] A^n, A = phi^, A^3 = -x A."""
    r = [[Fraction(1)], [Fraction(0)], [Fraction(0)]]
    acc = [[Fraction(0)] for _ in range(3)]
    for n in range(len(a)):
        for i in range(3):
            acc[i] = _poly_add(acc[i], [a[n] * c for c in r[i]])
        r = [[Fraction(0)], _poly_add(r[0], _poly_shift(r[2], 1, Fraction(-1))), r[1]]
    out = np.zeros((3, _X_DEGREE + 1))
    for i in range(3):
        for k, c in enumerate(acc[i][: _X_DEGREE + 1]):
            out[i, k] = float(c)
    return out


def _shifted_factorial_series(shift: int) -> list[Fraction]:
    return [Fraction(1, factorial(n + shift)) for n in range(_N_TERMS)]


def _bernoulli_series() -> list[Fraction]:
    """a_n = B_n / n! (B_1 = -1/2): the series of x / (e^x - 1), i.e. of the inverse left Jacobian."""
    b = [Fraction(1)]
    for m in range(1, _N_TERMS):
        b.append(-sum(Fraction(factorial(m + 1), factorial(k) * factorial(m + 1 - k)) * b[k] for k in range(m))
                 / (m + 1))
    return [b[n] / factorial(n) for n in range(_N_TERMS)]


# SO(3): exp (1/n!), left Jacobian (1/(n+1)!), its inverse (B_n/n!)
SO3_EXP = _reduce_so3(_shifted_factorial_series(0))
SO3_JAC = _reduce_so3(_shifted_factorial_series(1))
SO3_JAC_INV = _reduce_so3(_bernoulli_series())
# se(3) (curlyhat): Ad(exp) = sum S^n/n!, J = sum S^n/(n+1)!, H = sum S^n/(n+2)!
SE3_EXP = _reduce_se3(_shifted_factorial_series(0))
SE3_JAC = _reduce_se3(_shifted_factorial_series(1))
SE3_H = _reduce_se3(_shifted_factorial_series(2))


def horner(coeffs: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Evaluate sum_k coeffs[..., k] x^k for each leading row of coeffs; returns (rows, *x.shape)."""
    if np.ndim(x) == 0:  # scalar fast path (the solver's single-state calls)
        return coeffs @ (float(x) ** np.arange(coeffs.shape[1]))
    out = np.zeros((coeffs.shape[0],) + np.shape(x))
    for k in range(coeffs.shape[1] - 1, -1, -1):
        out = out * x + coeffs[:, k].reshape((-1,) + (1,) * np.ndim(x))
    return out

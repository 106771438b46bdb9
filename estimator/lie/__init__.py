"""Lie groups SO(3) and SE(3) in the paper's conventions: see docs/conventions.md.

`se3`, `so3`: the NumPy reference. `kernels`: their compiled (numba) counterparts and the upper-block matrix
kernels the priors and the solver share; import it explicitly (`from rodo.estimator.lie import kernels`), so that
the NumPy modules do not load numba.
"""

from . import se3, so3

__all__ = ["se3", "so3"]

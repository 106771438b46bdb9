"""Motion priors of the paper (sec. IV): constant acceleration (Magnus) and constant velocity.

`ConstantAccelerationPrior(Qc, magnus_order=3)` and `ConstantVelocityPrior(Qc)` are fast (numba kernels);
`estimator.priors.kernels` holds those compiled kernels (Magnus mean, F_k and Q_k fused, batched forms), used
directly by the solver; `estimator.priors.exact` holds the ODE references and `ExactConstantAccelerationPrior`
(same API, slow).
Derivations: docs/priors.md.
"""

from .constant_acceleration import ConstantAccelerationPrior
from .constant_velocity import ConstantVelocityPrior

__all__ = ["ConstantAccelerationPrior", "ConstantVelocityPrior"]

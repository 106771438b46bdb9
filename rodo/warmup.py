"""`python -m rodo.warmup`: compile (or load) every kernel the odometry runs, for all four models.

`make install` runs it once, so the first `rodo run`, `make demo` and the test suite find the numba cache
warm (`rodo.estimator.jit`: compiling takes a minute or more; loading the cache, about a second). It runs each
model on two seconds of the simulated `city` scenario; a second call only loads the cache.
"""

from __future__ import annotations

import sys
import time

MODELS = ("ca-polar", "cv-cartesian", "ca-cartesian", "cv-polar")


def main() -> int:
    from rodo import scenarios
    from rodo.estimator.config import OdometryConfig
    from rodo.validation.driver import run_sequence

    tic = time.perf_counter()
    seq, _ = scenarios.get("city").simulate(0, duration=2.0)
    for model in MODELS:
        run_sequence(seq, OdometryConfig.for_model(model))
    print(f"rodo: estimator kernels ready ({time.perf_counter() - tic:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

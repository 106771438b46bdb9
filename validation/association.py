"""Time association of two trajectories (or of estimates and truth): mutual nearest time stamps within a
tolerance. The one place where times are matched: `validation.metrics`, `validation.consistency` and the Rerun
recording (through `match_index`) all use it. Definition: docs/evaluation.md, "Time association".

Checked by: tests/validation/test_association.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.errors import InputError

DEFAULT_TOLERANCE = 1e-3  # s


def _times(name: str, t) -> np.ndarray:
    t = np.asarray(t, dtype=float)
    if t.ndim != 1:
        raise InputError(f"{name}: expected a 1-D array of times, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        k = int(np.flatnonzero(~np.isfinite(t))[0])
        raise InputError(f"{name}: time {float(t[k])!r} at index {k} is not finite")
    if t.size > 1 and np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise InputError(f"{name}: times must strictly increase (index {k}: {float(t[k])!r} after "
                         f"{float(t[k - 1])!r})")
    return t


def associate(t_a, t_b, tolerance: float = DEFAULT_TOLERANCE, min_matches: int = 2,
              min_fraction: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Match two strictly increasing time stamp lists: mutual nearest neighbours within `tolerance`.

    A pair (i, j) is kept when t_b[j] is the nearest stamp of b to t_a[i], t_a[i] the nearest of a to t_b[j],
    and |t_a[i] - t_b[j]| <= tolerance; so each stamp is used at most once.

    Args:
        t_a: (N,) times of the first trajectory (e.g. ground truth); t_b: (M,) of the second.
        tolerance: largest accepted time difference, seconds.
        min_matches: fewer matches is an error.
        min_fraction: fewer than this fraction of the shorter list matched is an error (mismatched files).

    Returns:
        (ia, ib): index arrays of equal length, increasing.

    Raises:
        InputError naming the argument: non-finite or unsorted times, or too few matches (with both time spans).

    Checked by: tests/validation/test_association.py::test_associate_*
    """
    t_a, t_b = _times("t_a", t_a), _times("t_b", t_b)
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise InputError(f"tolerance: must be a finite number >= 0, got {tolerance!r}")
    if t_a.size == 0 or t_b.size == 0:
        raise InputError(f"t_a, t_b: empty trajectory ({t_a.size} and {t_b.size} poses)")

    def nearest(src, dst):
        k = np.clip(np.searchsorted(dst, src), 1, max(len(dst) - 1, 1))
        lo = np.maximum(k - 1, 0)
        hi = np.minimum(k, len(dst) - 1)
        return np.where(np.abs(dst[lo] - src) <= np.abs(dst[hi] - src), lo, hi)

    j = nearest(t_a, t_b)
    back = nearest(t_b, t_a)
    ia = np.arange(len(t_a))
    ok = (back[j] == ia) & (np.abs(t_a - t_b[j]) <= tolerance)
    ia, ib = ia[ok], j[ok]
    need = max(min_matches, int(np.ceil(min_fraction * min(len(t_a), len(t_b)))))
    if len(ia) < need:
        raise InputError(
            f"t_a, t_b: only {len(ia)} time stamps match within {tolerance:g} s (need {need}); "
            f"first trajectory spans [{t_a[0]:.6f}, {t_a[-1]:.6f}] s with {len(t_a)} poses, second "
            f"[{t_b[0]:.6f}, {t_b[-1]:.6f}] s with {len(t_b)}: are these files of the same sequence?")
    return ia, ib


def match_index(t_a, t_b, tolerance: float = DEFAULT_TOLERANCE) -> np.ndarray:
    """For every stamp of t_a the index of its `associate`d stamp of t_b, or -1 where it has none.

    The same pairs as `associate(t_a, t_b, tolerance, min_matches=0, min_fraction=0)` (mutual nearest within
    `tolerance`), laid out per stamp of t_a: the form a per-scan plot needs, where a scan without truth is a gap
    rather than an error.

    Args:
        t_a: (N,) strictly increasing times (e.g. the estimates').
        t_b: (M,) strictly increasing times (e.g. the truth's), M >= 1.
        tolerance: largest accepted time difference, seconds.

    Returns:
        (N,) int64 indices into t_b, -1 where unmatched.

    Checked by: tests/validation/test_association.py::test_match_index_is_associate_per_stamp
    """
    ia, ib = associate(t_a, t_b, tolerance, min_matches=0, min_fraction=0.0)
    out = np.full(len(np.asarray(t_a)), -1, dtype=np.int64)
    out[ia] = ib
    return out

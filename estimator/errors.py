"""The one exception type for bad input: the CLI turns it into a message and exit code 2."""


class InputError(ValueError):
    """Bad input at a public boundary: says which file/line/field or argument, and why."""


def check_finite(name: str, value, shape: tuple | None = None):
    """Return value as a float array; raise InputError naming the argument if non-finite or misshaped.

    `shape` may contain -1 for "any" and may omit leading batch dimensions (it is matched from the right).
    """
    import numpy as np

    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: not a numeric array ({exc})") from None
    if shape is not None:
        tail = arr.shape[len(arr.shape) - len(shape):] if arr.ndim >= len(shape) else None
        if tail is None or any(s != -1 and s != t for s, t in zip(shape, tail)):
            want = "(..., " + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
            raise InputError(f"{name}: expected shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name}: contains NaN or infinity")
    return arr


def check_time(name: str, value) -> float:
    """Return value as a finite float (a time in seconds); raise InputError naming the argument otherwise."""
    import math

    try:
        t = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a time in seconds, got {value!r}") from None
    if not math.isfinite(t):
        raise InputError(f"{name}: must be finite, got {t}")
    return t


def check_rows(name: str, value, width: int):
    """Return value as an (n, width) float array (one row (width,) allowed); InputError naming the argument if
    non-finite or of another shape (an (m, k, width) array is not m * k rows)."""
    arr = check_finite(name, value, (width,))
    if arr.ndim > 2:
        raise InputError(f"{name}: expected shape (N, {width}), got {arr.shape}")
    return arr.reshape(-1, width)

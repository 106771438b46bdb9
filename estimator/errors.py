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

"""The one exception type for bad input: the CLI turns it into a message and exit code 2. And the errors of the
place a command writes to (a full disk, a quota, a file-size limit, a read-only or forbidden place), which are
the machine's, not the input's: the CLI reports them in one line with exit 1, and a campaign stops at them rather
than recording a trial as failed."""

import errno


class InputError(ValueError):
    """Bad input at a public boundary: says which file/line/field or argument, and why."""


# the OSErrors of the place a command writes to (`is_environment_error`); of those, no room (`out_of_space`)
SPACE_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
ENVIRONMENT_ERRORS = SPACE_ERRORS | {errno.EROFS, errno.EACCES, errno.EPERM}


def is_environment_error(exc: BaseException) -> bool:
    """True for an OSError of ENVIRONMENT_ERRORS: not a defect and not bad input, so not a result either (a trial
    that met a full disk did not fail; it is run again once there is room)."""
    return isinstance(exc, OSError) and exc.errno in ENVIRONMENT_ERRORS


def out_of_space(exc: BaseException) -> bool:
    """True for a full disk, a quota or a file-size limit (ENOSPC, EDQUOT, EFBIG): the environment's whatever the
    writer, where a place that cannot be written at all (EACCES, EROFS) may be the user's choice of output, which the
    commands that check their outputs first refuse as input (exit 2)."""
    return isinstance(exc, OSError) and exc.errno in SPACE_ERRORS


def naming(exc: OSError, path, tmp=None) -> OSError:
    """`exc` with `path` as its filename where it names none or the temporary file `tmp` written for it: an error
    from write, flush or fsync carries no filename, and the user wants the file being written, not
    `.NAME.xxxx.tmp`. A file it names otherwise (another file's error) is kept."""
    if exc.filename is None or (tmp is not None and str(exc.filename) == str(tmp)):
        exc.filename = str(path)
    return exc


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

"""The files of a Monte Carlo campaign directory: `results.csv` (one row per trial and model, appended with
flush + fsync) and `trials/trial_XXXX_MODEL.npz` (per-scan arrays, written atomically). Layout:
docs/evaluation.md, "Monte Carlo campaigns"; the runner is `validation.campaign`.

Checked by: tests/validation/test_campaign.py
"""

from __future__ import annotations

import csv
import io
import os
import zipfile
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError, naming
from rodo.sim.sequence import atomic_write_bytes

# the columns of results.csv before the odometry consistency measures (a campaign started then still resumes:
# read_results fills the new columns with "", and resume rewrites the file with the current header)
FIELDS_V1 = ("trial", "seed", "model", "status", "kitti_t_err_pct", "kitti_r_err_deg_per_m", "ate_rmse_m",
             "rpe_trans_pct", "drift_x_m", "drift_y_m", "drift_z_m", "drift_roll_deg", "drift_pitch_deg",
             "drift_yaw_deg", "max_abs_z_m", "max_abs_roll_deg", "max_abs_pitch_deg", "nees_mean", "nees_dim",
             "nis_mean", "nu_rmse_mps", "ms_per_scan", "scans", "path_length_m", "wall_s", "error")
# mean NEES / dof over a run's scans of each `validation.odometry_consistency` measure (docs/evaluation.md)
CONSISTENCY_FIELDS = ("nees_velocity_per_dof", "nees_acceleration_per_dof", "nees_relative_scan_per_dof",
                      "nees_relative_span_per_dof", "nees_pose_per_dof", "nees_pose_window_per_dof")
FIELDS_V2 = FIELDS_V1[:-1] + CONSISTENCY_FIELDS + ("error",)  # before the ellipsoid coverage (session 36)
# the % of a run's scans whose true position is inside the 3-sigma ellipsoid of its absolute pose covariance
COVERAGE_FIELDS = ("ellipsoid_3sigma_pct",)
FIELDS = FIELDS_V2[:-1] + COVERAGE_FIELDS + ("error",)
METRICS = FIELDS[4:-1]


def append_rows(path: Path, rows: list[dict]) -> None:
    """Append rows to results.csv (header first if the file is new), flushed and fsync'ed before returning."""
    new = not path.exists() or path.stat().st_size == 0
    try:
        with open(path, "a", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=FIELDS, extrasaction="ignore")
            if new:
                w.writeheader()
            for row in rows:
                w.writerow({k: cell(row.get(k, "")) for k in FIELDS})
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:  # a write or fsync error names no file
        raise naming(exc, path) from None


def cell(v):
    """A CSV cell: floats by repr (round trip), multi-line text on one line."""
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return " | ".join(v.splitlines())
    return v


def read_results(path: str | Path) -> list[dict]:
    """Rows of results.csv as dicts of strings (every key of FIELDS; a file with an older header, FIELDS_V1 or
    FIELDS_V2, gets "" in the columns it lacks); a torn last row (crash while writing) is dropped, and a torn
    header alone is no rows."""
    path = Path(path)
    if not path.exists():
        return []
    text = path.read_text()
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return []
    header = tuple(rows[0])
    if "\n" not in text and header[:-1] == FIELDS[:len(header) - 1] and len(header) <= len(FIELDS) \
            and FIELDS[len(header) - 1].startswith(header[-1]):
        return []  # a header torn by a full disk in the first write: no row yet (the resume writes it whole)
    if header not in (FIELDS, FIELDS_V2, FIELDS_V1):
        raise InputError(f"{path}: line 1: unexpected header (expected {','.join(FIELDS)})")
    body = rows[1:] if text.endswith("\n") else rows[1:-1]  # a final row without its newline is torn: drop it
    out, first = [], {}
    for line, row in enumerate(body, start=2):
        if len(row) != len(header) or row[3] not in ("ok", "error") or not row[0].isdigit():
            raise InputError(f"{path}: line {line}: malformed row ({len(row)} fields, status {row[3:4]})")
        r = {**dict.fromkeys(FIELDS, ""), **dict(zip(header, row))}
        key = (int(r["trial"]), r["model"])
        if key in first:  # each run is written once (a resume rewrites the file without the runs it repeats)
            raise InputError(f"{path}: line {line}: trial {key[0]}, model {key[1]} again (first on line "
                             f"{first[key]})")
        first[key] = line
        for k in METRICS:
            if not _number(r[k]):
                raise InputError(f"{path}: line {line}: {k} is {r[k]!r}, not a number")
        out.append(r)
    return out


def _number(text: str) -> bool:
    """A metric cell: empty, None (not measured), or a float's text (nan and inf included)."""
    if text in ("", "None"):
        return True
    try:
        float(text)
    except ValueError:
        return False
    return True


def rewrite_results(path: Path, rows: list[dict]) -> None:
    """Replace results.csv by these rows, atomically (`atomic_write_bytes`: a uniquely named temporary file,
    fsync, rename; the temporary file removed on failure)."""
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=FIELDS)
    w.writeheader()
    w.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode("utf-8"))


def npz_path(out_dir: str | Path, trial: int, model: str) -> Path:
    """trials/trial_XXXX_MODEL.npz of one run."""
    return Path(out_dir) / "trials" / f"trial_{trial:04d}_{model}.npz"


def writes_arrays(out: Path, rows: list[dict], model: str) -> bool:
    """Whether any ok row of `model` among `rows` has its trial arrays on disk (the campaign writes them)."""
    return any(npz_path(out, int(r["trial"]), model).exists() for r in rows
               if r["model"] == model and r["status"] == "ok")


def save_arrays(path: Path, arrays: dict) -> None:
    """Write a run's per-scan arrays as .npz, atomically (`atomic_write_bytes`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    atomic_write_bytes(path, buf.getvalue())


def load_trial_arrays(path: Path, needed: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """A run's per-scan arrays (np.load with allow_pickle=False); an InputError naming the file if it is
    truncated, corrupt or lacks one of `needed`, with the way out."""
    way_out = "resume the campaign (--resume) to run that trial again"
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # our handle: closed on a bad file too
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, TypeError, EOFError, zipfile.BadZipFile) as exc:  # TypeError: a .npy, not .npz
        raise InputError(f"{path}: unreadable trial arrays ({type(exc).__name__}: {exc}); {way_out}") from None
    missing = [k for k in needed if k not in arrays]
    if missing:
        raise InputError(f"{path}: no {', '.join(missing)} array in the trial arrays; {way_out}")
    return arrays

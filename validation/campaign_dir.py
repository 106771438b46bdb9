"""A campaign directory's ownership and identity: the lock that keeps a second writer out, and campaign.json,
the parameters that say which campaign the directory holds (docs/evaluation.md, "Monte Carlo campaigns").

- `campaign_lock(out_dir)`: an exclusive `fcntl.flock` on `out_dir/.campaign.lock`, held for as long as the
  context lasts and released on exit (also on an error or KeyboardInterrupt; the kernel drops it when the
  process dies). A second writer, in another process, gets an InputError naming the directory. The lock is
  re-entrant within one process (a command holds it over the whole run, `run_campaign` takes it again inside).
- `check_and_save_meta(out_dir, meta, resume)`: refuse to overwrite a campaign, to resume a different one, to
  resume without (or with a corrupt) campaign.json, or to shrink one; a larger `runs` extends it. A refused
  resume names each differing parameter on one line (`describe_difference`: long values by a digest).

Checked by: tests/validation/test_campaign_lock.py
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
from pathlib import Path

from rodo.estimator.errors import InputError
from rodo.sim.sequence import atomic_write_bytes

LOCK_NAME = ".campaign.lock"
_held: dict[str, int] = {}  # lock files held by this process -> nesting depth (re-entrancy)


def prepare_dir(out_dir, option: str = "--out") -> Path:
    """Create out_dir (and its parents); an InputError naming `option` if it is a file or cannot be written."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{option}: {out} exists and is not a directory; choose a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option}: cannot create directory {out}: {exc.strerror or exc}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"{option}: directory {out} is not writable; choose another directory")
    return out


@contextlib.contextmanager
def campaign_lock(out_dir, option: str = "--out"):
    """Hold the exclusive lock of a campaign directory (created if missing) for the duration of the context.

    Raises:
        InputError: another process holds it ("... is in use by another campaign"), or out_dir is not a
            writable directory.

    Checked by: tests/validation/test_campaign_lock.py::test_second_writer_is_refused_while_the_first_runs
    """
    out = prepare_dir(out_dir, option)
    path = out / LOCK_NAME
    key = os.path.realpath(path)
    if key in _held:
        _held[key] += 1
        try:
            yield out
        finally:
            _held[key] -= 1
        return
    fd = _acquire(path, out, option)
    _held[key] = 1
    try:
        yield out
    finally:
        del _held[key]
        # unlock explicitly: worker processes forked meanwhile share the descriptor, and closing ours alone
        # would leave the lock held until they exit
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def _acquire(path: Path, out: Path, option: str) -> int:
    """Open (no symlink following) and flock the lock file without waiting; its text records the holder."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        raise InputError(f"{option}: cannot open the campaign lock {path}: {exc.strerror or exc}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
        os.close(fd)
        raise InputError(f"{option}: {out} is in use by another campaign ({holder} holds {path}); wait for it "
                         "to finish or choose another directory") from None
    except BaseException:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()}\n".encode(), 0)
    return fd


def load_meta(path: Path) -> dict:
    """campaign.json as a dict; an InputError naming the file and the way out if it is unreadable."""
    way_out = "restore it, or start a fresh campaign in another directory"
    try:
        saved = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"resume: {path} is missing, so nothing says which campaign {path.parent} holds; "
                         f"{way_out}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"resume: cannot read {path} ({exc}); {way_out}") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"resume: {path}: line {exc.lineno} column {exc.colno}: not valid JSON ({exc.msg}); "
                         f"{way_out}") from None
    if not isinstance(saved, dict):
        raise InputError(f"resume: {path}: expected a JSON object, got {type(saved).__name__}; {way_out}")
    return saved


def check_and_save_meta(out: Path, meta: dict, resume: bool) -> None:
    """Refuse to overwrite a campaign (without resume), to resume a different one or to shrink one; a larger
    meta["runs"] than the saved one extends the campaign. Saves campaign.json (when meta is given).

    Checked by: tests/validation/test_campaign_lock.py::test_extended_resume_equals_a_fresh_campaign
    """
    csv_path, meta_path = out / "results.csv", out / "campaign.json"
    if csv_path.exists() and not resume:
        raise InputError(f"out: {csv_path} exists; pass --resume to continue that campaign or choose another "
                         "directory")
    if resume and meta and (csv_path.exists() or meta_path.exists()):
        saved = load_meta(meta_path)
        _check_runs(meta_path, saved.get("runs"), meta.get("runs"))
        diff = sorted(k for k in set(saved) | set(meta) if k != "runs" and saved.get(k) != meta.get(k))
        if diff:
            raise InputError(f"resume: {meta_path} was written for a different campaign (differs in "
                             f"{'; '.join(describe_difference(k, saved.get(k), meta.get(k)) for k in diff)})")
    if meta:
        atomic_write_bytes(meta_path, (json.dumps(meta, indent=2, sort_keys=True) + "\n").encode("utf-8"))


SHORT_VALUE = 60  # characters of a value's repr shown as it is; a longer one by its SHA-256 prefix


def describe_difference(key: str, saved, now) -> str:
    """One line on how campaign.json's `key` differs: short values as they are (`saved 0, now 1`); long ones
    (config texts) by a SHA-256 prefix and length, and for a dict (`configs`: label -> config text) only the
    labels added, removed or changed, e.g. `configs: cvx changed (saved sha256 68c371d8bb9a, 2411 characters;
    now sha256 0d4445c8f5b3, 2418 characters)`. A text's digest is the one `sha256sum` prints for its file.

    Checked by: tests/cli/test_review2_campaign_resume.py::test_resume_with_an_edited_config_names_the_label_briefly
    """
    if isinstance(saved, dict) and isinstance(now, dict) and max(len(repr(saved)), len(repr(now))) > SHORT_VALUE:
        parts = []
        for label in sorted(set(saved) | set(now), key=str):
            if label not in saved:
                parts.append(f"{label} added ({_brief(now[label])})")
            elif label not in now:
                parts.append(f"{label} removed (saved {_brief(saved[label])})")
            elif saved[label] != now[label]:
                parts.append(f"{label} changed (saved {_brief(saved[label])}; now {_brief(now[label])})")
        return f"{key}: {', '.join(parts)}"
    return f"{key}: saved {_brief(saved)}, now {_brief(now)}"


def _brief(value) -> str:
    """repr(value) when short, else its SHA-256 prefix (of the text, or of its JSON) and size; a dict by entry."""
    text = repr(value)
    if len(text) <= SHORT_VALUE:
        return text
    if isinstance(value, str):
        return f"sha256 {hashlib.sha256(value.encode('utf-8')).hexdigest()[:12]}, {len(value)} characters"
    if isinstance(value, dict):  # e.g. configs against none: the labels, each briefly
        return "{" + ", ".join(f"{k!r}: {_brief(v)}" for k, v in value.items()) + "}"
    data = json.dumps(value, sort_keys=True, default=str).encode("utf-8")
    return f"{type(value).__name__} of JSON sha256 {hashlib.sha256(data).hexdigest()[:12]}, {len(data)} bytes"


def _check_runs(meta_path: Path, saved, now) -> None:
    """A resume may keep or raise the number of runs (extend), never lower it."""
    if saved == now:
        return
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (saved, now)):
        raise InputError(f"resume: {meta_path} was written for a different campaign (differs in runs: saved "
                         f"{saved!r}, now {now!r})")
    if now < saved:
        raise InputError(f"--runs: {now} is fewer than the {saved} runs of the campaign in {meta_path.parent} "
                         f"({meta_path}); a campaign cannot shrink: pass --runs {saved}, or more to extend it")

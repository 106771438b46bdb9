"""A Rerun recording written to a file from Python (`recording_file`), so that a write that fails raises.

`RecordingStream.save` hands the file to Rerun's native sink, which logs a failed write (a full disk, a quota, a
file-size limit) and then waits for ever in its flush. Here the stream records into memory
(`RecordingStream.binary_stream`) and its bytes are written once, when the recording is complete, to a temporary
file beside the target, which is then synced and renamed (`sim.sequence.replace_synced`).

The bytes are read once: each read of a BinaryStream (Rerun 0.41) is a whole RRD stream with its own manifest, and
two of them in one file are a corrupt .rrd ("More than one RRD manifest"; session 56's drain, which read every
0.5 s, wrote such files whenever a recording took longer). The price is memory: a recording is held until it is
written, about 1 MB per second of drive at the default detail (the demo's 20 s: 18 MB).

Checked by: tests/viz/test_sequence_recording.py::test_an_unwritable_recording_raises_and_leaves_nothing,
    tests/viz/test_sequence_recording.py::test_a_slow_recording_is_one_readable_rrd,
    tests/viz/test_recording.py (every recording read back)
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from rodo.estimator.errors import naming
from rodo.sim.sequence import replace_synced, temporary_beside


@contextlib.contextmanager
def recording_file(rr, path, recording_id: str | None):
    """A RecordingStream whose recording goes to a uniquely named temporary file beside `path`; when the block
    completes it is flushed, written, synced and renamed to `path` (a crash never leaves half a recording under
    the final name), and when the block raises, or the file cannot be written, the temporary file is removed.

    The temporary file is opened before the block runs, so a place that cannot be written fails before the work;
    a write that fails (a full disk, a quota, a file-size limit) raises as the OSError it is, naming `path`.
    Rerun's own file sink (`save`) only logs such an error, and its flush then waits for ever (the review of
    session 56, finding 2)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_beside(path)
    rec = rr.RecordingStream("rodo", recording_id=recording_id)
    stream = rec.binary_stream()
    try:
        with open(tmp, "wb") as fh:
            yield rec
            fh.write(stream.read(flush=True) or b"")
    except BaseException as exc:
        rec.disconnect()
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise naming(exc, path, tmp)
        raise
    rec.disconnect()
    replace_synced(tmp, path)

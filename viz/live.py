"""Live Rerun stream of `rodo run`, scan by scan while the estimator runs: `--connect [URL]` sends to a running
viewer (or a `rerun --serve-grpc` proxy), `--serve` hosts a gRPC server and the web viewer in this process, as
Rerun's own examples do (`rr.script_setup`). The `.rrd` of `--rerun` is written after the run, unchanged.

Entity paths are those of `record_run` (docs/visualisation.md): `world/vehicle` (estimated T_world_vehicle per
frame), `world/estimate/trajectory` (the path so far), `world/vehicle/sensor/scan` (detections, class ids of
DETECTION_CLASSES when the association detail is kept), `world/map`, `velocity/<nu_x ...>`, `events`.
Timelines `frame` and `time`, as in the recording.

Checked by: tests/viz/test_live.py
"""

from __future__ import annotations

import socket
from urllib.parse import urlsplit

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import so3
from rodo.estimator.measurements import polar_to_cartesian

from .recording import DETECTION_CLASSES, ESTIMATE_COLOUR, VELOCITY_NAMES, detection_classes

DEFAULT_PORT = 9876  # the viewer's default gRPC port


def grpc_url(value: str | None) -> str:
    """A viewer address for `--connect`: None -> the local default viewer; a port ('9877'), 'host:port' or a
    full 'rerun+http://host:port/proxy' URL. InputError naming --connect otherwise."""
    if value is None or value == "":
        return f"rerun+http://127.0.0.1:{DEFAULT_PORT}/proxy"
    if value.startswith(("rerun://", "rerun+http://", "rerun+https://")):
        return value
    host, _, port = value.rpartition(":")
    if port.isdigit() and 0 < int(port) < 65536 and (host or ":" not in value):
        return f"rerun+http://{host or '127.0.0.1'}:{port}/proxy"
    raise InputError(f"--connect: expected a port, HOST:PORT or a rerun+http://HOST:PORT/proxy URL, got {value!r}")


def check_viewer(url: str, timeout: float = 3.0) -> None:
    """InputError naming --connect when nothing accepts connections at the viewer address `url` (a `grpc_url`):
    the SDK would otherwise buffer the whole run for a viewer that never comes, and wait for it at the end."""
    parts = urlsplit(url.split("+", 1)[1] if url.startswith("rerun+") else url.replace("rerun://", "http://", 1))
    host, port = parts.hostname or "127.0.0.1", parts.port or DEFAULT_PORT
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as e:
        raise InputError(f"--connect: no Rerun viewer is listening at {host}:{port} ({e.strerror or e}); start one "
                         "first (`rerun`, or `rerun --port N` for another port), or use --serve or --rerun OUT.rrd") \
            from None


class LiveRun:
    """Streams each scan of a run as the driver reports it (`on_scan` is `run_sequence`'s callback).

    Args:
        seq: the sequence being run (sensor extrinsics).
        connect: viewer URL (see `grpc_url`) or None.
        serve: host a gRPC server and a web viewer (`url` is the server's address).
        recording: an open `rr.RecordingStream` to log into instead (tests pass one with a memory sink).
        open_browser: with `serve`, open the web viewer in a browser.
    """

    def __init__(self, seq, connect: str | None = None, serve: bool = False, recording=None,
                 open_browser: bool = True, recording_id: str | None = None):
        import rerun as rr

        self.rr, self.url, self.connected = rr, None, connect is not None
        self.rec = recording if recording is not None else rr.RecordingStream("rodo", recording_id=recording_id)
        if connect is not None:
            self.url = grpc_url(connect)
            self.rec.connect_grpc(self.url)
        elif serve:
            self.url = self.rec.serve_grpc()
            rr.serve_web_viewer(connect_to=self.url, open_browser=open_browser)
        self.positions: list[np.ndarray] = []
        self._log_static(seq)

    def _log_static(self, seq) -> None:
        rr, rec = self.rr, self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("world", rr.AnnotationContext([(i, label, colour) for i, (label, colour) in
                                               DETECTION_CLASSES.items()]), static=True)
        T = seq.sensor.T_vehicle_sensor
        rec.log("world/vehicle/sensor", rr.Transform3D(translation=T[:3, 3], quaternion=so3.to_quaternion(T[:3, :3])),
                rr.TransformAxes3D(axis_length=0.8), static=True)
        rec.log("world/vehicle", rr.TransformAxes3D(axis_length=2.0), static=True)
        for name in VELOCITY_NAMES:
            rec.log(f"velocity/{name.split(' ')[0]}", rr.SeriesLines(names=[f"estimate {name}"],
                                                                     colors=[ESTIMATE_COLOUR]), static=True)

    def on_scan(self, k: int, t: float, scan, est) -> None:
        """Log frame k: the pose, the path so far, the scan (class ids from est.detail when kept), the local
        map, the body velocity and the events."""
        rr, rec = self.rr, self.rec
        rec.set_time("frame", sequence=k)
        rec.set_time("time", duration=float(t))
        T = est.T_world_vehicle
        rec.log("world/vehicle", rr.Transform3D(translation=T[:3, 3], quaternion=so3.to_quaternion(T[:3, :3])))
        self.positions.append(T[:3, 3].copy())
        rec.log("world/estimate/trajectory", rr.LineStrips3D([np.array(self.positions)], colors=[ESTIMATE_COLOUR],
                                                             radii=0.08))
        d = est.detail
        if d is not None:
            rec.log("world/vehicle/sensor/scan", rr.Points3D(polar_to_cartesian(d.polar), class_ids=detection_classes(d),
                                                             radii=0.15))
            rec.log("world/map", rr.Points3D(d.map_points, colors=[(90, 90, 90)], radii=0.1))
        elif scan is not None:
            rec.log("world/vehicle/sensor/scan", rr.Points3D(scan.points_sensor, class_ids=np.full(len(scan), 4),
                                                             radii=0.15))
        for name, value in zip(VELOCITY_NAMES, est.varpi):
            rec.log(f"velocity/{name.split(' ')[0]}", rr.Scalars(float(value)))
        if est.events:
            rec.log("events", rr.TextLog("; ".join(est.events), level="INFO"))

    def close(self, timeout: float = 10.0) -> str | None:
        """Flush what is buffered; close a connection (a server keeps serving until the process ends). Returns
        None, or why the viewer did not get everything (it went away during the run) after at most about
        `timeout` s plus the SDK's own few seconds of grace."""
        problem = None
        try:
            self.rec.flush(timeout_sec=timeout)
        except RuntimeError as e:  # the SDK's "unable to connect" once the timeout has passed
            problem = f"the live viewer at {self.url} did not receive the whole run ({e})"
        if self.connected:
            self.rec.disconnect()
        return problem

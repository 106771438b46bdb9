"""ROS bags (ROS 1 `.bag`, ROS 2 bag directories with sqlite3 or mcap storage, bare `.mcap` files) -> the
sequence format. Reads one `sensor_msgs/PointCloud2` topic with the `rosbags` package (pure Python, imported
only here and only when a bag is converted: `pip install rosbags`).

- Points: Cartesian fields (default `x,y,z`, sensor frame x forward, y left, z up) turned into range,
  azimuth, elevation in float64 (paper eq. 80, `polar_from_xyz`), or polar fields (`polar=(R, AZ, EL)`, metres
  and radians) taken as they are.
- Doppler: one field (default: the first of DOPPLER_NAMES present). The sequence format's sign convention is
  d(range)/dt, **negative when approaching** (docs/conventions.md: v_r = -u . v for a static target); a
  sensor that reports positive approaching speeds needs `flip_doppler=True`.
- Time of a scan: the message's header stamp; when every stamp is zero or the stamps do not increase (the TI
  demo bag: ti_mmwave_rospkg writes stamp 0), the bag's record (receive) time instead, said in a note.
  Seconds from the first scan; its absolute time in ns is `t0_ns` in conversion.json.
- Every other scalar numeric field present in all messages is kept as an extra column (its name).
- Vehicle frame = sensor frame (T_vehicle_sensor identity), nominal noise (override with --sigma), no ground
  truth.
- Refused, naming the bag, topic, message and field: scan times that do not strictly increase (with the other
  --time to try), a median step between them that is no scan rate (0.1-1000 Hz), more than 1 % of the polar
  azimuths or elevations out of range (degrees, [0, 2pi); fewer are dropped and counted), no detections.

Checked by: tests/sim/test_convert_rosbag.py, tests/sim/test_convert_review55_rosbag.py
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.sensor_values import ANGLE_BOUNDS, angle_hint
from rodo.sim.sequence import NoiseSigmas, SensorConfig, Sequence
from rodo.sim.sequence_types import REQUIRED_COLUMNS

from ._common import (Conversion, ConversionReport, check_scan_step, drop_few, field_of_view, polar_from_xyz,
                      require_detections, scans_from_rows)

POINTCLOUD2 = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2")
DOPPLER_NAMES = ("velocity", "doppler", "radial_velocity", "v_r", "vr", "v_radial")
# sensor_msgs/PointField datatypes -> numpy
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
# nominal 1-sigma of a 3+1D radar; override with --sigma
DEFAULT_SIGMAS = NoiseSigmas(range=0.1, azimuth=float(np.deg2rad(1.5)), elevation=float(np.deg2rad(1.5)),
                             radial_velocity=0.1)
TIME_SOURCES = ("auto", "header", "record")


@dataclass
class Cloud:
    """One PointCloud2 message: record (bag) time and header stamp in ns, and its points by field name."""

    record_ns: int
    header_ns: int
    fields: dict[str, np.ndarray]


def _rosbags():
    """The parts of rosbags used here; InputError naming the install command when it is missing."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise InputError("reading ROS bags needs the rosbags package: pip install 'rodo[ros]'") from None
    return AnyReader, Stores, get_typestore


def decode_cloud(msg, where: str) -> dict[str, np.ndarray]:
    """Scalar fields of a PointCloud2 message -> name -> (n,) float64 (count > 1 fields skipped).

    Rows may be padded (row_step > width * point_step); byte order from is_bigendian.
    """
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.count != 1 or f.datatype not in DATATYPES:
            continue
        names.append(f.name)
        formats.append(order + DATATYPES[f.datatype])
        offsets.append(f.offset)
    n_rows, width, step = int(msg.height), int(msg.width), int(msg.point_step)
    data = np.frombuffer(bytes(np.asarray(msg.data, dtype=np.uint8)), dtype=np.uint8)
    if n_rows * width == 0:
        return {name: np.zeros(0) for name in names}
    if step <= 0 or msg.row_step < width * step or len(data) < (n_rows - 1) * msg.row_step + width * step:
        raise InputError(f"{where}: PointCloud2 data too short for height {n_rows} x width {width} x "
                         f"point_step {step} (row_step {msg.row_step}, {len(data)} bytes)")
    try:
        dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    except ValueError as exc:
        raise InputError(f"{where}: PointCloud2 fields do not fit point_step {step} ({exc})") from None
    rows = [np.frombuffer(data, dtype=dtype, count=width, offset=r * int(msg.row_step)) for r in range(n_rows)]
    points = np.concatenate(rows)
    return {name: points[name].astype(np.float64) for name in names}


def read_clouds(bag, topic: str, progress=None) -> tuple[list[Cloud], str]:
    """All PointCloud2 messages of `topic` in record order, and the bag's kind ('ROS 1', 'ROS 2').
    `progress`: optional object with update(), called once per message read.

    Raises:
        InputError naming the bag and the topic: missing or unreadable bag, topic absent (the topics of the
        bag are listed), a message type other than PointCloud2, no message on the topic.
    """
    AnyReader, Stores, get_typestore = _rosbags()
    path = Path(bag)
    if not path.exists():
        raise InputError(f"BAG: {path}: not found")
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                found = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
                raise InputError(f"{path}: no topic {topic!r} (topics: {found})")
            bad = sorted({c.msgtype for c in conns if c.msgtype not in POINTCLOUD2})
            if bad:
                raise InputError(f"{path}, topic {topic}: message type {bad[0]}, expected "
                                 f"sensor_msgs/msg/PointCloud2")
            clouds = []
            for k, (conn, t_ns, raw) in enumerate(reader.messages(connections=conns)):
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                clouds.append(Cloud(int(t_ns), stamp, decode_cloud(msg, f"{path}, topic {topic}, message {k}")))
                if progress is not None:
                    progress.update()
            kind = "ROS 2" if reader.is2 else "ROS 1"
    except InputError:
        raise
    except Exception as exc:  # rosbags raises its own error classes and struct/key errors on corrupt files
        raise InputError(f"{path}: cannot read as a ROS 1 bag, ROS 2 bag or mcap file "
                         f"({type(exc).__name__}: {exc})") from None
    if not clouds:
        raise InputError(f"{path}, topic {topic}: no messages")
    return clouds, kind


def scan_times_ns(clouds: list[Cloud], time: str, report: ConversionReport, where: str = "BAG") -> np.ndarray:
    """(S,) int64 time of each message in ns: header stamps, or record times (see module docstring); strictly
    increasing, at a scan rate of 0.1-1000 Hz, or an InputError naming `where` (bag and topic), the message and
    its time, and the other --time to try.

    Checked by: tests/sim/test_convert_review55_rosbag.py::test_duplicate_record_times_name_bag_topic_message_and_time
    """
    if time not in TIME_SOURCES:
        raise InputError(f"--time: expected one of {', '.join(TIME_SOURCES)}, got {time!r}")
    header = np.array([c.header_ns for c in clouds], dtype=np.int64)
    record = np.array([c.record_ns for c in clouds], dtype=np.int64)
    usable = bool(np.all(header > 0) and np.all(np.diff(header) > 0))
    if time == "header" and not usable:
        raise InputError(f"--time header: the header stamps are zero or do not increase in {where} "
                         "(use --time record for the bag's record time)")
    if time == "record" or (time == "auto" and not usable):
        _check_times(record, "record time", where, "try --time header" if usable else
                     "the header stamps (--time header) are zero or do not increase either")
        why = "" if time == "record" else " (the header stamps are zero or do not increase)"
        report.notes.append(f"WARNING: scan times are the bag's record (receive) times{why}, not the "
                            f"sensor's measurement times; they lag the measurement by the transport delay")
        report.info["time"] = "bag record time, seconds from t0_ns"
        return record
    _check_times(header, "header stamp", where, "try --time record" if np.all(np.diff(record) > 0) else
                 "the record times (--time record) do not increase either")
    report.info["time"] = "header stamp, seconds from t0_ns"
    return header


def _check_times(t_ns: np.ndarray, what: str, where: str, other: str) -> None:
    """InputError naming the first message whose time `what` is not above the previous one's, or the median
    step when it is no scan rate; `other` says what the other --time would give."""
    steps = np.diff(t_ns)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise InputError(f"{where}, message {k}: {what} {int(t_ns[k])} ns is not after message {k - 1}'s "
                         f"({int(t_ns[k - 1])} ns): scan times must strictly increase; {other}")
    try:
        check_scan_step(t_ns, 1e-9, "ns", f"{where}, {what}s")
    except InputError as exc:
        raise InputError(f"{exc} ({other})") from None


def _pick_doppler(available, doppler: str | None, where: str) -> str:
    if doppler is not None:
        return doppler
    for name in DOPPLER_NAMES:
        if name in available:
            return name
    raise InputError(f"{where}: no Doppler field (looked for {', '.join(DOPPLER_NAMES)}; found "
                     f"{', '.join(available)}): name it with --doppler")


def _stack_fields(clouds: list[Cloud], needed: tuple[str, ...], where: str):
    """Concatenate the needed fields and the common extra fields of all messages; InputError naming the first
    message that lacks a needed field."""
    for k, c in enumerate(clouds):
        missing = [f for f in needed if f not in c.fields]
        if missing:
            raise InputError(f"{where}, message {k}: missing field(s) {', '.join(missing)} "
                             f"(found {', '.join(c.fields) or 'none'})")
    common = set.intersection(*(set(c.fields) for c in clouds))
    extras = [f for f in clouds[0].fields if f in common and f not in needed and f.isidentifier()
              and f not in REQUIRED_COLUMNS]
    cols = {f: np.concatenate([c.fields[f] for c in clouds]) for f in (*needed, *extras)}
    return cols, extras


def convert(bag, topic: str, xyz=("x", "y", "z"), polar=None, doppler: str | None = None,
            flip_doppler: bool = False, time: str = "auto", progress=None) -> Conversion:
    """Convert one PointCloud2 topic of a ROS bag (see module docstring) into one Conversion named 'rosbag'.

    Args:
        bag: ROS 1 .bag file, ROS 2 bag directory (sqlite3 or mcap) or .mcap file.
        topic: the PointCloud2 topic.
        xyz: names of the Cartesian fields (used when `polar` is None).
        polar: names of the range, azimuth, elevation fields (metres, radians), or None.
        doppler: name of the Doppler field, None for the first of DOPPLER_NAMES present.
        flip_doppler: negate the Doppler (for sensors reporting positive when approaching).
        time: 'auto' (header stamps unless zero / not increasing, then record time), 'header', 'record'.
        progress: optional object with update(), called once per message read (rodo.progress.Progress).

    Checked by: tests/sim/test_convert_rosbag.py::test_ros2_bag_round_trip,
        ::test_ros1_bag_polar_fields_record_time_and_flip,
        ::test_ti_demo_bag_matches_the_csv_export
    """
    clouds, kind = read_clouds(bag, topic, progress)
    where = f"{bag}, topic {topic}"
    report = ConversionReport("rosbag", str(bag))
    t_ns = scan_times_ns(clouds, time, report, where)
    dop = _pick_doppler(list(clouds[0].fields), doppler, where)
    geometry = tuple(polar) if polar is not None else tuple(xyz)
    cols, extras = _stack_fields(clouds, (*geometry, dop), where)
    n = np.array([len(c.fields[dop]) for c in clouds])
    scan = np.repeat(np.arange(len(clouds)), n)
    vr = -cols[dop] if flip_doppler else cols[dop]
    vals = np.stack([cols[f] for f in (*geometry, dop)])
    keep = report.drop("detections with NaN or infinity", ~np.all(np.isfinite(vals), axis=0))
    if polar is not None:
        rng, az, el = (cols[f] for f in geometry)
        keep = _polar_kept(report, keep, rng, az, el, geometry, scan, where)
    else:
        rng, az, el = polar_from_xyz(np.where(keep[:, None], vals[:3].T, 1.0))
        keep &= report.drop("detections at zero range", keep & ~(rng > 1e-6))
    t0_ns = int(t_ns[0])
    t_scan = (t_ns - t0_ns).astype(np.float64) * 1e-9
    scans = scans_from_rows(report, scan[keep], t_scan, rng[keep], az[keep], el[keep], vr[keep],
                            {f: cols[f][keep] for f in extras})
    require_detections(report, where)
    report.info.update({"t0_ns": t0_ns, "topic": topic, "bag": kind, "doppler_field": dop,
                        "geometry_fields": list(geometry), "flip_doppler": bool(flip_doppler),
                        "extra_columns": extras})
    _add_notes(report, kind, dop, flip_doppler, len(clouds))
    sensor = _sensor(t_scan, rng[keep], az[keep], el[keep])
    return Conversion("rosbag", Sequence(sensor=sensor, scans=scans, groundtruth=None), report)


def _polar_kept(report: ConversionReport, keep, rng, az, el, fields, scan, where: str) -> np.ndarray:
    """The keep mask less polar detections with range <= 0 and angles out of range (dropped and counted; more
    than 1 % out of range is an InputError naming the message, the field and the likely mistake)."""
    keep = keep & report.drop("detections with range <= 0", keep & ~(rng > 0))
    for name, field, angle, text in (("azimuth", fields[1], az, "[-pi, pi]"),
                                     ("elevation", fields[2], el, "[-pi/2, pi/2]")):
        keep = drop_few(report, keep, ~(np.abs(angle) <= ANGLE_BOUNDS[name]), f"detections with {name} outside {text}",
                        lambda k, n=name, f=field, a=angle, b=text: f"{where}, message {scan[k]}, field '{f}': "
                        f"{float(a[k])!r} is outside {b}; {angle_hint(n, a[k])}")
    return keep


def _sensor(t_scan: np.ndarray, rng, az, el) -> SensorConfig:
    """Sensor description from the data: rate from the median scan interval, FOV from the detections."""
    good = np.diff(t_scan) > 0
    rate = float(1.0 / np.median(np.diff(t_scan)[good])) if good.any() else 10.0
    return SensorConfig(rate_hz=rate, T_vehicle_sensor=np.eye(4), noise=DEFAULT_SIGMAS,
                        azimuth_fov=field_of_view(az, np.pi / 2, np.pi),
                        elevation_fov=field_of_view(el, np.pi / 4, np.pi / 2),
                        max_range=float(np.ceil(rng.max())) if len(rng) else 100.0)


def _add_notes(report: ConversionReport, kind: str, dop: str, flip: bool, messages: int) -> None:
    sign = "negated (--flip-doppler)" if flip else "as recorded"
    report.notes.append(f"{kind} bag, {messages} PointCloud2 messages; Doppler from field '{dop}', {sign}: "
                        f"the sequence expects negative = approaching")
    report.notes.append("vehicle frame = sensor frame (T_vehicle_sensor identity); no ground truth")
    report.notes.append("noise sigmas are nominal (0.1 m, 1.5 deg, 1.5 deg, 0.1 m/s): set them with --sigma")

"""ROS bag converter (sim/convert/rosbag.py, `rodo convert rosbag`): bags written here with rosbags' own
writers (ROS 2 sqlite3 and mcap, ROS 1) with known points, the real TI demo bag, and the bad-input paths."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rodo import cli
from rodo.commands import convert as convert_cmd
from rodo.estimator.ego_velocity import estimate_ego_velocity
from rodo.estimator.errors import InputError
from rodo.sim.convert import CONVERSION_JSON, read_csv, rosbag
from rodo.sim.sequence import polar_to_cartesian, read_sequence

rosbags = pytest.importorskip("rosbags", reason="the rosbag converter needs rosbags (pip install rosbags)")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

PC2 = "sensor_msgs/msg/PointCloud2"
TI_BAG = "rio_ti_mmwave_demo/ti_mmwave_rospkg_demo.bag"
TI_TOPIC = "/ti_mmwave/radar_scan_pcl"


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed))


def _run(argv) -> int:
    return cli.main([str(a) for a in argv], commands=[convert_cmd])


def _cloud(ts, fields: dict[str, np.ndarray], stamp_ns: int, dtype: str = "<f4", pad: int = 4):
    """A PointCloud2 (height 1) with the given scalar fields, `pad` unused bytes after each point."""
    names = list(fields)
    size = np.dtype(dtype).itemsize
    step = size * len(names) + pad
    rec = np.dtype({"names": names, "formats": [dtype] * len(names),
                    "offsets": [size * j for j in range(len(names))], "itemsize": step})
    n = len(fields[names[0]])
    arr = np.zeros(n, dtype=rec)
    for name in names:
        arr[name] = fields[name]
    T = ts.types
    datatype = {"<f4": 7, "<f8": 8}[dtype]
    header = {"stamp": T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
              "frame_id": "radar"}
    if "seq" in T["std_msgs/msg/Header"].__dataclass_fields__:  # ROS 1 header
        header["seq"] = 0
    pf = T["sensor_msgs/msg/PointField"]
    return T[PC2](header=T["std_msgs/msg/Header"](**header), height=1, width=n,
                  fields=[pf(name=f, offset=size * j, datatype=datatype, count=1) for j, f in enumerate(names)],
                  is_bigendian=False, point_step=step, row_step=step * n,
                  data=np.frombuffer(arr.tobytes(), dtype=np.uint8), is_dense=True)


def _write_bag(path: Path, kind: str, clouds, topic="/radar", record_ns=None, extra_topic=None):
    """Write `clouds` [(fields, stamp_ns)] to a ROS 1 bag ('ros1') or a ROS 2 bag ('sqlite3', 'mcap')."""
    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    record_ns = record_ns if record_ns is not None else [10**18 + 100_000_000 * k for k in range(len(clouds))]
    if kind == "ros1":
        writer, ser = Writer1(path), ts.serialize_ros1
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer, ser = Writer2(path, version=9, storage_plugin=plugin), ts.serialize_cdr
    with writer as w:
        conn = w.add_connection(topic, PC2, typestore=ts)
        if extra_topic:
            other = w.add_connection(extra_topic, "std_msgs/msg/String", typestore=ts)
            w.write(other, record_ns[0] if record_ns else 1, ser(ts.types["std_msgs/msg/String"](data="x"),
                                                                 "std_msgs/msg/String"))
        for (fields, stamp), t in zip(clouds, record_ns):
            w.write(conn, t, ser(_cloud(ts, fields, stamp), PC2))
    return path


def _static_scene(rng, n: int, v_sensor: np.ndarray) -> dict[str, np.ndarray]:
    """n static points ahead of the sensor, v_r = -u . v (the sequence's convention), and an intensity."""
    p = np.c_[rng.uniform(2, 40, n), rng.uniform(-15, 15, n), rng.uniform(-2, 3, n)].astype(np.float32)
    u = p / np.linalg.norm(p.astype(float), axis=1, keepdims=True)
    vr = (-u @ v_sensor).astype(np.float32)
    return {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "velocity": vr,
            "intensity": rng.uniform(5, 30, n).astype(np.float32)}


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_ros2_bag_round_trip(tmp_path, kind):
    """x, y, z -> range/azimuth/elevation that reproduce the points; Doppler unchanged, its sign the sequence's
    (the ego-velocity fit recovers +v); header stamps give the times; the intensity is kept as a column."""
    rng, v = _rng(1), np.array([3.0, -0.4, 0.1])
    scenes = [_static_scene(rng, n, v) for n in (40, 25, 33)]
    stamps = [1_700_000_000_000_000_000 + 50_000_000 * k for k in range(3)]  # 20 Hz
    bag = _write_bag(tmp_path / "bag", kind, list(zip(scenes, stamps)))
    assert _run(["convert", "rosbag", bag, "--topic", "/radar", "--out", tmp_path / "seq"]) == 0
    seq = read_sequence(tmp_path / "seq", use_cache=False)
    assert [s.scan for s in seq.scans] == [0, 1, 2] and seq.groundtruth is None
    np.testing.assert_allclose([s.t for s in seq.scans], [0.0, 0.05, 0.1], atol=1e-12)
    assert seq.sensor.rate_hz == pytest.approx(20.0) and np.array_equal(seq.sensor.T_vehicle_sensor, np.eye(4))
    for scan, scene in zip(seq.scans, scenes):
        xyz = np.c_[scene["x"], scene["y"], scene["z"]].astype(float)
        np.testing.assert_allclose(polar_to_cartesian(scan.range, scan.azimuth, scan.elevation), xyz,
                                   rtol=0, atol=1e-12)
        np.testing.assert_array_equal(scan.radial_velocity, scene["velocity"].astype(float))
        np.testing.assert_array_equal(scan.extra["intensity"], scene["intensity"].astype(float))
    est = estimate_ego_velocity(seq.scans[0].azimuth, seq.scans[0].elevation, seq.scans[0].radial_velocity,
                                _rng(2), sigma_vr=0.01, planar=False)
    assert est.ok and np.allclose(est.v_sensor, v, atol=1e-4)
    report = json.loads((tmp_path / "seq" / CONVERSION_JSON).read_text())
    assert report["info"]["t0_ns"] == stamps[0] and report["info"]["time"].startswith("header stamp")
    assert report["kept_detections"] == 98 and report["info"]["bag"] == "ROS 2"
    if kind == "mcap":  # a bare .mcap file reads too
        (mcap,) = (tmp_path / "bag").glob("*.mcap")
        assert rosbag.convert(mcap, "/radar").report.kept_detections == 98


def test_ros1_bag_polar_fields_record_time_and_flip(tmp_path):
    """Polar fields taken as they are (float64); zero header stamps -> record time, with a warning note;
    --flip-doppler negates; --doppler names a non-default field; NaN rows dropped and counted."""
    rng = _rng(3)
    scans = []
    for n in (12, 9):
        f = {"range": rng.uniform(1, 50, n), "azimuth": rng.uniform(-1, 1, n), "elevation": rng.uniform(-0.3, 0.3, n),
             "approach_speed": rng.uniform(-5, 5, n), "rcs": rng.normal(0, 3, n)}
        scans.append((f, 0))
    scans[1][0]["range"][4] = np.nan
    record = [1_600_000_000_123_000_000, 1_600_000_000_223_000_000]
    bag = tmp_path / "r.bag"
    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(bag) as w:
        conn = w.add_connection("/radar/points", PC2, typestore=ts)
        for (f, stamp), t in zip(scans, record):
            w.write(conn, t, ts.serialize_ros1(_cloud(ts, f, stamp, dtype="<f8"), PC2))
    argv = ["convert", "rosbag", bag, "--topic", "/radar/points", "--out", tmp_path / "seq",
            "--polar", "range,azimuth,elevation", "--doppler", "approach_speed", "--flip-doppler"]
    assert _run(argv) == 0
    seq = read_sequence(tmp_path / "seq", use_cache=False)
    np.testing.assert_allclose([s.t for s in seq.scans], [0.0, 0.1], atol=1e-12)
    keep = ~np.isnan(scans[1][0]["range"])
    np.testing.assert_array_equal(seq.scans[1].range, scans[1][0]["range"][keep])
    np.testing.assert_array_equal(seq.scans[1].azimuth, scans[1][0]["azimuth"][keep])
    np.testing.assert_array_equal(seq.scans[0].radial_velocity, -scans[0][0]["approach_speed"])
    np.testing.assert_array_equal(seq.scans[0].extra["rcs"], scans[0][0]["rcs"])
    report = json.loads((tmp_path / "seq" / CONVERSION_JSON).read_text())
    assert report["info"]["t0_ns"] == record[0] and report["info"]["bag"] == "ROS 1"
    assert report["dropped"] == {"detections with NaN or infinity": 1}
    assert any(n.startswith("WARNING: scan times are the bag's record") for n in report["notes"])
    with pytest.raises(InputError, match="--time header: the header stamps are zero"):
        rosbag.convert(bag, "/radar/points", polar=("range", "azimuth", "elevation"), doppler="rcs", time="header")


def test_decode_cloud_padded_rows_and_big_endian():
    """Rows padded beyond width * point_step and big-endian data decode to the written values."""
    vals = np.array([[1.5, -2.0], [3.25, 4.0], [-0.5, 8.0]])  # 3 points, fields a, b
    rec = np.dtype({"names": ["a", "b"], "formats": [">f8", ">f4"], "offsets": [0, 8], "itemsize": 16})
    rows = []
    for r in range(2):  # height 2, width 3, row_step 3 * 16 + 8
        arr = np.zeros(3, dtype=rec)
        arr["a"], arr["b"] = vals[:, 0] + r, vals[:, 1] - r
        rows.append(arr.tobytes() + b"\xff" * 8)
    fields = [SimpleNamespace(name="a", offset=0, datatype=8, count=1),
              SimpleNamespace(name="b", offset=8, datatype=7, count=1),
              SimpleNamespace(name="rgb", offset=12, datatype=7, count=3)]
    msg = SimpleNamespace(fields=fields, is_bigendian=True, height=2, width=3, point_step=16, row_step=56,
                          data=np.frombuffer(b"".join(rows), dtype=np.uint8))
    out = rosbag.decode_cloud(msg, "m")
    assert set(out) == {"a", "b"}  # count > 1 skipped
    np.testing.assert_array_equal(out["a"], np.r_[vals[:, 0], vals[:, 0] + 1])
    np.testing.assert_array_equal(out["b"], np.r_[vals[:, 1], vals[:, 1] - 1])
    msg.data = msg.data[:60]
    with pytest.raises(InputError, match="m: PointCloud2 data too short"):
        rosbag.decode_cloud(msg, "m")


@pytest.mark.realdata
def test_ti_demo_bag_matches_the_csv_export(realdata_dir, tmp_path):
    """The TI demo bag: 412 scans, 17,872 detections, the same points as the folder's CSV export, times =
    the record times (t_bag_ns; the header stamps are all zero) from the first scan."""
    folder = realdata_dir / "rio_ti_mmwave_demo"
    assert _run(["convert", "rosbag", realdata_dir / TI_BAG, "--topic", TI_TOPIC, "--out", tmp_path / "seq"]) == 0
    seq = read_sequence(tmp_path / "seq", use_cache=False)
    assert len(seq.scans) == 412 and sum(len(s) for s in seq.scans) == 17872
    sc = read_csv(folder / "radar_scans.csv", ("scan_idx", "t_bag_ns"), int_columns=("scan_idx", "t_bag_ns"))
    t_bag = sc["t_bag_ns"][np.argsort(sc["scan_idx"])]
    np.testing.assert_allclose([s.t for s in seq.scans], (t_bag - t_bag[0]) * 1e-9, atol=1e-9)
    det = read_csv(folder / "radar_detections.csv", ("scan_idx", "x_m", "y_m", "z_m", "v_radial_mps", "intensity"),
                   int_columns=("scan_idx",))
    xyz = np.concatenate([polar_to_cartesian(s.range, s.azimuth, s.elevation) for s in seq.scans])
    # the CSV export keeps 6 significant digits
    np.testing.assert_allclose(xyz, np.c_[det["x_m"], det["y_m"], det["z_m"]], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.concatenate([s.radial_velocity for s in seq.scans]), det["v_radial_mps"],
                               rtol=1e-5, atol=1e-6)
    report = json.loads((tmp_path / "seq" / CONVERSION_JSON).read_text())
    assert report["info"]["time"].startswith("bag record time")
    assert report["info"]["t0_ns"] == int(t_bag[0])


def test_rosbag_bad_inputs(tmp_path, capsys):
    """Missing bag, not a bag, missing topic (topics listed), wrong type, missing fields, no Doppler field,
    empty topic, option errors: exit 2 with one line naming the bag, topic, field or option."""
    scene = _static_scene(_rng(5), 6, np.ones(3))
    bag = _write_bag(tmp_path / "ok", "sqlite3", [(scene, 10**18)], extra_topic="/chatter")
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    out = tmp_path / "o"
    cases = [
        ([tmp_path / "none.bag", "--topic", "/radar"], ["none.bag: not found"]),
        ([junk, "--topic", "/radar"], ["junk.bag: cannot read as a ROS 1 bag"]),
        ([bag, "--topic", "/nope"], ["no topic '/nope'", "/radar (sensor_msgs/msg/PointCloud2)"]),
        ([bag, "--topic", "/chatter"], ["topic /chatter: message type std_msgs/msg/String"]),
        ([bag, "--topic", "/radar", "--xyz", "x,y,height"], ["topic /radar, message 0: missing field(s) height"]),
        ([bag, "--topic", "/radar", "--doppler", "dop"], ["message 0: missing field(s) dop"]),
        ([bag, "--topic", "/radar", "--xyz", "x,y"], ["--xyz: expected 3 comma-separated field names"]),
        ([bag, "--topic", "/radar", "--xyz", "x,y,z", "--polar", "r,a,e"], ["--xyz and --polar"]),
        ([bag], ["--topic: required for the rosbag format"]),
    ]
    for args, needles in cases:
        assert _run(["convert", "rosbag", *args, "--out", out]) == 2, args
        err = capsys.readouterr().err
        assert err.startswith("rodo convert: error: ") and err.count("\n") == 1, err
        for needle in needles:
            assert needle in err, (needle, err)
    assert not out.exists()
    no_doppler = {k: v for k, v in scene.items() if k != "velocity"}
    _write_bag(tmp_path / "nodop", "mcap", [(no_doppler, 10**18)])
    with pytest.raises(InputError, match=r"no Doppler field \(looked for velocity, .*name it with --doppler"):
        rosbag.convert(tmp_path / "nodop", "/radar")
    empty = tmp_path / "empty.bag"
    with Writer1(empty) as w:
        w.add_connection("/radar", PC2, typestore=get_typestore(Stores.ROS1_NOETIC))
    with pytest.raises(InputError, match=r"empty\.bag, topic /radar: no messages"):
        rosbag.convert(empty, "/radar")
    assert _run(["convert", "vod", tmp_path, "--out", out, "--topic", "/radar"]) == 2
    assert "--topic: only for the rosbag format" in capsys.readouterr().err


def test_missing_rosbags_names_the_install_command(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # import fails as when it is not installed
    with pytest.raises(InputError, match=r"needs the rosbags package: pip install 'rodo\[ros\]'"):
        rosbag.convert(tmp_path / "any.bag", "/radar")

"""Live Rerun stream of `rodo run` (viz/live.py, `--connect`, `--serve`): into the SDK's memory sink, and to a
local gRPC server (`rerun --port P --save FILE`, the viewer's headless proxy) started by the test."""

from __future__ import annotations

import signal
import socket
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from rodo import cli, scenarios
from rodo.commands import run as run_cmd
from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.sim.sequence import read_tum
from rodo.validation.driver import run_sequence

rr = pytest.importorskip("rerun", reason="the live stream needs rerun-sdk")
from rerun.chunk import RrdReader  # noqa: E402

from rodo.viz.live import LiveRun, check_viewer, grpc_url  # noqa: E402


def _run(argv) -> int:
    return cli.main([str(a) for a in argv], commands=[run_cmd])


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("seq")
    scenarios.simulate_to("city", 1, d, duration=0.6)
    return d


def _vehicle_translations(path) -> dict[int, list[float]]:
    """frame -> translation of /world/vehicle's Transform3D in a .rrd."""
    out = {}
    with warnings.catch_warnings():  # `rerun --save` writes no footer (a warning, not an error, for readers)
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        chunks = list(RrdReader(path).stream().to_chunks())
    for ch in chunks:
        if str(ch.entity_path) != "/world/vehicle" or ch.is_static:
            continue
        rb = ch.to_record_batch()
        if "Transform3D:translation" not in rb.schema.names:
            continue
        for f, tr in zip(rb.column("frame").to_pylist(), rb.column("Transform3D:translation").to_pylist()):
            out[int(f)] = tr[0] if tr and isinstance(tr[0], list) else tr
    return out


def test_live_run_streams_every_scan_into_a_memory_sink(seq_dir, tmp_path):
    """run_sequence's on_scan feeds LiveRun: the stream holds the estimated position at every frame, the scans
    with class ids, and the velocity series."""
    from rodo.sim.sequence import read_sequence

    seq = read_sequence(seq_dir)
    rec = rr.RecordingStream("rodo", recording_id="live-memory")
    memory = rec.memory_recording()
    live = LiveRun(seq, recording=rec)
    result = run_sequence(seq, OdometryConfig.for_model("ca-polar"), record_detail=True, on_scan=live.on_scan)
    live.close()
    rrd = tmp_path / "live.rrd"
    rrd.write_bytes(memory.drain_as_bytes())
    got = _vehicle_translations(rrd)
    assert sorted(got) == list(range(len(result.estimates)))
    want = np.stack([e.T_world_vehicle[:3, 3] for e in result.estimates])
    np.testing.assert_allclose(np.array([got[k] for k in sorted(got)]), want, atol=1e-5)
    paths = {str(c.entity_path) for c in RrdReader(rrd).stream().to_chunks()}
    assert {"/world/vehicle/sensor/scan", "/world/map", "/world/estimate/trajectory", "/velocity/nu_x"} <= paths


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, proc, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            pytest.fail(f"the rerun server exited early: {proc.stderr.read().decode(errors='replace')[-500:]}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    pytest.fail(f"the rerun server did not listen on port {port} within {timeout} s")


def _rerun_server() -> str | None:
    """The rerun server binary itself (rerun-sdk's `rerun_cli/rerun`), not the `rerun` console script, which runs
    it as a child through `subprocess.call`: a signal to the script leaves that child to the script's exception
    handling, and a kill of the script orphaned it (a server left running after every `make test` until session
    50). None where it is not installed."""
    try:
        import rerun_cli
    except ImportError:
        return None
    exe = Path(rerun_cli.__file__).with_name("rerun")
    return str(exe) if exe.is_file() else None


def test_run_connect_streams_to_a_local_grpc_server(seq_dir, tmp_path, capsys):
    """`rodo run --connect 127.0.0.1:PORT` against `rerun --port PORT --save FILE` (a headless proxy started
    here): the server receives the estimated pose of every scan, equal to estimate.txt."""
    exe = _rerun_server()
    if exe is None:
        pytest.skip("the rerun server binary (rerun-sdk's rerun_cli) is not installed")
    port, saved = _free_port(), tmp_path / "server.rrd"
    proc = subprocess.Popen([exe, "--port", str(port), "--save", str(saved)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    try:
        _wait_for_port(port, proc)
        assert _run(["run", seq_dir, "--out", tmp_path / "out", "--connect", f"127.0.0.1:{port}"]) == 0
        assert f"streaming live to rerun+http://127.0.0.1:{port}/proxy" in capsys.readouterr().out
        time.sleep(0.5)
    finally:
        proc.send_signal(signal.SIGINT)  # the server saves its file and exits
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stderr.close()
    est = read_tum(tmp_path / "out" / "estimate.txt")
    got = _vehicle_translations(saved)
    assert sorted(got) == list(range(len(est)))
    np.testing.assert_allclose(np.array([got[k] for k in sorted(got)]), est.T_world_vehicle[:, :3, 3], atol=1e-5)


def test_run_serve_hosts_a_grpc_server_and_the_web_viewer(seq_dir, tmp_path, monkeypatch, capsys):
    """`--serve`: the web viewer is pointed at this process's gRPC server, and the command waits for Ctrl-C
    after the run (the browser and the wait are replaced here)."""
    calls = {}
    monkeypatch.setattr(rr, "serve_web_viewer", lambda **kw: calls.update(kw))
    monkeypatch.setattr(run_cmd, "wait_for_interrupt", lambda: calls.setdefault("waited", True))
    monkeypatch.setattr(rr.RecordingStream, "serve_grpc", lambda self, **kw: "rerun+http://127.0.0.1:1/proxy")
    assert _run(["run", seq_dir, "--out", tmp_path / "out", "--serve"]) == 0
    out = capsys.readouterr().out
    assert calls["connect_to"] == "rerun+http://127.0.0.1:1/proxy" and calls["waited"] is True
    assert "serving the web viewer" in out and "Ctrl-C to stop" in out


@pytest.mark.parametrize("value, url", [(None, "rerun+http://127.0.0.1:9876/proxy"),
                                        ("9877", "rerun+http://127.0.0.1:9877/proxy"),
                                        ("viewer.local:9000", "rerun+http://viewer.local:9000/proxy"),
                                        ("rerun+http://10.0.0.2:9876/proxy", "rerun+http://10.0.0.2:9876/proxy")])
def test_grpc_url(value, url):
    assert grpc_url(value) == url


def test_live_flags_bad_input(seq_dir, tmp_path, capsys):
    for argv, needle in ((["--connect", "host:port"], "--connect: expected a port, HOST:PORT"),
                         (["--connect", "1234", "--serve"], "--connect and --serve: give one of them")):
        assert _run(["run", seq_dir, "--out", tmp_path / "o", *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("rodo run: error: ") and needle in err, err
    assert not (tmp_path / "o").exists()
    with pytest.raises(InputError, match="--connect"):
        grpc_url("99999")


def test_run_connect_without_a_viewer_fails_before_the_work(seq_dir, tmp_path, capsys):
    """Nothing listening at the --connect address: refused at once, naming it, with nothing written (the SDK
    would buffer the whole run and wait for a viewer for ever, Ctrl-C included)."""
    port = _free_port()
    assert _run(["run", seq_dir, "--out", tmp_path / "o", "--connect", str(port)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rodo run: error: --connect: no Rerun viewer is listening at 127.0.0.1:"
                          f"{port}"), err
    assert "--serve or --rerun" in err and not (tmp_path / "o").exists()


def test_run_writes_its_files_when_the_viewer_goes_away(seq_dir, tmp_path, monkeypatch, capsys):
    """A viewer that goes away during the run: the files are written first, and the lost stream is a warning."""
    import rodo.viz.live as live

    monkeypatch.setattr(live, "check_viewer", lambda url: None)
    monkeypatch.setattr(rr.RecordingStream, "connect_grpc", lambda self, url=None, **kw: None)

    def flush(self, timeout_sec=1e38):
        raise RuntimeError("gRPC has been unable to connect for 10s")

    monkeypatch.setattr(rr.RecordingStream, "flush", flush)
    monkeypatch.setattr(rr.RecordingStream, "disconnect", lambda self: None)
    assert _run(["run", seq_dir, "--out", tmp_path / "o", "--connect", "9"]) == 0
    err = capsys.readouterr().err
    assert "rodo run: warning: the live viewer at rerun+http://127.0.0.1:9/proxy did not receive the whole run" in err
    assert read_tum(tmp_path / "o" / "estimate.txt").t.size > 0


def test_check_viewer_accepts_a_listening_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        check_viewer(grpc_url(str(s.getsockname()[1])))  # no error

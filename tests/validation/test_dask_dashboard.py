"""`--dashboard [ADDR]` for campaigns on `--dask local`: parsing and its errors (exit 2 naming the flag), the
address handed to the LocalCluster and its link printed (a fake cluster class), and one real LocalCluster with
its dashboard on a free port (threads, about 3 s; skipped without bokeh).
"""

import importlib.machinery
import re
import sys
import types
import urllib.request

import pytest

from rodo.cli import main
from rodo.commands import montecarlo as montecarlo_cmd
from rodo.commands import table1 as table1_cmd
from rodo.estimator.errors import InputError
from rodo.validation import campaign


def _parse(*argv):
    import argparse

    parser = argparse.ArgumentParser(prog="rodo")
    sub = parser.add_subparsers()
    montecarlo_cmd.register(sub)
    return parser.parse_args(["montecarlo", "city", "--runs", "1", "--out", "x", *argv])


def test_dashboard_flag_parsing():
    assert _parse().dashboard is None
    assert _parse("--dashboard").dashboard == montecarlo_cmd.DASHBOARD_DEFAULT == "localhost:8787"
    assert _parse("--dashboard", ":9999").dashboard == ":9999"
    assert _parse("--dashboard", "0.0.0.0:0").dashboard == "0.0.0.0:0"


@pytest.mark.parametrize("addr", ["8787", "host:port", ":70000", "http://x:1", ""])
def test_bad_dashboard_address_exits_2_naming_the_flag(addr, capsys):
    with pytest.raises(SystemExit) as exc:
        _parse("--dashboard", addr)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--dashboard" in err and "[HOST]:PORT" in err


@pytest.mark.parametrize("command, extra", [(montecarlo_cmd, ["city"]), (table1_cmd, [])])
@pytest.mark.parametrize("dask", [[], ["--dask", "tcp://127.0.0.1:1"]])
def test_dashboard_needs_dask_local(command, extra, dask, tmp_path, capsys):
    argv = [command.__name__.rsplit(".", 1)[1], *extra, "--runs", "1", "--out", str(tmp_path / "o"),
            *dask, "--dashboard"]
    assert main(argv, commands=[command]) == 2
    err = capsys.readouterr().err
    assert "--dashboard" in err and "--dask local" in err
    assert not (tmp_path / "o").exists()  # refused before any work


class _FakeCluster:
    made = []

    def __init__(self, **kwargs):
        self.kwargs = kwargs
        self.dashboard_link = f"http://127.0.0.1:{kwargs['dashboard_address']}/status"
        _FakeCluster.made.append(self)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class _FakeClient:
    def __init__(self, cluster):
        self.cluster = cluster

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def get_executor(self):
        return "executor"


@pytest.fixture
def fake_dask(monkeypatch):
    distributed = pytest.importorskip("distributed", reason="needs the dask extra: pip install 'rodo[dask]'")

    _FakeCluster.made.clear()
    monkeypatch.setattr(distributed, "LocalCluster", _FakeCluster)
    monkeypatch.setattr(distributed, "Client", _FakeClient)
    bokeh = types.ModuleType("bokeh")
    bokeh.__spec__ = importlib.machinery.ModuleSpec("bokeh", None)
    monkeypatch.setitem(sys.modules, "bokeh", bokeh)  # installed or not, find_spec sees it
    return _FakeCluster.made


def test_local_cluster_gets_the_dashboard_address_and_the_link_is_reported(fake_dask):
    links = []
    with campaign.make_executor(3, "local", dashboard=":8787", on_dashboard=links.append) as ex:
        assert ex == "executor"
    (cluster,) = fake_dask
    assert cluster.kwargs["dashboard_address"] == ":8787" and cluster.kwargs["n_workers"] == 3
    assert links == ["http://127.0.0.1::8787/status"]
    with campaign.make_executor(1, "local", on_dashboard=links.append):
        pass
    assert fake_dask[1].kwargs["dashboard_address"] is None and len(links) == 1  # off by default


def test_dashboard_without_bokeh_is_a_clear_error(fake_dask, monkeypatch):
    monkeypatch.setitem(sys.modules, "bokeh", None)  # import blocked: find_spec returns None
    with pytest.raises(InputError, match=r"bokeh.*dask\[diagnostics\]"):
        with campaign.make_executor(1, "local", dashboard=":8787"):
            pass
    assert fake_dask == []


def test_cli_passes_the_address_and_prints_the_link(tmp_path, capsys, monkeypatch):
    seen = {}

    def fake_make_executor(jobs, dask, dashboard=None, on_dashboard=None):
        seen.update(jobs=jobs, dask=dask, dashboard=dashboard)
        on_dashboard("http://localhost:8799/status")
        raise InputError("stop here")  # the wiring is what this test checks, not a campaign

    monkeypatch.setattr(montecarlo_cmd, "make_executor", fake_make_executor)
    argv = ["montecarlo", "city", "--runs", "1", "--jobs", "2", "--dask", "local", "--dashboard", ":8799",
            "--out", str(tmp_path / "mc")]
    assert main(argv, commands=[montecarlo_cmd]) == 2
    assert seen == {"jobs": 2, "dask": "local", "dashboard": ":8799"}
    assert "Dask dashboard: http://localhost:8799/status" in capsys.readouterr().out


def test_a_real_dashboard_serves_its_status_page():
    pytest.importorskip("bokeh")
    links = []
    with campaign.make_executor(1, "local", processes=False, dashboard="127.0.0.1:0",
                                on_dashboard=links.append) as ex:
        assert ex.submit(sum, [1, 2]).result() == 3
        (link,) = links
        # the link's host is the scheduler's (in-process here: the machine's address); the page is on 127.0.0.1
        port = re.fullmatch(r"http://[^/:]+:(\d+)/status", link).group(1)
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/status", timeout=20) as page:
            assert page.status == 200

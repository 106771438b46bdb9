"""`rodo view` on something that is not a recording: the hint never suggests writing over the path given (an
input such as radar.csv), and a directory is called one, with its .rrd files named."""

from tests.cli.helpers import fails

HINT = "`rodo run SEQ --out DIR --rerun OUT.rrd`"


def test_a_file_that_is_not_a_recording_gets_a_placeholder_hint(seq, capsys):
    csv = seq / "radar.csv"
    before = csv.read_bytes()
    err = fails(capsys, ["view", csv], f"{csv}: not a Rerun recording", HINT)
    assert f"--rerun {csv}" not in err
    assert csv.read_bytes() == before


def test_a_missing_recording_gets_the_placeholder_hint(tmp_path, capsys):
    fails(capsys, ["view", tmp_path / "none.rrd"], "none.rrd: recording not found", HINT)


def test_a_directory_is_said_to_be_one(seq, tmp_path, capsys):
    err = fails(capsys, ["view", seq], f"{seq}: is a directory", "holds no .rrd recording", HINT)
    assert "not found" not in err
    for name in ("b.rrd", "a.rrd"):
        (tmp_path / name).write_bytes(b"RRF2")
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "sub.rrd").mkdir()  # a directory named like one is not a recording
    err = fails(capsys, ["view", tmp_path], f"{tmp_path}: is a directory, not a recording",
                "it holds a.rrd, b.rrd: give one", f"rodo view {tmp_path / 'a.rrd'}")
    assert "notes.txt" not in err and "sub.rrd" not in err

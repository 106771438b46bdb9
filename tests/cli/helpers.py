"""What the CLI tests share: `fails`, a command that must exit 2 with one line naming the problem."""

from rodo.cli import main


def fails(capsys, argv, *needles):
    """Run `rodo argv`; expect exit 2 and a one-line 'rodo CMD: error:' message containing every needle."""
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert rc == 2, f"exit {rc}; stderr: {cap.err!r}"
    assert cap.err.startswith(f"rodo {argv[0]}: error: "), cap.err
    assert "Traceback" not in cap.err and cap.err.count("\n") == 1, cap.err
    for needle in needles:
        assert str(needle) in cap.err, f"{needle!r} not in {cap.err!r}"
    return cap.err

"""rodo: a testbed for radar odometry on SE(3). The command line lives in rodo.cli."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("rodo")  # one source: pyproject.toml's [project] version
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "unknown"

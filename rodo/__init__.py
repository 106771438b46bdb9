"""rodo: a testbed for radar odometry on SE(3). The command line lives in rodo.cli."""

__version__ = "0.1.0"

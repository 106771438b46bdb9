"""Lie groups SO(3) and SE(3) in the paper's conventions: see docs/conventions.md."""

from . import se3, so3

__all__ = ["se3", "so3"]

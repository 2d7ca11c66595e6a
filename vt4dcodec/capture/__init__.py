"""Captures: synchronized multi-camera videos with calibration, on disk and in memory."""

from .capture import Capture  # noqa: F401

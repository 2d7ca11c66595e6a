"""Captures: synchronized multi-camera videos with calibration, on disk and in memory.

``Capture`` is the in-memory form; :mod:`.io` reads and writes capture directories (spec:
FORMAT.md, Part III); :mod:`.resample` fits captures to a model resolution; :mod:`.caliscope`
imports real recordings; :mod:`.trajectories` makes target camera paths; :mod:`.contact_sheet` draws
a capture.  OpenCV is imported only when media are decoded or encoded.
"""

from .capture import Capture  # noqa: F401
from .io import read_capture, write_capture  # noqa: F401

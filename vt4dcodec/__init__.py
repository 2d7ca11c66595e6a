"""vt4dcodec: a file format, storage library and neural codec for compact 4D scene tokens.

Reading and writing ``.vt4d`` files needs only numpy, msgpack and zstandard; the codec functions
import torch lazily, on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from .version import __version__  # noqa: F401

from .errors import *  # noqa: F401,F403  (the exception family is part of the public API)
from .cameras import Trajectory  # noqa: F401
from .format import (  # noqa: F401,E402  (the single-scene container: numpy + msgpack + zstandard only)
    ModelFingerprint, Provenance, Scene, dumps, load, loads, open_scene, save, verify,
)
from . import format  # noqa: E402
from .archive import ArchiveWriter, open_archive, verify_archive  # noqa: F401,E402  (torch-free too)
from .generate import generate  # noqa: F401,E402  (eager: the submodule shares the name; torch loads on call)

def _entropy_tables(fingerprint: ModelFingerprint) -> Any:
    """The entropy tables of an installed model (shipped or under $VT4D_MODEL_PATH) with this fingerprint,
    for ``learned-rans`` files (torch-free: the model directory's safetensors are parsed directly)."""
    try:
        tables = importlib.import_module(".model.tables", __name__)
    except ImportError:  # a tree without the model package (e.g. the source tree, not installed): none here
        return None
    return tables.entropy_tables(fingerprint)


format.set_tables_resolver(_entropy_tables)

# The codec needs torch; it is imported on first use so that `import vt4dcodec` stays light.
_LAZY = {"encode": "codec", "encode_clips": "codec", "decode": "codec", "SceneDecoder": "codec"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'vt4dcodec' has no attribute {name!r}")

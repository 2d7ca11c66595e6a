"""`vt4d pack` subprocess for the interrupt tests (not a test module).

Usage: python pack_slowly.py PAUSE_S VT4D-ARGS...
Runs ``vt4d VT4D-ARGS`` in this process with ``ArchiveWriter.append`` slowed down: after each append returns it
prints "A key" and sleeps PAUSE_S, so a test can signal a long write mid-run and know which scenes had finished.
"""

import sys
import time

from vt4dcodec.archive import ArchiveWriter
from vt4dcodec.cli import main

_append = ArchiveWriter.append


def _slow_append(self, key, record, **kwargs):
    entry = _append(self, key, record, **kwargs)
    print("A", key, flush=True)
    time.sleep(float(sys.argv[1]))
    return entry


if __name__ == "__main__":
    ArchiveWriter.append = _slow_append
    sys.exit(main(sys.argv[2:]))

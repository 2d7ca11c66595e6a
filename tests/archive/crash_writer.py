"""Writer subprocess for the crash and concurrency tests (not a test module).

Usage: python crash_writer.py ARCHIVE SEED [MAX_COMMITS [PAUSE_S]]
Opens ARCHIVE (recovering or discarding what a killed predecessor left, chosen by SEED), prints
"ready", then appends 1-4 scenes and commits in a loop, printing "C key..." after each commit()
returns, then sleeps PAUSE_S (default 0).  Scene bytes are payload_for(key), so any reader can check them.
"""

import os
import random
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from helpers import payload_for  # noqa: E402

from vt4dcodec.archive import ArchiveWriter  # noqa: E402


def main() -> None:
    path, seed = sys.argv[1], int(sys.argv[2])
    max_commits = int(sys.argv[3]) if len(sys.argv) > 3 else 10**9
    pause_s = float(sys.argv[4]) if len(sys.argv) > 4 else 0.0
    rng = random.Random(seed)
    writer = ArchiveWriter(path, on_uncommitted=rng.choice(["recover", "discard"]))
    print("ready", flush=True)
    for c in range(max_commits):
        keys = [f"s{seed}-{c}-{j}" for j in range(rng.randint(1, 4))]
        for key in keys:
            writer.append(key, payload_for(key), validate=False, replace=rng.random() < 0.1)
        writer.commit()
        print("C", *keys, flush=True)
        time.sleep(pause_s)
    writer.close()


if __name__ == "__main__":
    main()

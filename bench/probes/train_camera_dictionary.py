"""How FORMAT.md's camera dictionary (I.4.2) was made, and what it saves (run once; the dictionary is frozen).

    vt4d synth -n 64 --split train --seed 7100 -o runs/partner_scenes
    vt4d synth -n 64 --split train --seed 7300 --style room -o runs/partner_scenes
    vt4d synth -n 20 --split train --seed 7200 -o runs/dictionary_test
    python bench/probes/train_camera_dictionary.py --train runs/partner_scenes --test runs/dictionary_test \
        --out runs/camera_dictionary.zdict

The raw CAMS and XCAM payloads (fixed-point cameras, FORMAT.md I.5.4) of the training captures encoded with 1, 5
and all 10 cameras are the samples of zstd's dictionary trainer (ZDICT, 1,024 bytes, level 19); the test
captures (other seeds) measure the stored bytes with zstd alone and with the dictionary, at the writer's level.
The cameras are what the writer makes of a capture's trajectories; no model is needed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import zstandard

from vt4dcodec.capture import read_capture
from vt4dcodec.format.compact_cameras import pack_compact_cameras
from vt4dcodec.format.extra_cameras import pack_extra_cameras
from vt4dcodec.format.writer import DEFAULT_COMPRESSION_LEVEL


def camera_payloads(directory: Path, views: tuple[int, ...] = (1, 5, 10)) -> list[bytes]:
    """The CAMS payload (with timestamps) and the XCAM payload (without) of a capture encoded with its first
    ``v`` cameras, as a learned-rans file stores them."""
    capture = read_capture(directory)
    names = capture.camera_names
    out = []
    for v in views:
        first = capture.cameras[names[0]]
        out.append(pack_compact_cameras(first, "compact", quaternions=True, fixed=True))
        extras = tuple(dataclasses.replace(capture.cameras[n], distortion=None, timestamps=None) for n in names[1:v])
        if extras:
            out.append(pack_extra_cameras(extras, "compact", quaternions=True, fixed=True))
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--train", type=Path, required=True)
    p.add_argument("--test", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--size", type=int, default=1024)
    args = p.parse_args()
    train = [b for d in sorted(args.train.iterdir()) if d.is_dir() for b in camera_payloads(d)]
    test = [b for d in sorted(args.test.iterdir()) if d.is_dir() for b in camera_payloads(d, (10,))]
    dictionary = zstandard.train_dictionary(args.size, train, level=19)
    args.out.write_bytes(dictionary.as_bytes())
    plain = zstandard.ZstdCompressor(level=DEFAULT_COMPRESSION_LEVEL, write_content_size=True)
    with_dict = zstandard.ZstdCompressor(level=DEFAULT_COMPRESSION_LEVEL, dict_data=dictionary, write_dict_id=False,
                                         write_content_size=True)
    report = {"train_payloads": len(train), "test_payloads": len(test), "dictionary_bytes": len(dictionary.as_bytes()),
              "raw": float(np.mean([len(b) for b in test])),
              "zstd": float(np.mean([min(len(b), len(plain.compress(b))) for b in test])),
              "zstd_with_dictionary": float(np.mean([len(with_dict.compress(b)) for b in test]))}
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

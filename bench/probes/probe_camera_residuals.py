#!/usr/bin/env python
"""How far are fixed-point camera records (FORMAT.md I.5.4) from the entropy of their residuals?

    python bench/probes/probe_camera_residuals.py [--first-seed 2000] [--scenes 12]

For every camera of held-out 10-camera synthetic captures (split test), the reference writer's fixed-point
payload (camera centres, cubic prediction when shorter) is built and its prediction residuals collected per
column and record position; prints the payload's mean bytes, the varint bytes of the residual blocks and the
plug-in (empirical, per class) entropy of the same residuals, per camera. The plug-in entropy is optimistic
(fitted to the residuals it scores); it bounds what an entropy coder of residuals could save over varints.
"""

from __future__ import annotations

import argparse
import collections
import math

import numpy as np

from vt4dcodec.format import compact_cameras as cc
from vt4dcodec.synth import generate_scene


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--first-seed", type=int, default=2000)
    p.add_argument("--scenes", type=int, default=12)
    args = p.parse_args()
    residuals: dict[str, list[int]] = collections.defaultdict(list)
    cameras, payload = 0, 0
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        for traj in generate_scene(seed, split="test").capture.cameras.values():
            raw = cc._encode_fixed(traj, centre=True)
            assert raw is not None
            cameras, payload = cameras + 1, payload + len(raw)
            cubic = bool(raw[1] & cc.CUBIC_PREDICTION)
            e_k, e_r, e_t = cc.fixed_exponents(traj, centre=True)
            K = traj.K[:1] if raw[1] & cc.CONSTANT_INTRINSICS else traj.K
            w2c = traj.w2c[:1] if raw[1] & cc.STATIC_POSE else traj.w2c
            q = cc._grid_quaternions(cc.rotation_to_quaternion(w2c[:, :3, :3]), e_r)
            centre = -np.linalg.solve(w2c[:, :3, :3], w2c[:, :3, 3][:, :, None])[:, :, 0]
            blocks = {"K": [[int(round(float(v) * 2.0 ** e_k)) for v in row] for row in cc._intrinsic_records(K)],
                      "P": [qr + [int(round(float(v) * 2.0 ** e_t)) for v in c] for qr, c in zip(q, centre)]}
            for name, k in blocks.items():
                for r, row in enumerate(k):
                    for j, v in enumerate(row):
                        residuals[f"{name}{min(r, 3)}:{j}"].append(v - cc._predicted(k, r, j, cubic))

    def entropy(values: list[int]) -> float:
        counts = collections.Counter(values)
        return -sum(c / len(values) * math.log2(c / len(values)) for c in counts.values())

    varint = sum(len(cc._varint(cc._zigzag(v))) for vs in residuals.values() for v in vs) / cameras
    plug_in = sum(entropy(vs) * len(vs) for vs in residuals.values()) / 8 / cameras
    print(f"{cameras} cameras: payload {payload / cameras:.1f} B a camera; residual varints {varint:.1f} B, "
          f"plug-in entropy of the same residuals {plug_in:.1f} B")


if __name__ == "__main__":
    main()

#!/usr/bin/env python
"""Where do a moving rig's extra-camera bytes go in the joint XCAM layout (FORMAT.md I.5.5)? Bits per camera of
each residual group (intrinsics record 0 and later; pose records 0, 1, 2 and later x quaternion, x, y, z),
at each group's best Exp-Golomb order, over the extra cameras of held-out synthetic 10-camera rigs.

    python bench/probes/probe_joint_camera_groups.py [--first-seed 2000] [--scenes 12] [--out FILE.json]

The rigs' extra cameras are packed as the reference writer packs a whole-capture learned-rans file's (fixed point,
I.5.4, then the joint layout); no tokens are involved.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from vt4dcodec.format import extra_cameras, joint_cameras  # noqa: E402
from vt4dcodec.synth import SynthConfig, generate_scene  # noqa: E402

NAMES = ["intrinsics r0", "intrinsics r>=1"] + [f"pose r{r if r < 3 else '>=3'} {v}"
                                                 for r in range(4) for v in ("quaternion", "x", "y", "z")]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--first-seed", type=int, default=2000)
    p.add_argument("--scenes", type=int, default=12)
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()
    total: dict[int, float] = defaultdict(float)
    cameras = 0
    payload_bytes = []
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10, num_frames=args.frames,
                                                                      height=args.size, width=args.size)).capture
        names = list(cap.camera_names)
        extras = [cap.cameras[n][:args.frames] for n in names[1:]]
        raw = extra_cameras.pack_extra_cameras(extras, "compact", quaternions=True, fixed=True)
        joint = extra_cameras.joint_extra_cameras(raw, args.frames, args.size, args.size)
        assert joint is not None, "every extra camera of a synthetic rig is fixed point"
        payload_bytes.append(len(joint))
        records = joint_cameras.unpack_joint_cameras(joint, args.frames, args.size, args.size)
        parsed = [joint_cameras._record_ints(r, args.frames) for r in records]
        by_group: dict[int, list[int]] = defaultdict(list)
        for values in joint_cameras._residuals(parsed, args.size, args.size):  # type: ignore[arg-type]
            for group, z in values:
                by_group[group].append(z)
        for group, zs in by_group.items():
            total[group] += min(sum(joint_cameras.exp_golomb_bits(z, k) for z in zs) for k in range(32))
        cameras += len(records)
    per_camera = {NAMES[g]: total[g] / 8 / cameras for g in sorted(total)}
    print(f"{cameras} extra cameras, XCAM {np.mean(payload_bytes):.1f} B a rig (raw joint payload); bytes per camera:")
    for name, b in per_camera.items():
        print(f"    {name}: {b:.2f}")
    print(f"    all groups: {sum(per_camera.values()):.2f}")
    if args.out:
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "cameras": cameras,
                                        "xcam_bytes_mean": float(np.mean(payload_bytes)),
                                        "bytes_per_camera": per_camera}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

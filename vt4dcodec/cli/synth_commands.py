"""The `vt4d synth` command: generate synthetic scenes as capture directories.

Registered by :mod:`vt4dcodec.cli.capture_commands`; the scenes come from :mod:`vt4dcodec.synth`.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from ..synth.dataset_writer import write_dataset
from ..synth.generator import SynthConfig
from . import add_command, add_overwrite_option, emit, int_at_least, plural, show_progress

__all__ = ["add_synth_parser", "run_synth"]




def run_synth(args: argparse.Namespace) -> int:
    config = SynthConfig(
        num_cameras=args.cameras, num_frames=args.frames, height=args.size, width=args.size,
        num_objects=(args.min_objects, args.max_objects), static=args.static,
        camera_motion=not args.fixed_cameras, fps=args.fps, style=args.style,
    )
    start = time.perf_counter()
    paths = write_dataset(args.output, num_scenes=args.num_scenes, split=args.split, seed=args.seed,
                          config=config, workers=args.workers, overwrite=args.overwrite,
                          progress=show_progress(args))
    elapsed = time.perf_counter() - start
    emit(args, {"output": args.output, "split": args.split, "scenes": [str(p) for p in paths],
                "seconds": round(elapsed, 3)},
         [f"{plural(len(paths), args.split + ' scene')} (seeds {args.seed}..{args.seed + len(paths) - 1}) in "
          f"{args.output} [{elapsed:.1f} s]"])
    return 0


def add_synth_parser(sub: Any) -> None:
    p = add_command(
        sub, "synth", help="generate synthetic multi-camera dynamic scenes as capture directories",
        examples=["vt4d synth -n 4 --split test -o captures/",
                  "vt4d synth -n 100 --cameras 4 --frames 16 --size 128 --workers 2 -o train_caps/",
                  "vt4d synth -n 20 --style room --cameras 4 -o rooms/"],
        description=(
            "Generate N synthetic scenes (style objects: textured room, moving rigid objects, K "
            "synchronized moving cameras; style room: people walking or gesturing in a furnished room "
            "with shadows, webcam-like rigs and a sensor model) as capture directories OUT/<split>-<seed>/ with PNG frames, 16-bit PNG depth "
            "(mm), and ground truth synth_flow.npy + synth_gt.npz.  Deterministic from (seed, split, "
            "options); train and test scenes use disjoint textures and objects.  Complete scenes "
            "already in OUT are kept, so an interrupted run can be resumed."
        ),
    )
    p.add_argument("-n", "--num-scenes", type=int_at_least(1), required=True, help="number of scenes")
    p.add_argument("--split", choices=("train", "test"), default="train", help="asset pool (default train)")
    p.add_argument("-o", "--output", required=True, help="output directory")
    p.add_argument("--seed", type=int_at_least(0), default=0, help="first scene seed (default 0)")
    p.add_argument("--workers", type=int_at_least(1), default=2, help="processes (default 2)")
    p.add_argument("--cameras", type=int_at_least(1), default=10, help="cameras per scene (default 10)")
    p.add_argument("--frames", type=int_at_least(2), default=8, help="frames per camera (default 8)")
    p.add_argument("--size", type=int_at_least(2), default=64, help="square image side in pixels (default 64)")
    p.add_argument("--fps", type=float, default=8.0, help="frame rate (default 8)")
    p.add_argument("--min-objects", type=int_at_least(0), default=2, help="fewest objects (default 2)")
    p.add_argument("--max-objects", type=int_at_least(0), default=4, help="most objects (default 4)")
    p.add_argument("--static", action="store_true", help="objects (people) stand still (nothing moves)")
    p.add_argument("--style", choices=("objects", "room", "closeup"), default="objects",
                   help="objects: rigid shapes in a large room (default); room: people in a furnished room "
                        "that looks like webcam footage; closeup: the room with the webcams near one person, as "
                        "desk and calibration recordings (--min/--max-objects apply to neither)")
    p.add_argument("--fixed-cameras", action="store_true", help="cameras do not move")
    add_overwrite_option(p, "regenerate scenes that already exist")
    p.set_defaults(func=run_synth)

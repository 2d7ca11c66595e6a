#!/usr/bin/env python
"""Compact cameras and the compact container (FORMAT.md I.5.1, I.5.2, format 1.2 and 1.3): bytes of the
cameras section, and what is left of a scene besides its tokens, for the trajectories the synthetic test
captures hold (8 frames at 64x64 with timestamps, every camera), in each cameras mode; the largest
reprojection change of the lossy modes.

    python bench/bench_compact_cameras.py                   # 20 held-out captures x 10 cameras, ~1 minute
    python bench/bench_compact_cameras.py --captures 5
    python bench/bench_compact_cameras.py --fixed           # only the fixed-point records of learned-rans
                                                            # files (I.5.4), 5 captures x 10 cameras, seconds

The whole-file part encodes camera 0 of the first capture with the shipped model (``--model``, default
vt4d-tiny) at the codec's default token encoding, then writes that one scene in each header and cameras
mode: file bytes, token bytes, and every non-token byte by where it goes (preamble, header, section
table, padding, cameras, quantization sections), the header by its top-level keys, and the header
encodings measured before format 1.3 chose one (``header_variants``).
Results: bench/results/compact_cameras.json.

``--fixed`` measures the fixed-point records (format 1.6, FORMAT.md I.5.4) that ``learned-rans`` files store,
on held-out 10-camera rigs (``--first-seed``, default 3000; ``--captures``, default 5 there): bytes of one
record without timestamps in each form (float32 quaternions; fixed point with translations or camera centres,
linear or cubic prediction), the largest reprojection change of each, and a rig file's ``CAMS`` + ``XCAM``
stored bytes (camera 0 with its timestamps in ``CAMS``, the other nine in ``XCAM``, each zstd-compressed when
that is smaller), and the ``XCAM`` of the writer's records in each layout: I.5.3 with zstd, with the camera
dictionary (I.4.2) where shorter, and the joint layout (I.5.5).  Results: bench/results/compact_cameras_fixed.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import calendar  # noqa: E402
import time  # noqa: E402

import msgpack  # noqa: E402
import zstandard  # noqa: E402

from vt4dcodec.format import dumps, open_scene  # noqa: E402
from vt4dcodec.format.compact_cameras import (CAMERA_MODES, pack_compact_cameras, reprojection_change,  # noqa: E402
                                              unpack_compact_cameras)
from vt4dcodec.format.header import HEADER_DICTIONARY, compress_header  # noqa: E402
from vt4dcodec.format.layout import entry_size  # noqa: E402
from vt4dcodec.format.sections import compress_payload, pack_cameras, unpack_cameras  # noqa: E402
from vt4dcodec.format.writer import DEFAULT_COMPRESSION_LEVEL  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "compact_cameras.json"
FIXED_RESULTS = Path(__file__).resolve().parent / "results" / "compact_cameras_fixed.json"


def section_bytes(traj, mode: str) -> tuple[int, object]:
    """Stored bytes of the cameras section and the trajectory read back.  ``mode``: a cameras mode, or
    "compact-1.2" (float32 matrices only, as a 1.2 writer stores them; "compact" may use quaternions)."""
    layout, raw = pack_cameras(traj)
    if mode != "legacy":
        quaternions = mode == "compact"
        raw = pack_compact_cameras(traj, "compact" if mode == "compact-1.2" else mode, quaternions=quaternions)
        back = unpack_compact_cameras(raw, layout, quaternions=quaternions)
    else:
        back = unpack_cameras(raw, layout)
    return len(compress_payload(raw, DEFAULT_COMPRESSION_LEVEL)[1]), back


def non_token_breakdown(data: bytes) -> dict:
    """Every byte of a container that is not a token section, by where it goes."""
    f = open_scene(data)
    table = entry_size(f.preamble.required_flags) * len(f.sections)
    out = {"preamble": 64, "header": f.preamble.header_length, "section_table": table}
    cursor, padding = 64 + f.preamble.header_length + table, 0
    for e in f.sections:
        padding += e.offset - cursor
        cursor = e.offset + e.stored_length
        if e.type not in ("ZSTA", "ZDYN"):
            out[{"CAMS": "cameras"}.get(e.type, e.type)] = e.stored_length
    out["padding"] = padding
    assert sum(out.values()) == f.nbytes - f.token_bytes
    return out


def header_keys(header: dict) -> dict:
    """msgpack bytes of each top-level header entry (key and value), and of each fingerprint entry."""
    pack = lambda v: len(msgpack.packb(v, use_bin_type=True))  # noqa: E731
    return {"top_level": {k: pack(k) + pack(v) for k, v in header.items()},
            "fingerprint": {k: pack(k) + pack(v) for k, v in header["fingerprint"].items()}}


def header_variants(header: dict) -> dict:
    """The header encodings measured before format 1.3 chose one (FORMAT.md I.3.1), in bytes."""
    pack = lambda v: msgpack.packb(v, use_bin_type=True)  # noqa: E731
    fp = header["fingerprint"]
    binary = dict(header, fingerprint=dict(fp, config_sha256=bytes.fromhex(fp["config_sha256"]),
                                           weights_sha256=bytes.fromhex(fp["weights_sha256"])))
    # short integer keys from a fixed table, binary digests, defaults left out (no distortion, float32 token
    # dtype, "encoded", no metadata), the fingerprint's shapes taken from the header's, encodings and kinds as
    # codes, created_utc as integer seconds
    cams, prov = header["cameras"], header["provenance"]
    ints = {0: header["static_shape"], 1: header["dynamic_shape"], 2: header["encoding"],
            3: {k: v for k, v in ((0, cams["num_frames"]), (1, cams["width"]), (2, cams["height"]),
                                  (3, cams["distortion_terms"]), (4, cams["has_timestamps"])) if v},
            4: {0: fp["model_id"], 1: fp["model_version"], 2: binary["fingerprint"]["config_sha256"],
                3: binary["fingerprint"]["weights_sha256"]}}
    ints[2] = ["float32", "float16", "int8", "int4", *[f"int{b}-rans" for b in range(2, 9)]].index(header["encoding"])
    if prov is not None:
        ints[5] = {0: prov["library_version"],
                   1: calendar.timegm(time.strptime(prov["created_utc"][:19], "%Y-%m-%dT%H:%M:%S"))}
        if prov["source_capture_id"] is not None:
            ints[5][2] = prov["source_capture_id"]
    if header["metadata"]:
        ints[6] = header["metadata"]
    plain = zstandard.ZstdCompressor(level=19, write_content_size=True, write_checksum=False)
    raw_dict = zstandard.ZstdCompressionDict(HEADER_DICTIONARY, dict_type=zstandard.DICT_TYPE_RAWCONTENT)
    with_dict = zstandard.ZstdCompressor(level=19, dict_data=raw_dict, write_content_size=True,
                                         write_checksum=False, write_dict_id=False)
    return {"msgpack_1_2": len(pack(header)), "binary_digests": len(pack(binary)),
            "integer_keys_binary_digests_no_defaults": len(pack(ints)),
            "zstd_no_dictionary": len(plain.compress(pack(header))),
            "zstd_spec_dictionary": len(with_dict.compress(pack(header))),
            "zstd_spec_dictionary_binary_digests (kept, 1.3)": len(compress_header(pack(binary))),
            "integer_keys_zstd_spec_dictionary": len(with_dict.compress(pack(ints)))}


def whole_files(model: str) -> dict:
    from vt4dcodec import codec
    from vt4dcodec.synth import SynthConfig, generate_scene

    net = codec.load_model(model)
    cfg = net.config
    cap = generate_scene(0, split="test", config=SynthConfig(num_frames=cfg.frames, height=cfg.image_size,
                                                              width=cfg.image_size)).capture
    scene = codec.encode(cap, net, codec.DEFAULT_ENCODING, camera=cap.camera_names[0], seed=0)
    out = {"model": f"{scene.fingerprint.model_id} {scene.fingerprint.model_version}",
           "encoding": scene.encoding, "command_equivalent": "vt4d info --json FILE: bytes minus token sections",
           "modes": {}}
    for header in ("compact", "legacy"):
        for cameras in CAMERA_MODES:
            data = dumps(scene, cameras=cameras, header=header)
            f = open_scene(data)
            out["modes"][f"header={header} cameras={cameras}"] = {
                "version": "%d.%d" % f.version, "file_bytes": f.nbytes, "token_bytes": f.token_bytes,
                "non_token_bytes": f.nbytes - f.token_bytes, "camera_encoding": f.camera_encoding(),
                "non_token_breakdown": non_token_breakdown(data)}
    header = open_scene(dumps(scene, header="legacy")).header
    out["header_1_2_by_key"] = header_keys(header)
    out["header_variants"] = header_variants(header)
    return out, scene


def default_over_trajectories(scene, trajectories: list) -> dict:
    """The default file's non-token bytes with each benchmark trajectory in place of the scene's own (same
    tokens, header and metadata), so the 512 B target is seen over 200 trajectories, not one."""
    from vt4dcodec.format import Scene

    sizes = []
    for traj in trajectories:
        f = open_scene(dumps(Scene(scene.static_tokens, scene.dynamic_tokens, traj, scene.fingerprint,
                                   scene.metadata, scene.provenance, scene.encoding)))
        sizes.append(f.nbytes - f.token_bytes)
    return {"mean": round(float(np.mean(sizes)), 1), "max": int(np.max(sizes)),
            "over_512": int(np.sum(np.array(sizes) > 512))}


def fixed_point_records(first_seed: int, captures: int) -> dict:
    """FORMAT.md I.5.4 on held-out rigs: record bytes (no timestamps) and worst reprojection change of each
    form, and the CAMS + XCAM bytes of a rig file as each writer stores them."""
    from dataclasses import replace

    from vt4dcodec.format import compact_cameras as cc
    from vt4dcodec.format.extra_cameras import joint_extra_cameras, pack_extra_cameras
    from vt4dcodec.format.sections import compress_with_camera_dictionary
    from vt4dcodec.synth.generator import SynthConfig, scene_setup

    def first_16(traj):  # the fixed-point record of the first 1.6 writer: translations, linear prediction
        return cc._encode_fixed(traj, centre=False, cubic=False, fixed_timestamps=False)

    forms = {
        "float32 quaternions (I.5.2)": lambda t: cc.pack_compact_cameras(t, quaternions=True),
        "fixed, translations, linear prediction (1.6 before F bits 3-5)": first_16,
        "fixed, translations, cubic prediction where shorter": lambda t: cc._encode_fixed(t, centre=False),
        "fixed, centres, linear prediction": lambda t: cc._encode_fixed(t, centre=True, cubic=False),
        "fixed, centres, cubic prediction where shorter (the writer)":
            lambda t: cc.pack_compact_cameras(t, quaternions=True, fixed=True),
    }
    files = {  # CAMS record (with timestamps), then the record of each extra camera (without)
        "fixed, translations, linear, float64 timestamps (1.6 before F bits 3-5)": (first_16, first_16),
        "fixed, centres, cubic where shorter, float64 timestamps":
            (lambda t: cc._encode_fixed(t, centre=True, fixed_timestamps=False),
             lambda t: cc.pack_compact_cameras(t, quaternions=True, fixed=True)),
        "fixed, centres, cubic where shorter, fixed-point timestamps (the writer)":
            (lambda t: cc.pack_compact_cameras(t, quaternions=True, fixed=True),) * 2,
    }
    record = {name: [] for name in forms}
    worst = {name: 0.0 for name in forms}
    stored = {name: {"CAMS": [], "XCAM": [], "CAMS+XCAM": []} for name in files}
    xcam_layouts: dict[str, list[int]] = {"I.5.3, zstd": [], "I.5.3, zstd or the camera dictionary (I.4.2)": [],
                                          "I.5.5 joint (raw)": []}
    flags: dict[str, int] = {}
    for seed in range(first_seed, first_seed + captures):
        rig = list(scene_setup(seed, split="test", config=SynthConfig(num_cameras=10)).cameras.values())
        for traj in rig:
            bare = replace(traj, timestamps=None)
            for name, encode in forms.items():
                raw = encode(bare)
                back = cc._decode(raw, bare.num_frames, bare.width, bare.height, 0, False, quaternions=True,
                                  fixed=True)
                record[name].append(len(raw))
                worst[name] = max(worst[name], cc.reprojection_change(bare, back))
            key = f"P={raw[0]} F=0x{raw[1]:02x}"
            flags[key] = flags.get(key, 0) + 1
        for name, (cams_form, extra_form) in files.items():
            extras = [extra_form(replace(t, timestamps=None)) for t in rig[1:]]
            xcam = bytes([len(extras)]) + b"".join(len(r).to_bytes(4, "little") for r in extras) + b"".join(extras)
            sizes = [len(compress_payload(raw, DEFAULT_COMPRESSION_LEVEL)[1]) for raw in (cams_form(rig[0]), xcam)]
            for part, n in zip(("CAMS", "XCAM", "CAMS+XCAM"), (*sizes, sum(sizes))):
                stored[name][part].append(n)
        xcam = pack_extra_cameras([replace(t, timestamps=None) for t in rig[1:]], quaternions=True, fixed=True)
        zstd = len(compress_payload(xcam, DEFAULT_COMPRESSION_LEVEL)[1])
        joint = joint_extra_cameras(xcam, rig[0].num_frames, rig[0].width, rig[0].height)
        assert joint is not None
        xcam_layouts["I.5.3, zstd"].append(zstd)
        xcam_layouts["I.5.3, zstd or the camera dictionary (I.4.2)"].append(
            min(zstd, len(compress_with_camera_dictionary(xcam))))
        xcam_layouts["I.5.5 joint (raw)"].append(len(joint))
    mean = lambda v: round(float(np.mean(v)), 1)  # noqa: E731
    return {
        "records": len(record[next(iter(forms))]),
        "captures": f"test split, seeds {first_seed}..{first_seed + captures - 1}",
        "cameras_per_capture": 10, "frames": 8, "size": "64x64", "timestamps": "i / 8 s (CAMS only)",
        "record_bytes_without_timestamps": {name: {"mean": mean(v), "max": int(np.max(v))}
                                            for name, v in record.items()},
        "max_reprojection_change_px": {name: round(v, 5) for name, v in worst.items()},
        "writer_layout_flags": flags,
        "rig_file_cameras_stored_bytes": {name: {part: mean(v) for part, v in parts.items()}
                                          for name, parts in stored.items()},
        "xcam_stored_bytes_by_layout": {name: mean(v) for name, v in xcam_layouts.items()},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--captures", type=int, default=None, help="held-out captures (default 20; 5 with --fixed)")
    ap.add_argument("--model", default="vt4d-tiny")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--fixed", action="store_true", help="only the fixed-point records of learned-rans files")
    ap.add_argument("--first-seed", type=int, default=3000, help="with --fixed: the first held-out capture")
    args = ap.parse_args()
    if args.fixed:
        result = fixed_point_records(args.first_seed, args.captures or 5)
        result["command"] = "python bench/bench_compact_cameras.py " + " ".join(sys.argv[1:])
        result["machine"] = {"python": platform.python_version(), "cpus": os.cpu_count()}
        out = args.out or FIXED_RESULTS
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps(result, indent=1))
        return 0
    args.captures = args.captures or 20
    args.out = args.out or RESULTS
    from vt4dcodec.synth import SynthConfig, generate_scene

    modes = ("compact", "compact-1.2", "exact", "legacy")
    sizes: dict[str, list[int]] = {m: [] for m in modes}
    all_trajectories = []
    worst = {"compact": 0.0, "compact-1.2": 0.0}
    f32 = quats = 0
    for seed in range(args.captures):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_frames=8, height=64, width=64)).capture
        for name in cap.camera_names:
            traj = cap.cameras[name]
            all_trajectories.append(traj)
            for mode in modes:
                n, back = section_bytes(traj, mode)
                sizes[mode].append(n)
                if mode in worst:
                    worst[mode] = max(worst[mode], reprojection_change(traj, back))
            packed = pack_compact_cameras(traj, "compact", quaternions=True)
            f32 += packed[0] == 4
            quats += bool(packed[1] & 4)
    trajectories = len(sizes["legacy"])
    files, scene = whole_files(args.model)
    result = {
        "trajectories": trajectories, "captures": args.captures, "frames": 8, "size": "64x64", "timestamps": True,
        "cameras_section_bytes": {m: {"mean": round(float(np.mean(v)), 1), "max": int(np.max(v))}
                                  for m, v in sizes.items()},
        "modes": {"compact": "1.3 compact container: float32 quaternion poses where within 0.01 px (the default)",
                  "compact-1.2": "float32 matrices where within 0.01 px (1.2, or header=legacy)",
                  "exact": "float64 matrices", "legacy": "the 1.0 float64 section"},
        "compact_float32_share": round(f32 / trajectories, 3),
        "compact_quaternion_share": round(quats / trajectories, 3),
        "max_reprojection_change_px": worst,
        "single_camera_scene": files,
        "default_file_non_token_bytes_over_trajectories": default_over_trajectories(scene, all_trajectories),
        "command": "python bench/bench_compact_cameras.py " + " ".join(sys.argv[1:]),
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

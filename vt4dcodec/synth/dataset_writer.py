"""Write generated scenes to disk as capture directories plus ground truth (numpy + OpenCV PNG).

Layout of one scene directory ``OUT/<split>-<seed:06d>/``:

* a capture directory (``capture.json``, ``camXX/rgb/*.png``, ``camXX/depth/*.png`` 16-bit
  millimetres), readable with :func:`vt4dcodec.capture.io.read_capture`; the manifest metadata holds
  the generator seed, split, config, objects and textures;
* ``synth_flow.npy``: (C, T-1, H, W, 2) float16 ground-truth flow t -> t+1 in pixels (float16 keeps
  ~0.01 px at 8 px of motion; it does not compress, so it is stored plain);
* ``synth_gt.npz`` (zip-compressed .npy arrays; ``np.load(path)`` without pickle):
  ``camera_names`` (C,) str, ``flow_valid`` (C, T-1, H, W) bool, ``object_ids`` (C, T, H, W) int16,
  ``dynamic_mask`` (C, T, H, W) bool.
Cameras are stacked in manifest order.  The ground truth is written first and the capture manifest
last, so a directory with ``capture.json`` is complete; re-running skips complete scenes.
"""

from __future__ import annotations

import os
import zipfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..capture.io import write_capture
from .assets import SynthError, check_split
from .generator import SynthConfig, SynthScene, generate_scene

__all__ = ["GT_NAME", "FLOW_NAME", "scene_dirname", "write_scene", "write_dataset", "read_ground_truth"]

GT_NAME = "synth_gt.npz"
FLOW_NAME = "synth_flow.npy"
MAX_SCENES = 10_000_000


def scene_dirname(seed: int, split: str) -> str:
    """Directory name of scene ``seed`` of ``split``, e.g. ``train-000042``."""
    return f"{split}-{seed:06d}"


def _save_npz(path: Path, arrays: dict[str, np.ndarray], level: int = 1) -> None:
    """``np.savez_compressed`` with a fast deflate level (masks and ids are long runs: level 1 is
    ~3x faster than numpy's default level 6 for ~2x the few tens of kB).  Plain .npz for ``np.load``."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=level) as zf:
        for name, array in arrays.items():
            with zf.open(name + ".npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(array), allow_pickle=False)


def write_scene(scene: SynthScene, directory: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write one generated scene (capture + ``synth_gt.npz``) into ``directory``; returns its path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    names = scene.capture.camera_names
    flow = np.stack([scene.flow[n] for n in names]).astype(np.float16)
    gt = {
        "camera_names": np.array(names),
        "flow_valid": np.stack([scene.flow_valid[n] for n in names]),
        "object_ids": np.stack([scene.object_ids[n] for n in names]),
        "dynamic_mask": np.stack([scene.dynamic_mask[n] for n in names]),
    }
    with open(directory / (FLOW_NAME + ".tmp"), "wb") as fh:
        np.save(fh, flow, allow_pickle=False)
    os.replace(directory / (FLOW_NAME + ".tmp"), directory / FLOW_NAME)
    tmp = directory / (GT_NAME + ".tmp.npz")
    _save_npz(tmp, gt)
    os.replace(tmp, directory / GT_NAME)
    write_capture(scene.capture, directory, media="png", depth="png16", overwrite=overwrite)
    return directory


def read_ground_truth(directory: str | os.PathLike) -> dict[str, dict[str, np.ndarray]]:
    """Read ``synth_gt.npz`` of a scene directory: field -> camera -> array (flow as float32)."""
    path = Path(directory) / GT_NAME
    flow_path = Path(directory) / FLOW_NAME
    if not path.is_file() or not flow_path.is_file():
        raise SynthError(f"{directory} has no {GT_NAME} + {FLOW_NAME}; it is not a generated synthetic scene")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["flow"] = np.load(flow_path, allow_pickle=False)
    except (ValueError, OSError, KeyError, EOFError) as exc:
        raise SynthError(f"{directory}: ground truth is damaged: {exc}") from None
    needed = ("camera_names", "flow", "flow_valid", "object_ids", "dynamic_mask")
    missing = [k for k in needed if k not in arrays]
    if missing:
        raise SynthError(f"{path} lacks arrays {missing}")
    names = [str(n) for n in arrays["camera_names"]]
    out: dict[str, dict[str, np.ndarray]] = {}
    for key in needed[1:]:
        a = arrays[key]
        if a.ndim < 1 or a.shape[0] != len(names):
            raise SynthError(f"{directory}: {key} has shape {a.shape}, expected {len(names)} cameras first")
        a = a.astype(np.float32) if key == "flow" else a
        out[key] = {n: a[i] for i, n in enumerate(names)}
    return out


def _write_one(job: tuple[int, str, SynthConfig, str, bool]) -> str:
    seed, split, config, out_dir, overwrite = job
    path = Path(out_dir) / scene_dirname(seed, split)
    if not overwrite and all((path / f).is_file() for f in ("capture.json", GT_NAME, FLOW_NAME)):
        return str(path)
    write_scene(generate_scene(seed, split=split, config=config), path, overwrite=True)
    return str(path)


def write_dataset(
    out_dir: str | os.PathLike, *, num_scenes: int, split: str, seed: int = 0,
    config: SynthConfig = SynthConfig(), workers: int = 2, overwrite: bool = False,
    progress: bool = False,
) -> list[Path]:
    """Generate scenes ``seed .. seed + num_scenes - 1`` of ``split`` into ``out_dir``.

    Uses ``workers`` processes (1 = in this process).  Complete scenes already on disk are kept unless
    ``overwrite``.  Returns the scene directories in seed order.  ``progress`` shows a tqdm bar.
    """
    check_split(split)
    for name, v, lo in (("num_scenes", num_scenes, 0), ("seed", seed, 0), ("workers", workers, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise SynthError(f"{name} must be an integer >= {lo}, got {v!r}")
    if num_scenes > MAX_SCENES:
        raise SynthError(f"num_scenes is limited to {MAX_SCENES}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(seed + i, split, config, str(out), overwrite) for i in range(num_scenes)]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=num_scenes, unit="scene", desc=f"synth {split}")
    paths: list[str] = []
    try:
        if workers == 1 or num_scenes <= 1:
            for job in jobs:
                paths.append(_write_one(job))
                if bar is not None:
                    bar.update(1)
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                for p in pool.map(_write_one, jobs, chunksize=4):
                    paths.append(p)
                    if bar is not None:
                        bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    return [Path(p) for p in paths]

"""The synthetic multi-camera dynamic scene generator (numpy only; no torch).

    from vt4dcodec.synth import SynthConfig, generate_scene, write_dataset
    scene = generate_scene(7, split="train", config=SynthConfig(num_cameras=10, num_frames=8))
    scene.capture, scene.flow, scene.dynamic_mask, scene.object_ids
    xy, visible = true_tracks(scene, "cam00", [[10, 20, 0]])   # exact 2-D tracks (N, T, 2), (N, T)

See docs/synth.md for what the scenes look like and the asset-disjoint train/test split.
"""

from .assets import SynthError, texture_names, texture_split  # noqa: F401
from .generator import SceneSetup, SynthConfig, SynthScene, generate_scene, scene_id, scene_setup  # noqa: F401
from .tracks import true_tracks  # noqa: F401
from .dataset_writer import read_ground_truth, write_dataset, write_scene  # noqa: F401

__all__ = ["SynthConfig", "SynthScene", "generate_scene", "write_dataset", "write_scene", "scene_id",
           "SynthError", "texture_names", "texture_split", "read_ground_truth", "SceneSetup", "scene_setup",
           "true_tracks"]

"""The evaluation figure draws one column per method the run predicted, the Table 5 ablations included."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from PIL import Image

from vt4dcodec.eval.report import FIGURE_COLUMNS, save_figure
from vt4dcodec.eval.protocol import METHODS


def _kept(methods: tuple[str, ...]) -> dict[int, dict]:
    frames = {name: np.full((4, 16, 16, 3), 40 * i, np.uint8) for i, name in enumerate(("cam00", "cam01"))}
    capture = SimpleNamespace(num_frames=4, camera_names=["cam00", "cam01"], frames=frames)
    entry = {m: {"videos": [np.full((4, 16, 16, 3), 10 * k, np.uint8)]} for k, m in enumerate(methods)}
    return {0: {**entry, "scene": {"scene": SimpleNamespace(capture=capture), "targets": ["cam01"]}}}


def test_every_token_method_has_a_column():
    assert set(FIGURE_COLUMNS) == set(METHODS) - {"ours_no_static", "mean_colour"}


def test_figure_width_grows_with_the_ablations(tmp_path):
    base = ("ours", "ours_no_dynamic", "unified")
    table5 = base + ("no_motion_isolation", "fixed_grid")
    narrow = Image.open(save_figure(tmp_path / "a.png", _kept(base))).size
    wide = Image.open(save_figure(tmp_path / "b.png", _kept(table5))).size
    assert wide[0] > narrow[0] * 1.25 and wide[1] == narrow[1]

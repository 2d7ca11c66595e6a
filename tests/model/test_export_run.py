"""export_run: a training checkpoint becomes a model directory with frozen tables, its decode steps and the
config fields asked for."""

import json

import numpy as np
import pytest
import torch

from vt4dcodec import codec
from vt4dcodec.model import VideoTok4D
from vt4dcodec.model.configs import get_config
from vt4dcodec.model.train.common import save_checkpoint
from vt4dcodec.model.train.export_run import main
from vt4dcodec.model.train.ship import reconfigure

SMALL = dict(frames=4, image_size=32, width=32, heads=2, ae_width=8, spatial_layers=1, static_query_layers=1,
             track_layers=1, renderer_layers=1, n_static=80, n_dynamic=4, token_dim=8, n_tracks=8, patch_size=2,
             locality_sigma=0.35, query_from_grid=True, project_anchors=True, prediction="x0", anchor_views=True,
             token_splat=True, token_from_cell=True, frame_copies=True, entropy_levels=2)


def test_a_run_exports_with_its_decode_steps_frozen_tables_and_the_rounding_asked_for(tmp_path, capsys):
    cfg = get_config("tiny", **SMALL)
    net = VideoTok4D(cfg)
    save_checkpoint(tmp_path / "run" / "checkpoint", net, torch.optim.SGD(net.parameters(), lr=0.1), 3,
                    {"config": cfg.to_dict(), "args": {"tau_one": 1.0}})
    assert main(["--run", str(tmp_path / "run"), "--out", str(tmp_path / "m"), "--version", "0.0.1-dev",
                 "--set", "entropy_rounding=[0.45,0.2,0.45,0.5,0.5,0.5]"]) == 0
    model = codec.load_model(tmp_path / "m")
    assert model.decode_steps == 1  # trained at tau = 1 only (model_from_run), not the reconfigured default
    assert json.loads((tmp_path / "m" / "config.json").read_text())["config"]["entropy_rounding"] == \
        [0.45, 0.2, 0.45, 0.5, 0.5, 0.5]
    tables = codec.model_tables(model)
    assert tables is not None and np.array_equal(tables.rounding, [[0.45, 0.2, 0.45], [0.5, 0.5, 0.5]])
    assert "step 3" in capsys.readouterr().out


def test_reconfigure_keeps_the_codec_settings():
    """Regression: ship's --set rebuilt the model from its config and so dropped decode_steps (back to the
    default 8 for a model trained to decode in 1) and default_quality."""
    net = VideoTok4D(get_config("tiny", **SMALL))
    net.decode_steps, net.default_quality = 1, 2
    new = reconfigure(net, {"entropy_rounding": [0.5] * 6})
    assert (new.decode_steps, new.default_quality) == (1, 2)


@pytest.mark.parametrize("extra", [["--set", "entropy_rounding=[0.9]"], ["--set", "width=64"]])
def test_bad_overrides_are_usage_errors_naming_the_flag(tmp_path, extra, capsys):
    cfg = get_config("tiny", **SMALL)
    net = VideoTok4D(cfg)
    save_checkpoint(tmp_path / "run" / "checkpoint", net, torch.optim.SGD(net.parameters(), lr=0.1), 1,
                    {"config": cfg.to_dict(), "args": {}})
    with pytest.raises(SystemExit) as exc:
        main(["--run", str(tmp_path / "run"), "--out", str(tmp_path / "m"), "--version", "1", *extra])
    assert exc.value.code == 2 and "--set" in capsys.readouterr().err

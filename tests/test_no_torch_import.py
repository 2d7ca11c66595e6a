"""Reading and writing .vt4d files must not import torch or cv2 (checked in a fresh interpreter)."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_format_round_trip_and_cli_do_not_import_torch_or_cv2(tmp_path):
    script = textwrap.dedent(f"""
        import sys
        import numpy as np
        import vt4dcodec
        from vt4dcodec.cameras import Trajectory
        from vt4dcodec.format import ModelFingerprint, Scene, load, open_scene, save, verify
        from vt4dcodec.cli import main
        fp = ModelFingerprint("m", "1", "a" * 64, "b" * 64, (2, 2), (1, 2))
        cams = Trajectory(np.array([[9.0, 0, 1], [0, 9.0, 1], [0, 0, 1]]), np.eye(4), 4, 4)
        scene = Scene(np.ones((2, 2)), np.zeros((1, 2)), cams, fp)
        path = {str(tmp_path / "a.vt4d")!r}
        save(scene, path)
        load(path); verify(path); open_scene(path).summary()
        assert main(["info", path]) == 0 and main(["verify", path]) == 0
        bad = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "cv2", "kornia"))
        assert not bad, bad
        print("clean")
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "clean" in out.stdout

"""Inputs the fuzz campaign (bench/fuzz_campaign.py) found, kept as regressions: each is read without a numpy
RuntimeWarning, and either refused with the library's error family or read exactly as the FORMAT.md-only
reader reads it.

- nan_camera_plane: a float32 compact-camera plane holding a signalling NaN ("invalid value in cast");
- rans_scale_overflow_refused / _unused: int-rans scales whose dequantization table overflows float32
  ("overflow in cast"), once in entries the tokens use (refused), once only in unused ones (read)."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from format_strategies import REPO
from vt4dcodec.errors import Vt4dError
from vt4dcodec.format import load, open_scene

CASES = sorted((Path(__file__).parent / "fuzz_regressions").glob("*.vt4d"))


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_fuzz_finding_reads_quietly_and_as_the_spec_reader(path):
    sys.path.insert(0, str(REPO / "spec"))
    import make_vectors

    make_vectors.install_spec_tables()
    data = path.read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            f = open_scene(data)
            f.verify()
            scene = load(data)
        except Vt4dError:
            assert "refused" in path.stem or "nan" in path.stem
            return
    assert "unused" in path.stem
    import test_independent_reader as spec

    parsed = spec.read_scene(data)
    want = np.asarray(spec.decode_tokens(parsed, "ZSTA", "QSTA", parsed["header"]["static_shape"]), np.float32)
    assert np.array_equal(want, scene.static_tokens)

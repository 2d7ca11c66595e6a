"""`vt4d capture-info` and `vt4d contact-sheet`, and the contact sheet itself."""

import json

import cv2
import numpy as np
import pytest

from vt4dcodec.capture import write_capture
from vt4dcodec.capture.contact_sheet import HEADER_HEIGHT, LABEL_WIDTH, contact_sheet
from vt4dcodec.cli import main
from vt4dcodec.errors import CaptureError

from capture_helpers import make_capture


@pytest.fixture
def capture_dir(tmp_path):
    write_capture(make_capture(T=5, width=32, height=24), tmp_path / "cap")
    return tmp_path / "cap"


def test_capture_info_json(capture_dir, capsys):
    assert main(["capture-info", str(capture_dir), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["num_frames"] == 5 and info["num_cameras"] == 2 and info["fps"] == 10.0
    cam = info["cameras"][0]
    assert cam["name"] == "cam_a" and (cam["width"], cam["height"]) == (32, 24)
    assert cam["depth"]["type"] == "npy_m" and cam["media"]["exists"]
    assert not cam["static"] and cam["path_length_m"] == pytest.approx(0.3)
    assert info["cameras"][1]["depth"] is None


def test_capture_info_text_and_errors(capture_dir, tmp_path, capsys):
    assert main(["capture-info", str(capture_dir)]) == 0
    out = capsys.readouterr().out
    assert "2 cameras, 5 frames" in out and "cam_b" in out
    assert main(["capture-info", str(tmp_path / "missing")]) == 3  # a missing input: exit 3 on every command
    assert "missing: no such file or directory" in capsys.readouterr().err
    (capture_dir / "capture.json").write_text("{}")
    assert main(["capture-info", str(capture_dir)]) == 1


def test_contact_sheet_command(capture_dir, tmp_path, capsys):
    out = tmp_path / "sheet.png"
    assert main(["contact-sheet", str(capture_dir), "-o", str(out), "--frames", "3", "--thumb-height", "24"]) == 0
    img = cv2.imread(str(out))
    assert img.shape == (HEADER_HEIGHT + 2 * (24 + 2), LABEL_WIDTH + 3 * (32 + 2), 3)
    with pytest.raises(SystemExit) as exc:
        main(["contact-sheet", str(capture_dir), "-o", str(out), "--frames", "0"])
    assert exc.value.code == 2


def test_contact_sheet_places_the_right_frames():
    cap = make_capture(T=10, width=16, height=8, depth=False)
    sheet = contact_sheet(cap, max_frames=4, thumb_height=8)
    # columns are frames 0, 3, 6, 9; thumbnails at native size are exact copies
    for row, name in enumerate(cap.cameras):
        for col, f in enumerate([0, 3, 6, 9]):
            y, x = HEADER_HEIGHT + row * (8 + 2), LABEL_WIDTH + col * (16 + 2)
            np.testing.assert_array_equal(sheet[y:y + 8, x:x + 16], cap.frames[name][f])
    with pytest.raises(CaptureError):
        contact_sheet(cap, max_frames=0)


def test_bad_usage_exits_2(capture_dir):
    with pytest.raises(SystemExit) as exc:
        main(["contact-sheet", str(capture_dir)])  # -o is required
    assert exc.value.code == 2

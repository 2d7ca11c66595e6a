"""Packaging: a core install without torch reads and writes scenes and archives; the extras and the
README's commands bring the rest; one version; type hints shipped; no fcntl.

The real core install (a fresh venv with `pip install .` alone) is .ci/run's last step; here the same
check script runs in this interpreter with the codec's packages made unimportable.
"""

from __future__ import annotations

import importlib.metadata
import re
import subprocess
import sys
import tomllib

from cli_helpers import ROOT, vt4d

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
CODEC_ONLY = ("torch", "kornia", "cv2", "av", "safetensors", "skimage", "matplotlib", "tqdm", "fsspec", "aiohttp",
              "onnxruntime", "onnx")
# a meta-path finder that makes the codec's packages unimportable, as on a core install
BLOCK_CODEC = f"""
import sys
class _Absent:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {CODEC_ONLY!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, _Absent())
"""


def _names(requirements: list[str]) -> set[str]:
    return {re.split(r"[<>=\[; ]", r, maxsplit=1)[0].lower() for r in requirements}


def test_core_dependencies_are_the_container_only_and_extras_bring_the_rest():
    project = PYPROJECT["project"]
    assert _names(project["dependencies"]) == {"numpy", "msgpack", "zstandard", "filelock"}
    extras = project["optional-dependencies"]
    # the codec runs the exported graphs on onnxruntime: no torch (issue 51); the torch networks are the train extra
    assert {"opencv-contrib-python-headless", "av", "onnxruntime", "tqdm", "vt4dcodec"} <= _names(extras["codec"])
    assert not {"torch", "kornia", "safetensors", "onnx"} & _names(extras["codec"])
    assert {"torch", "kornia", "safetensors", "onnx"} <= _names(extras["train"]) and "vt4dcodec[codec]" in extras["train"]
    assert "vt4dcodec[remote]" in extras["codec"] and {"fsspec", "aiohttp"} <= _names(extras["remote"])
    assert "vt4dcodec[train]" in extras["test"]  # CI's `pip install -e ".[test]"` gets everything


def test_readme_install_commands_set_up_everything():
    readme = (ROOT / "README.md").read_text()
    installs = re.findall(r"pip install -q -e (\S+)", readme)
    assert installs == ['".[codec]"', '".[test]"'], installs
    assert 'pip install -q -e ".[test]" && python -m pytest' in (ROOT / ".ci" / "run").read_text()


def test_ci_installs_the_core_alone_and_checks_it():
    run = (ROOT / ".ci" / "run").read_text()
    assert ".venv-core/bin/pip install -q ." in run and "core_check.py" in run
    assert "find_spec('torch') is not None" in run  # the step fails if torch crept into the core


def test_core_check_passes_with_the_codec_packages_absent():
    code = BLOCK_CODEC + f"""
import runpy
sys.argv = ["core_check.py"]
runpy.run_path({str(ROOT / ".ci" / "core_check.py")!r}, run_name="__main__")
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "core install OK" in r.stdout


def test_a_codec_command_on_the_core_names_the_extra(tmp_path):
    code = BLOCK_CODEC + f"""
from vt4dcodec.cli import main
sys.exit(main(["encode", {str(tmp_path)!r}, "-o", {str(tmp_path / "x.vt4d")!r}, "--model", "vt4d-tiny"]))
"""
    (tmp_path / "capture.json").write_text("{}")  # a capture folder as far as the argument checks go
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 1 and 'pip install "vt4dcodec[codec]"' in r.stderr, r.stderr


def test_version_is_written_once_and_read_from_the_metadata():
    import vt4dcodec

    assert PYPROJECT["project"]["version"] == vt4dcodec.__version__ == importlib.metadata.version("vt4dcodec")
    assert "version" not in PYPROJECT["project"].get("dynamic", [])
    literal = re.compile(r"__version__\s*=\s*[\"']\d+\.\d+")
    assert not [p for p in (ROOT / "vt4dcodec").rglob("*.py") if literal.search(p.read_text())]
    assert vt4d("--version").stdout.strip() == f"vt4dcodec {vt4dcodec.__version__}"


def test_type_hints_ship_and_no_module_needs_fcntl():
    assert (ROOT / "vt4dcodec" / "py.typed").is_file()
    assert "py.typed" in PYPROJECT["tool"]["setuptools"]["package-data"]["vt4dcodec"]
    assert not [p for p in (ROOT / "vt4dcodec").rglob("*.py") if re.search(r"^\s*import fcntl", p.read_text(), re.M)]


def test_the_readme_installs_from_a_clone_not_an_index_that_lacks_the_package():
    """`pip install vt4dcodec` is not published: the README says so and installs from a clone (or a wheel built
    there); no install line names the package as if an index had it."""
    readme = (ROOT / "README.md").read_text()
    by_name = re.findall(r'pip install "?vt4dcodec(?![-\w])[^`]*', readme)  # not a wheel's file name
    assert by_name == ['pip install vt4dcodec'], by_name  # the one that says it finds nothing
    assert "`pip install vt4dcodec` finds nothing" in readme and "from a\nclone of this repository" in readme
    assert 'pip install ".[codec]"' in readme and "pip wheel --no-deps -w dist ." in readme

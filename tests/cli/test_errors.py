"""Every error of the `vt4d` command names the flag that fixes it, never a Python keyword."""

from __future__ import annotations

import ast
import re

from cli_helpers import ROOT, make_scene, save_small_model, vt4d

from vt4dcodec import ArchiveWriter, save
from vt4dcodec.cli import KEYWORD_FLAGS, cli_message

# the form of a keyword hint in a library message: replace=True, on_uncommitted='discard', model=<path>
HINT = re.compile(r"(?<![`\w])[a-z_]+=(?:True|False|'[^']*'|<[^>]+>)")
# hints no command can reach, with the reason
API_ONLY = {"depth='npy'": "write_capture's depth format; the commands write synthetic rooms (depth < 65 m) only",
            "media='png'": "write_capture's media format; the commands write PNG captures only",
            "header='compact'": "dumps/save's header layout beside header_dictionary=2; the commands write compact "
                                "headers and the writer's own dictionary choice"}


def _message_hints() -> set[str]:
    """Every keyword hint in a string literal (docstrings aside) of the library and the networks."""
    found = set()
    for root in ("vt4dcodec", "model"):
        for path in (ROOT / root).rglob("*.py"):
            if "cli" in path.parts:
                continue
            tree = ast.parse(path.read_text())
            docs = {id(n.body[0].value) for n in ast.walk(tree)
                    if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                    and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
                    found.update(HINT.findall(node.value))
    return found


def test_every_keyword_hint_in_the_library_has_a_flag():
    hints = _message_hints()
    assert {"replace=True", "model=<path to the model directory>", "force=True"} <= hints  # the scan sees them
    assert hints - set(KEYWORD_FLAGS) - set(API_ONLY) == set()


def test_cli_message_rewrites_hints_into_the_commands_flags():
    assert cli_message("scene 'a' is already in x (pass replace=True)", {"--overwrite"}) == \
        "scene 'a' is already in x (pass --overwrite)"
    assert cli_message("decode with the model that made it, or force=True (--force) to try anyway", {"--force"}) == \
        "decode with the model that made it, or --force to try anyway"
    assert cli_message("pass allow_truncated=True (CLI: --allow-truncated) to read it", {"--allow-truncated"}) == \
        "pass --allow-truncated to read it"
    # a parenthesised alternative the command has no flag for is the API's alone: dropped
    assert cli_message("run `vt4d repair` (or open with on_uncommitted='discard' to drop them)", set()) == \
        "run `vt4d repair`"
    assert cli_message("x; pass model=<path to the model directory>", {"--model"}) == "x; pass --model PATH"


def test_encode_into_an_existing_key_names_overwrite_and_replace_still_works(small_model, capture_dir, tmp_path):
    archive = tmp_path / "a.vt4da"
    assert vt4d("encode", capture_dir, "--model", small_model, "--archive", archive, "-q").returncode == 0
    r = vt4d("encode", capture_dir, "--model", small_model, "--archive", archive)
    assert r.returncode == 1 and "--overwrite" in r.stderr and "replace=True" not in r.stderr, r.stderr
    r = vt4d("encode", capture_dir, "--model", small_model, "--archive", archive, "--replace", "--json")  # as before
    assert r.returncode == 0, r.stderr
    assert vt4d("encode", capture_dir, "-o", tmp_path / "x.vt4d", "--replace").returncode == 1  # archives only


def test_pack_duplicate_key_names_overwrite(scene_file, tmp_path):
    archive = tmp_path / "a.vt4da"
    assert vt4d("pack", scene_file, "-o", archive, "-q").returncode == 0
    r = vt4d("pack", scene_file, "-o", archive, "--append")
    assert r.returncode == 1 and "--overwrite" in r.stderr and "replace=True" not in r.stderr, r.stderr
    assert vt4d("pack", scene_file, "-o", archive, "--append", "--overwrite", "-q").returncode == 0


def test_unknown_model_names_the_model_flag(capture_dir, tmp_path, scene_file):
    r = vt4d("encode", capture_dir, "--model", "no-such-model", "-o", tmp_path / "x.vt4d")
    assert r.returncode == 1 and "--model PATH" in r.stderr and "model=" not in r.stderr, r.stderr
    r = vt4d("decode", scene_file, "-o", tmp_path / "v")  # its fingerprint names model "m", which nobody has
    assert r.returncode == 1 and "--model PATH" in r.stderr and "model=" not in r.stderr, r.stderr


def test_unknown_prior_names_the_prior_flag(capture_dir, tmp_path):
    r = vt4d("generate", capture_dir, "--prior", "no-such-prior", "-o", tmp_path / "g")
    assert r.returncode == 1 and "--prior PATH" in r.stderr, r.stderr
    assert not (tmp_path / "g").exists()


def test_a_different_model_names_force(encoded_file, tmp_path):
    other = save_small_model(tmp_path, seed=1)  # same id and shapes, other weights
    r = vt4d("decode", encoded_file, "--model", other, "-o", tmp_path / "v", "--steps", "1")
    assert r.returncode == 1 and "--force" in r.stderr and "force=True" not in r.stderr, r.stderr
    r = vt4d("decode", encoded_file, "--model", other, "-o", tmp_path / "v", "--steps", "1", "--force", "-q")
    assert r.returncode == 0 and r.stdout == "", r.stderr


def test_uncommitted_bytes_name_repair_and_a_pack_flag(scene_file, tmp_path):
    archive = tmp_path / "a.vt4da"
    with ArchiveWriter(archive) as w:
        w.append("a", scene_file.read_bytes())
        w.commit()
    with open(archive, "ab") as fh:  # a crashed writer's torn bytes after the last commit
        fh.write(b"\0" * 100)
    save(make_scene(), tmp_path / "b.vt4d")
    r = vt4d("pack", tmp_path / "b.vt4d", "-o", archive, "--append")
    assert r.returncode == 1 and "vt4d repair" in r.stderr and "on_uncommitted" not in r.stderr, r.stderr
    r = vt4d("pack", tmp_path / "b.vt4d", "-o", archive, "--append", "--discard-uncommitted", "--json")
    assert r.returncode == 0, r.stderr

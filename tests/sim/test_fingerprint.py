"""The world fingerprint follows the code and constants of the world modules, not their prose."""

import shutil
from pathlib import Path

from nerf_transporter.sim import fingerprint

BLOCK = "sim/tasks/block_insertion.py"


def _copy_package(tmp_path: Path) -> Path:
    root = tmp_path / "nerf_transporter"
    shutil.copytree(fingerprint.PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_a_changed_constant_changes_its_module_digest(tmp_path):
    root = _copy_package(tmp_path)
    before = fingerprint.module_digests(root)
    assert before == fingerprint.module_digests()  # the copy is the installed package
    _edit(root / BLOCK, "CLEARANCE = 0.009", "CLEARANCE = 0.012")
    after = fingerprint.module_digests(root)
    assert [name for name in before if after[name] != before[name]] == [BLOCK]
    old_world, new_world = fingerprint.world_description(), fingerprint.world_description(root)
    assert new_world["fingerprint"] != old_world["fingerprint"]
    assert fingerprint.world_changes(old_world, new_world) == [f"{BLOCK} changed"]


def test_an_edited_comment_changes_nothing(tmp_path):
    root = _copy_package(tmp_path)
    before = fingerprint.module_digests(root)
    _edit(
        root / BLOCK,
        "# m between a centred block and each wall",
        "# metres from a centred block to each wall",
    )
    assert fingerprint.module_digests(root) == before
    assert fingerprint.world_description(root) == fingerprint.world_description()

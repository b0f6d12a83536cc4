"""Layers point one way (geometry/models/splits -> sim -> imagery -> data -> methods -> evaluation
-> CLI): using a module loads no package of a layer above it. Each probe runs in a fresh
interpreter, so what it loaded shows in `sys.modules`."""

import json

import pytest

from tests.helpers.fresh_python import run_python

LAYERS = ["sim", "imagery", "data", "methods", "evaluation", "cli"]


def loaded_packages(code: str) -> set[str]:
    """The `nerf_transporter.<package>` names loaded after running `code`."""
    probe = (
        f"{code}\nimport json, sys\n"
        "print(json.dumps(sorted({name.split('.')[1] for name in sys.modules "
        "if name.startswith('nerf_transporter.')})))"
    )
    result = run_python("-c", probe)
    return set(json.loads(result.stdout.splitlines()[-1]))


@pytest.mark.parametrize(
    ("layer", "code"),
    [
        ("methods", "import nerf_transporter.methods"),
        (
            "data",  # the test seeds too: they were read from evaluation.testing
            "from nerf_transporter.data.datamodule import RavensDataModule\n"
            "RavensDataModule('block-insertion', test_episodes=2).test_dataloader()",
        ),
    ],
    ids=["methods", "data.datamodule"],
)
def test_a_layer_loads_nothing_from_the_layers_above(layer, code):
    above = set(LAYERS[LAYERS.index(layer) + 1 :])
    loaded = loaded_packages(code)
    assert layer in loaded  # the probe saw the import
    assert not loaded & above, f"{code!r} loads {sorted(loaded & above)}"


def _imported_sim_modules(path) -> set[str]:
    """The `nerf_transporter.sim...` modules a source file imports anywhere in it (type-checking
    imports included), as module names."""
    import ast

    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            base = node.module
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    return {name for name in names if name.startswith("nerf_transporter.sim.")}


def test_the_world_modules_import_each_other_one_way():
    """A task knows its assets, oracle and reward, the environment the robot and cameras: no
    module of `sim/` reaches back to one that imports it (`env` -> `tasks` -> `primitives` ->
    `robot` -> `assets`, never the other way)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "src" / "nerf_transporter"
    modules = {
        ".".join(("nerf_transporter", *path.relative_to(root).with_suffix("").parts)).removesuffix(
            ".__init__"
        ): path
        for path in (root / "sim").rglob("*.py")
    }
    graph = {
        name: {m for m in _imported_sim_modules(path) if m in modules and m != name}
        for name, path in modules.items()
    }

    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        for nxt in graph[start]:
            if nxt == goal or (nxt not in seen and reaches(nxt, goal, seen | {nxt})):
                return True
        return False

    package = "nerf_transporter.sim"
    cycles = sorted(
        name
        for name in graph
        if name not in (package, f"{package}.tasks") and reaches(name, name, set())
    )
    assert not cycles, f"sim/ modules in an import cycle: {cycles}"

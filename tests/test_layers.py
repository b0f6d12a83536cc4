"""Layers point one way (geometry/models/splits -> sim -> imagery -> data -> methods -> evaluation
-> experiments -> CLI): using a module loads no package of a layer above it (the probes, each in a
fresh interpreter, so what it loaded shows in `sys.modules`), no module imports one of a layer
above its own or `cli.py`, and no modules import each other, directly or through others (read
from the source: imports inside functions and under TYPE_CHECKING count, and so do the module
names that a module hands to `importlib.import_module`)."""

import ast
import json
from pathlib import Path

import pytest

from tests.helpers.fresh_python import run_python

LAYERS = ["sim", "imagery", "data", "methods", "evaluation", "experiments", "cli"]
PACKAGE = Path(__file__).resolve().parents[1] / "src" / "nerf_transporter"


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


def module_name(path: Path) -> str:
    """`nerf_transporter.<dotted path>` of a source file (a package's `__init__.py`: the package)."""
    parts = ("nerf_transporter", *path.relative_to(PACKAGE).with_suffix("").parts)
    return ".".join(parts).removesuffix(".__init__")


MODULES = {module_name(path): path for path in PACKAGE.rglob("*.py")}


def imported_modules(path: Path) -> set[str]:
    """The package's modules that a source file imports anywhere in it: `from a.b import c` is the
    module `a.b.c` where there is one, else `a.b`; in a module that calls `import_module`, every
    string naming a module (`"pkg.mod"` or `"pkg.mod:function"`) too."""
    tree = ast.parse(path.read_text())
    dynamic = any(
        isinstance(node, ast.Attribute) and node.attr == "import_module" for node in ast.walk(tree)
    )
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            for alias in node.names:
                submodule = f"{node.module}.{alias.name}"
                names.add(submodule if submodule in MODULES else node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif dynamic and isinstance(node, ast.Constant) and isinstance(node.value, str):
            names.add(node.value.split(":")[0])
    return {name for name in names if name in MODULES} - {module_name(path)}


IMPORTS = {name: imported_modules(path) for name, path in MODULES.items()}


def reachable(start: str) -> set[str]:
    """The modules that importing `start` imports, directly or through others."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        for name in IMPORTS[todo.pop()] - seen:
            seen.add(name)
            todo.append(name)
    return seen


def layer(name: str) -> int | None:
    """The index of a module's layer in LAYERS (None: a module of the ground, e.g. geometry)."""
    parts = name.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def test_the_import_reader_sees_every_kind_of_import():
    """The checks below read what they claim to: plain, lazy, aliased and by-string imports."""
    assert (
        "nerf_transporter.experiments.checkpoints" in IMPORTS["nerf_transporter.experiments.runs"]
    )
    assert "nerf_transporter.evaluation.workers" in IMPORTS["nerf_transporter.evaluation.rollout"]
    assert "nerf_transporter.experiments.run_cell" in IMPORTS["nerf_transporter.cli"]  # TOOLS
    assert "nerf_transporter.sim.env" in IMPORTS["nerf_transporter.sim"]  # its lazy names


def test_no_module_imports_one_of_a_layer_above_its_own():
    above = {
        name: sorted(
            other
            for other in reachable(name)
            if layer(other) is not None and (layer(name) is None or layer(other) > layer(name))
        )
        for name in MODULES
        if name != "nerf_transporter"  # the package registers the gymnasium ids (sim.registration)
    }
    assert not {name: found for name, found in above.items() if found}


def test_the_cli_is_the_top_no_module_imports_it():
    """`cli.py` dispatches (to `experiments.lightning_cli` and the tools by their module names);
    the run folders and the LightningCLI it starts live below it."""
    assert not [name for name, imports in IMPORTS.items() if "nerf_transporter.cli" in imports]
    assert "nerf_transporter.experiments.lightning_cli" in reachable("nerf_transporter.cli")


def test_no_modules_import_each_other_directly_or_through_others():
    in_a_circle = sorted(name for name in MODULES if name in reachable(name))
    assert not in_a_circle, f"modules in an import circle: {in_a_circle}"


def test_one_function_turns_a_policys_episodes_into_its_results_record():
    """`lightning test`, `evaluate-checkpoints` and `try` all evaluate a policy through
    `evaluation.testing.evaluate_policy`: nothing else builds a results record."""
    callers = set()
    for name, path in MODULES.items():
        for function in ast.walk(ast.parse(path.read_text())):
            if isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
                for node in ast.walk(function):
                    if (
                        isinstance(node, ast.Call)
                        and isinstance(node.func, ast.Name)
                        and node.func.id == "results_record"
                    ):
                        callers.add(f"{name}.{function.name}")
    assert callers == {"nerf_transporter.evaluation.testing.evaluate_policy"}

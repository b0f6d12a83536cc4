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

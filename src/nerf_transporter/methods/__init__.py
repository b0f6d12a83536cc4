"""LightningModules, one per method, all with `act(observation) -> action`.

Importing this package registers every method as a subclass of `Method`, so LightningCLI accepts
short class names (`class_path: Mira`).
"""

from nerf_transporter.methods.base import Method
from nerf_transporter.methods.form2fit import Form2Fit
from nerf_transporter.methods.gt_state_mlp import GTStateMLP
from nerf_transporter.methods.mira import Mira
from nerf_transporter.methods.transporter_se2 import TransporterSE2
from nerf_transporter.methods.transporter_se3 import TransporterSE3

METHODS: dict[str, type[Method]] = {
    cls.name: cls for cls in (Mira, TransporterSE2, TransporterSE3, Form2Fit, GTStateMLP)
}
# Arguments a checkpoint is tested under as the test's config says, not as it was fitted with.
TEST_TIME_OPTIONS = tuple(
    sorted({option for cls in METHODS.values() for option in cls.test_time_options})
)

__all__ = [
    "METHODS",
    "TEST_TIME_OPTIONS",
    "Form2Fit",
    "GTStateMLP",
    "Method",
    "Mira",
    "TransporterSE2",
    "TransporterSE3",
]

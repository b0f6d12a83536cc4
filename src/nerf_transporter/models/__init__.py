"""Plain nn.Modules: ResNet43_8s FCN, attention, transport, SE(3) heads, Form2Fit, state MLP."""

from nerf_transporter.models.attention import Attention, pixel_cross_entropy
from nerf_transporter.models.form2fit import Form2FitNets, rotation_contrastive_loss
from nerf_transporter.models.mlp import StateMLP, columns_from_rotation, rotation_from_columns
from nerf_transporter.models.resnet import ResNet43_8s
from nerf_transporter.models.se3 import PoseRegression
from nerf_transporter.models.transport import (
    Transport,
    bin_angles,
    cross_correlate,
    placement_cross_entropy,
    rotated_crops,
    unravel_argmax,
)

__all__ = [
    "Attention",
    "Form2FitNets",
    "PoseRegression",
    "ResNet43_8s",
    "StateMLP",
    "Transport",
    "bin_angles",
    "columns_from_rotation",
    "cross_correlate",
    "pixel_cross_entropy",
    "placement_cross_entropy",
    "rotated_crops",
    "rotation_contrastive_loss",
    "rotation_from_columns",
    "unravel_argmax",
]

"""privslam_jax.inpaint: EdgeConnect networks, privacy-safe masks and edges, baselines."""

from privslam_jax.inpaint.edgeconnect import (
    CPU_WIDTH,
    Conv,
    Discriminator,
    EdgeGenerator,
    InpaintGenerator,
    ResnetBlock,
    SpectralState,
    count_params,
    instance_norm,
)
from privslam_jax.inpaint.weights import load_npz, load_state_dict

__all__ = [
    "CPU_WIDTH",
    "Conv",
    "Discriminator",
    "EdgeGenerator",
    "InpaintGenerator",
    "ResnetBlock",
    "SpectralState",
    "count_params",
    "instance_norm",
    "load_npz",
    "load_state_dict",
]

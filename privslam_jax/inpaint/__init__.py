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
from privslam_jax.inpaint.baselines import LEAKY_METHODS, METHODS, SAFE_METHODS, fill
from privslam_jax.inpaint.data import CropBank, FolderData, Mixture, RealHoleData
from privslam_jax.inpaint.crops import CropBox, crop_box, extract, paste_back
from privslam_jax.inpaint.filter import (
    FILTER_METHODS,
    Inpainter,
    InpainterConfig,
    edgeconnect_forward,
    filter_frame,
    inpaint_inference,
)
from privslam_jax.inpaint.differentiable import (
    FilterConstants,
    FilterModel,
    filter_constants,
    filter_image,
    resize_matrices,
)
from privslam_jax.inpaint.losses import (
    discriminator_loss,
    feature_matching_loss,
    generator_adversarial_loss,
    gram,
    l1_hole_loss,
    perceptual_loss,
    style_loss,
)
from privslam_jax.inpaint.masks import (
    boxes_to_masks,
    dilate,
    edge_band,
    fill_hole_from_outside,
    instance_masks,
    random_box_mask,
    random_irregular_mask,
    safe_canny,
    to_grey,
    union,
)

__all__ = [
    "FILTER_METHODS",
    "LEAKY_METHODS",
    "METHODS",
    "SAFE_METHODS",
    "CropBank",
    "CropBox",
    "FilterConstants",
    "FilterModel",
    "FolderData",
    "Mixture",
    "RealHoleData",
    "Inpainter",
    "InpainterConfig",
    "InpaintTrainer",
    "TrainConfig",
    "boxes_to_masks",
    "discriminator_loss",
    "feature_matching_loss",
    "generator_adversarial_loss",
    "gram",
    "l1_hole_loss",
    "perceptual_loss",
    "prepare_batch",
    "style_loss",
    "crop_box",
    "dilate",
    "edge_band",
    "edgeconnect_forward",
    "extract",
    "fill",
    "fill_hole_from_outside",
    "filter_constants",
    "filter_frame",
    "filter_image",
    "inpaint_inference",
    "instance_masks",
    "paste_back",
    "random_box_mask",
    "random_irregular_mask",
    "resize_matrices",
    "safe_canny",
    "to_grey",
    "union",
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

# ``train`` itself stays in privslam_jax.inpaint.train (a same-named attribute would shadow the module)
from privslam_jax.inpaint.train import InpaintTrainer, TrainConfig, prepare_batch  # noqa: E402
# evaluate.py is run as ``python -m privslam_jax.inpaint.evaluate``; importing it here would make runpy warn.

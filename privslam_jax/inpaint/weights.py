"""Import official EdgeConnect weights (torch ``state_dict`` layout, as numpy arrays) into NNX.

The official checkpoints (``EdgeModel_gen.pth`` …) hold ``{"generator": state_dict}`` /
``{"discriminator": state_dict}``. Convert them once to ``.npz`` outside this package (e.g.
``np.savez(path, **{k: v.numpy() for k, v in sd.items()})``) — no torch or pickle is read here.

Key mapping (torch → this package):

* generators: ``encoder.{1,4,7}`` → ``enc1..enc3``, ``middle.{i}.conv_block.{1,5}`` →
  ``middle[i].conv1/conv2``, ``decoder.{0,3}`` (ConvTranspose) → ``dec1/dec2``,
  ``decoder.7`` → ``dec3``;
* discriminators: ``conv{k}.0`` → ``convs[k−1]``; ``features.0`` is torch's alias of
  ``conv1.0`` (``self.conv1 = self.features``) and must equal it.

Suffixes: ``weight`` / ``weight_orig`` → ``kernel`` (Conv2d ``(O, I, kh, kw)`` and
ConvTranspose2d ``(I, O, kh, kw)`` both become HWIO ``(kh, kw, I, O)``), ``bias``,
``weight_u`` → ``u``, ``weight_v`` → ``v`` (already in torch's ``(out, in·kh·kw)`` order,
which :meth:`Conv.weight_matrix` reproduces). Values are cast to float32.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from flax import nnx

from privslam_jax.inpaint.edgeconnect import Conv, Discriminator, _Generator

__all__ = ["load_npz", "load_state_dict"]

_GEN_MAP = {"encoder.1": "enc1", "encoder.4": "enc2", "encoder.7": "enc3", "decoder.0": "dec1",
            "decoder.3": "dec2", "decoder.7": "dec3"}


def _conv_for(module: nnx.Module, layer: str) -> Conv:
    if isinstance(module, _Generator):
        if layer in _GEN_MAP:
            return getattr(module, _GEN_MAP[layer])
        m = re.fullmatch(r"middle\.(\d+)\.conv_block\.([15])", layer)
        if m:
            i = int(m.group(1))
            if i >= len(module.middle):
                raise ValueError(f"state_dict has residual block {i}, the module only {len(module.middle)}")
            return module.middle[i].conv1 if m.group(2) == "1" else module.middle[i].conv2
    elif isinstance(module, Discriminator):
        m = re.fullmatch(r"conv([1-5])\.0", layer)
        if m:
            return module.convs[int(m.group(1)) - 1]
    raise ValueError(f"unexpected state_dict layer {layer!r} for {type(module).__name__}")


def load_state_dict(module: nnx.Module, state: Mapping[str, np.ndarray]) -> None:
    """Copy a torch-layout EdgeConnect ``state_dict`` into ``module`` in place (strict).

    Raises ``ValueError`` on unknown keys, shape mismatches, or missing parameters.
    """
    state = dict(state)
    if isinstance(module, Discriminator):
        for suffix in ("weight_orig", "weight_u", "weight_v", "weight", "bias"):
            alias = state.pop(f"features.0.{suffix}", None)
            if alias is not None and not np.array_equal(alias, state.get(f"conv1.0.{suffix}")):
                raise ValueError(f"features.0.{suffix} differs from its alias conv1.0.{suffix}")
    filled: set[tuple[int, str]] = set()
    for key, value in state.items():
        layer, _, suffix = key.rpartition(".")
        conv = _conv_for(module, layer)
        arr = np.asarray(value, dtype=np.float32)
        if suffix in ("weight", "weight_orig"):
            if (suffix == "weight_orig") != conv.spectral_norm:
                raise ValueError(f"{key}: spectral norm mismatch (module spectral_norm={conv.spectral_norm})")
            torch_shape = (
                (conv.in_features, conv.out_features) if conv.transpose else (conv.out_features, conv.in_features)
            ) + (conv.kernel_size, conv.kernel_size)
            if arr.shape != torch_shape:
                raise ValueError(f"{key}: shape {arr.shape}, expected {torch_shape}")
            hwio = arr.transpose(2, 3, 0, 1) if conv.transpose else arr.transpose(2, 3, 1, 0)
            conv.kernel[...] = jnp.asarray(hwio)
            name = "kernel"
        elif suffix in ("bias", "weight_u", "weight_v"):
            name = {"bias": "bias", "weight_u": "u", "weight_v": "v"}[suffix]
            var = getattr(conv, name)
            if var is None:
                raise ValueError(f"{key}: the module layer has no {name}")
            if arr.shape != var[...].shape:
                raise ValueError(f"{key}: shape {arr.shape}, expected {var[...].shape}")
            var[...] = jnp.asarray(arr)
        else:
            raise ValueError(f"unexpected state_dict key {key!r}")
        filled.add((id(conv), name))
    missing = []
    for path, conv in nnx.iter_graph(module):
        if isinstance(conv, Conv):
            for name in ("kernel", "bias", "u", "v"):
                if getattr(conv, name) is not None and (id(conv), name) not in filled:
                    missing.append(f"{'.'.join(map(str, path))}.{name}")
    if missing:
        raise ValueError(f"state_dict lacks {len(missing)} parameters, e.g. {missing[:3]}")


def load_npz(module: nnx.Module, path: str | Path, prefix: str = "") -> None:
    """Load ``module`` from the arrays of an ``.npz`` whose keys start with ``prefix``.

    ``prefix`` selects one network of a multi-network file, e.g. ``"edge_generator/"``;
    non-parameter arrays under the prefix (``input``, ``output``, ``features*``, ``*.sigma``)
    are ignored.

    A damaged or unusable file (an archive :func:`~privslam_jax.data.npz.read_npz` refuses, no
    parameters under ``prefix``, unknown keys, wrong shapes, missing parameters, NaN or inf
    values) raises :class:`~privslam_jax.errors.InputError` naming it; ``module`` is then left
    partly loaded. A missing file raises ``FileNotFoundError``.
    """
    from privslam_jax.data.npz import check_finite, read_npz
    from privslam_jax.errors import input_error

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"EdgeConnect weights not found: {path}")
    data = read_npz(path)
    state = {
        k[len(prefix):]: v
        for k, v in data.items()
        if k.startswith(prefix) and "." in k[len(prefix):] and not k.endswith(".sigma")
    }
    if not state:
        raise input_error(path, f"no parameters under prefix {prefix!r}")
    bad = [k for k, v in state.items() if v.dtype.kind not in "fiu"]
    if bad:
        raise input_error(path, f"{prefix}{bad[0]} is {state[bad[0]].dtype}, not a number array")
    check_finite(path, state)
    try:
        load_state_dict(module, state)
    except ValueError as err:
        raise input_error(path, f"does not fit the {type(module).__name__}", err) from err

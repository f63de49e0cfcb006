"""vit-pytorch's ViViT (``frame_patch_size=1``, factorised encoder) and slipsense's: the same network.

:func:`from_vit_pytorch` and :func:`load_reference_state_dict` load the study's and vit-pytorch's
weights into :class:`slipsense.models.vivit.ViViT`, so the benchmarks (``bench/bench_vivit.py``) and the
tests compare the two side by side.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Sequence

from torch import Tensor, nn

from slipsense.errors import ConfigError
from slipsense.models.vivit import ViViT, pair


def vit_pytorch_vivit() -> type:
    """vit-pytorch's ViViT class, loaded from its ``vivit.py`` file (the package's ``__init__`` imports
    torchvision); ModuleNotFoundError where vit-pytorch is not installed."""
    spec = importlib.util.find_spec("vit_pytorch")
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError("vit-pytorch is not installed (pip install --no-deps vit-pytorch)")
    path = Path(list(spec.submodule_search_locations)[0]) / "vivit.py"
    mod_spec = importlib.util.spec_from_file_location("_vit_pytorch_vivit", path)
    module = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(module)
    return module.ViViT


_REFERENCE_RENAMES = (
    ("to_patch_embedding.1.", "patch_norm."),
    ("to_patch_embedding.2.", "patch_to_dim."),
    ("to_patch_embedding.3.", "dim_norm."),
    ("spatial_cls_token", "spatial_cls"),
    ("temporal_cls_token", "temporal_cls"),
    ("mlp_head.", "head."),
)


def reference_key(key: str) -> str:
    """The name in :class:`~slipsense.models.vivit.ViViT` of a vit-pytorch ViViT state-dict key."""
    for old, new in _REFERENCE_RENAMES:
        if key.startswith(old):
            return new + key[len(old) :]
    parts = key.split(".")
    # {spatial,temporal}_transformer.layers.{i}.{0: attention, 1: feed-forward}.<...>
    if len(parts) >= 5 and parts[0].endswith("_transformer") and parts[1] == "layers":
        rest = ".".join(parts[4:])
        if parts[3] == "0":
            rest = rest.replace("to_out.0.", "to_out.")
        elif parts[3] == "1":
            rest = {
                "net.0.weight": "norm.weight",
                "net.0.bias": "norm.bias",
                "net.1.weight": "fc1.weight",
                "net.1.bias": "fc1.bias",
                "net.4.weight": "fc2.weight",
                "net.4.bias": "fc2.bias",
            }.get(rest, rest)
        return ".".join(parts[:4] + [rest])
    return key


def from_vit_pytorch(ref: nn.Module, image_size: int | Sequence[int] = (240, 320)) -> ViViT:
    """A ViViT with the weights of a vit-pytorch ``ViViT(frame_patch_size=1, variant="factorized_encoder")``.

    vit-pytorch does not store its image size: pass the one ``ref`` was built with (default: the
    paper's). The two models compute the same logits (vit-pytorch takes the clip as ``(B, C, T, H, W)``).
    """
    if getattr(ref, "frame_patch_size", 1) != 1:
        raise ConfigError("from_vit_pytorch: only frame_patch_size=1 (one token sequence per frame) is supported")
    if getattr(ref, "variant", "factorized_encoder") != "factorized_encoder":
        raise ConfigError("from_vit_pytorch: only variant='factorized_encoder' is supported")
    _, frames, num_patches, dim = ref.pos_embedding.shape
    ph, pw = ref.patch_size
    image_h, image_w = pair(image_size)
    if (image_h // ph) * (image_w // pw) != num_patches:
        raise ConfigError(
            f"from_vit_pytorch: image_size {(image_h, image_w)} with {ph} x {pw} patches does not "
            f"give the reference's {num_patches} patches"
        )
    attn, ff = (ref.spatial_transformer.layers or ref.temporal_transformer.layers)[0]
    model = ViViT(
        image_size=(image_h, image_w),
        patch_size=(ph, pw),
        frames=frames,
        dim=dim,
        spatial_depth=len(ref.spatial_transformer.layers),
        temporal_depth=len(ref.temporal_transformer.layers),
        heads=attn.heads,
        dim_head=attn.to_qkv.out_features // (3 * attn.heads),
        mlp_dim=ff.net[1].out_features,
        pool=ref.pool,
        dropout=float(attn.dropout_p),
        emb_dropout=float(ref.dropout.p),
        channels=ref.to_patch_embedding[1].normalized_shape[0] // (ph * pw),
        num_classes=ref.mlp_head.out_features,
    )
    load_reference_state_dict(model, ref.state_dict())
    return model


def load_reference_state_dict(model: ViViT, sd: dict[str, Tensor]) -> None:
    """Load a vit-pytorch ViViT (``frame_patch_size=1``) state dict, renaming its keys to slipsense's."""
    if model.positions != "slot":
        raise ConfigError(
            "load_reference_state_dict: vit-pytorch's ViViT has per-slot positions; this model has "
            f"positions={model.positions!r}"
        )

    model.load_state_dict({reference_key(k): v for k, v in sd.items()}, strict=True)

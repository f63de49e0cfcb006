"""Key names of vit-pytorch's ViViT (``frame_patch_size=1``, factorised encoder) in slipsense's ViViT.

Used by :meth:`slipsense.models.vivit.ViViT.load_reference_state_dict`, so the study's and
vit-pytorch's weights load into the fast model (the benchmarks compare the two side by side).
"""

from __future__ import annotations

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

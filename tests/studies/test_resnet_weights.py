"""Loading user-supplied 3D ResNet-50 weights (studies/experiments/resnet_weights.py): this model's
names or pytorchvideo's, a Kinetics head skipped, bad files named."""

from __future__ import annotations

import pytest
import torch
from safetensors.torch import save_file

from conftest import perturbed, random_clip
from slipsense.errors import InputError
from slipsense.models import build
from studies.experiments.resnet_weights import load_weights

TINY = dict(width=8)


def _to_pytorchvideo_names(sd: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """This file's names -> pytorchvideo create_resnet names (the inverse of the loader's mapping)."""
    out = {}
    bn = {"bn_a": "norm_a", "bn_b": "norm_b", "bn_c": "norm_c"}
    for key, value in sd.items():
        parts = key.split(".")
        if parts[0] == "stem":
            new = ["blocks", "0", "conv" if parts[1] == "conv" else "norm", *parts[2:]]
        elif parts[0] == "fc":
            new = ["blocks", "5", "proj", *parts[1:]]
        else:
            stage, block, name, rest = int(parts[1]), parts[2], parts[3], parts[4:]
            head = ["blocks", str(stage + 1), "res_blocks", block]
            if name == "shortcut_conv":
                new = head + ["branch1_conv", *rest]
            elif name == "shortcut_bn":
                new = head + ["branch1_norm", *rest]
            else:
                new = head + ["branch2", bn.get(name, name), *rest]
        out[".".join(new)] = value
    return out


def test_resnet3d50_load_weights(tmp_path):
    source = perturbed(build("resnet3d50", **TINY), seed=7).eval()
    x = random_clip(1, 2, 3, 32, 32)
    expected = source(x)
    sd = {k: v.contiguous() for k, v in source.state_dict().items()}

    st_path = tmp_path / "w.safetensors"
    save_file(sd, str(st_path))
    pt_path = tmp_path / "w.pt"
    torch.save({"state_dict": _to_pytorchvideo_names(sd)}, pt_path)
    for path in (st_path, pt_path):
        target = build("resnet3d50", **TINY).eval()
        load_weights(target, path)
        assert torch.allclose(target(x), expected, atol=1e-6)

    # a Kinetics-style head (400 classes) fits only with skip_head=True
    head400 = dict(sd, **{"fc.weight": torch.zeros(400, 256), "fc.bias": torch.zeros(400)})
    k400 = tmp_path / "k400.pt"
    torch.save(head400, k400)
    target = build("resnet3d50", **TINY)
    with pytest.raises(InputError) as info:
        load_weights(target, k400)
    assert str(k400) in str(info.value) and "fc.weight" in str(info.value) and "shape" in str(info.value)
    load_weights(target, k400, skip_head=True)

    with pytest.raises(InputError, match="missing"):
        load_weights(build("resnet3d50", layers=(3, 4, 6, 4), **TINY), st_path)
    with pytest.raises(InputError, match="no such"):
        load_weights(target, tmp_path / "absent.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="cannot read"):
        load_weights(target, junk)

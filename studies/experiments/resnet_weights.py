"""Weights for the 3D ResNet-50 from a file (the video comparison's ``--resnet-weights``): this model's
own state dict, or pytorchvideo's ``create_resnet`` layout (e.g. Kinetics-400 weights)."""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors.torch import load_file
from torch import Tensor

from slipsense.errors import InputError
from slipsense.models.resnet3d import ResNet3D50


def load_weights(model: ResNet3D50, path: str | Path, skip_head: bool = False) -> None:
    """Load user-supplied weights into ``model``: a ``.safetensors`` file or a torch ``.pt``/``.pth`` state dict.

    Accepts the model's parameter names, pytorchvideo ``create_resnet`` names (``blocks.0.conv``,
    ``blocks.1.res_blocks.0.branch2.conv_a``, ..., ``blocks.5.proj``) and a dict wrapping the state
    dict under ``"state_dict"`` or ``"model"``. ``skip_head=True`` keeps the model's ``fc`` (to
    fine-tune Kinetics-400 weights for 2 classes). Raises :class:`InputError` naming the file on an
    unreadable file or when names or shapes do not fit.
    """
    path = Path(path)
    sd = _read_state_dict(path)
    sd = {_rename_pytorchvideo_key(k): v for k, v in sd.items()}
    sd = {k: v for k, v in sd.items() if not k.endswith("num_batches_tracked")}
    own = {k: v for k, v in model.state_dict().items() if not k.endswith("num_batches_tracked")}
    if skip_head:
        sd = {k: v for k, v in sd.items() if not k.startswith("fc.")}
        own = {k: v for k, v in own.items() if not k.startswith("fc.")}
    missing = sorted(set(own) - set(sd))
    unexpected = sorted(set(sd) - set(own))
    wrong = [
        f"{k} {tuple(sd[k].shape)} != {tuple(own[k].shape)}" for k in own if k in sd and sd[k].shape != own[k].shape
    ]
    problems = []
    if missing:
        problems.append(f"{len(missing)} missing (e.g. {', '.join(missing[:3])})")
    if unexpected:
        problems.append(f"{len(unexpected)} unexpected (e.g. {', '.join(unexpected[:3])})")
    if wrong:
        problems.append(f"{len(wrong)} of the wrong shape (e.g. {'; '.join(wrong[:2])})")
    if problems:
        raise InputError(path, f"weights do not fit resnet3d50 {_short_config(model)}: " + ", ".join(problems))
    model.load_state_dict(sd, strict=not skip_head)


def _short_config(model: ResNet3D50) -> str:
    c = model.config()
    return (
        f"(layers={c['layers']}, width={c['width']}, stem_kernel={c['stem_kernel']}, "
        f"temporal_kernels={c['temporal_kernels']}, num_classes={c['num_classes']})"
    )


def _read_state_dict(path: Path) -> dict[str, Tensor]:
    if not path.is_file():
        raise InputError(path, "no such weights file")
    try:
        if path.suffix == ".safetensors":
            sd = load_file(str(path))
        else:
            sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any reader failure is a bad file for the user
        first_line = str(exc).splitlines()[0] if str(exc) else ""
        raise InputError(path, f"cannot read weights ({type(exc).__name__}: {first_line})") from None
    for wrapper in ("state_dict", "model"):
        if isinstance(sd, dict) and isinstance(sd.get(wrapper), dict):
            sd = sd[wrapper]
    if not isinstance(sd, dict) or not all(isinstance(k, str) and isinstance(v, Tensor) for k, v in sd.items()):
        raise InputError(path, "not a state dict (a mapping of parameter names to tensors)")
    return sd


_PTV_BLOCK = {
    "conv_a": "conv_a",
    "norm_a": "bn_a",
    "conv_b": "conv_b",
    "norm_b": "bn_b",
    "conv_c": "conv_c",
    "norm_c": "bn_c",
}


def _rename_pytorchvideo_key(key: str) -> str:
    """pytorchvideo ``create_resnet`` state-dict names -> ResNet3D50's (other names pass unchanged)."""
    parts = key.split(".")
    if parts[0] != "blocks" or len(parts) < 3:
        return key
    if parts[1] == "0" and parts[2] in ("conv", "norm"):  # stem
        return ".".join(["stem", "conv" if parts[2] == "conv" else "bn", *parts[3:]])
    if parts[2] == "proj":  # head
        return ".".join(["fc", *parts[3:]])
    if parts[2] == "res_blocks" and len(parts) >= 6:
        stage, block, name = int(parts[1]) - 1, parts[3], parts[4]
        if name == "branch1_conv":
            new, rest = "shortcut_conv", parts[5:]
        elif name == "branch1_norm":
            new, rest = "shortcut_bn", parts[5:]
        elif name == "branch2" and parts[5] in _PTV_BLOCK:
            new, rest = _PTV_BLOCK[parts[5]], parts[6:]
        else:
            return key
        return ".".join(["stages", str(stage), block, new, *rest])
    return key

"""3D ResNet-50 ("VideoResNet50" of the GelSight incipient-slip study), the study's baseline.

The study built it with ``pytorchvideo.models.resnet.create_resnet(input_channel=3, model_depth=50,
model_num_class=2, norm=BatchNorm3d, activation=ReLU)`` and reports 31,657,410 parameters. That is the
layout written here with the defaults (and exactly that count)::

    video (B, T, 3, H, W) BGR [0, 1] -> RGB, (x - mean) / std -> (B, 3, T, H, W)
    stem:  Conv3d 3->64, kernel 3x7x7, stride 1x2x2, BN, ReLU, MaxPool 1x3x3 stride 1x2x2   (B, 64, T, H/4, W/4)
    4 stages of bottleneck blocks, [3, 4, 6, 3] blocks, inner width 64 * 2^i, output 4x inner:
        conv_a  kernel kt x1x1 (kt = 1, 1, 3, 3 for the four stages), BN, ReLU
        conv_b  kernel 1x3x3, stride 1x2x2 in the first block of stages 2-4, BN, ReLU
        conv_c  kernel 1x1x1, BN;  + shortcut (1x1x1 conv + BN where the shape changes);  ReLU
                                                                                            (B, 2048, T, H/32, W/32)
    head:  global average pool -> dropout 0.5 -> Linear(2048, 2)                            (B, 2)

Temporal stride is 1 everywhere, so any number of frames works. (This is the "Slow" pathway
design: temporal kernels only in the last two stages; pytorchvideo's hub ``slow_r50`` is the same
with a 1x7x7 stem, 31,638,594 parameters for 2 classes.) One difference from pytorchvideo's head:
pytorchvideo averages 4x7x7 windows, projects, then averages the projections; here the features are
averaged over the whole clip before the Linear — the same for inputs whose final map is 4x7x7
(8 x 224 x 224 clips), a plain global average otherwise.

``width`` scales every channel count (``width=8`` gives a tiny model for tests); ``stem_kernel`` and
``temporal_kernels`` pick the other layouts above.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any, Sequence

import torch
import torch.nn.functional as F
from einops import rearrange
from torch import Tensor, nn

from slipsense.errors import ConfigError, InputError
from slipsense.models.base import VideoModel, register

#: Parameter count the study reports for its VideoResNet50 with 2 classes (the default config here).
PAPER_PARAMETERS = 31_657_410


class Bottleneck(nn.Module):
    """conv_a (kt x 1 x 1) -> conv_b (1 x 3 x 3, spatial stride) -> conv_c (1 x 1 x 1), each with BN; + shortcut.

    (B, dim_in, T, H, W) -> (B, dim_out, T, H / stride, W / stride)
    """

    def __init__(self, dim_in: int, dim_inner: int, dim_out: int, temporal_kernel: int, stride: int):
        super().__init__()
        kt = temporal_kernel
        self.conv_a = nn.Conv3d(dim_in, dim_inner, (kt, 1, 1), padding=(kt // 2, 0, 0), bias=False)
        self.bn_a = nn.BatchNorm3d(dim_inner)
        self.conv_b = nn.Conv3d(
            dim_inner, dim_inner, (1, 3, 3), stride=(1, stride, stride), padding=(0, 1, 1), bias=False
        )
        self.bn_b = nn.BatchNorm3d(dim_inner)
        self.conv_c = nn.Conv3d(dim_inner, dim_out, 1, bias=False)
        self.bn_c = nn.BatchNorm3d(dim_out)
        if dim_in != dim_out or stride != 1:
            self.shortcut_conv = nn.Conv3d(dim_in, dim_out, 1, stride=(1, stride, stride), bias=False)
            self.shortcut_bn = nn.BatchNorm3d(dim_out)
        else:
            self.shortcut_conv = self.shortcut_bn = None

    def forward(self, x: Tensor) -> Tensor:
        shortcut = x if self.shortcut_conv is None else self.shortcut_bn(self.shortcut_conv(x))
        y = F.relu(self.bn_a(self.conv_a(x)))
        y = F.relu(self.bn_b(self.conv_b(y)))
        y = self.bn_c(self.conv_c(y))
        return F.relu(y + shortcut)


def _triple(value: int | Sequence[int], name: str) -> tuple[int, int, int]:
    if isinstance(value, int):
        value = (value, value, value)
    value = tuple(int(v) for v in value)
    if len(value) != 3 or any(v < 1 or v % 2 == 0 for v in value):
        raise ConfigError(f"resnet3d50: {name} must be 3 odd positive integers (t, h, w), got {value!r}")
    return value


@register("resnet3d50")
class ResNet3D50(VideoModel):
    """Bottleneck 3D ResNet for ``(B, T, 3, H, W)`` BGR clips in [0, 1]; logits ``(B, num_classes)``, class 1 = slip.

    Keyword config: ``layers=(3, 4, 6, 3)``, ``width=64``, ``stem_kernel=(3, 7, 7)``,
    ``temporal_kernels=(1, 1, 3, 3)`` (conv_a's temporal size per stage), ``num_classes=2``,
    ``dropout=0.5``, ``channels=3``, ``frames=None`` (any; an int makes :meth:`check_input` insist),
    ``bgr_to_rgb=True`` and ``mean=(0.45,)*3``, ``std=(0.225,)*3`` (the Kinetics normalisation that
    pytorchvideo's pretrained weights expect, applied inside the model).
    """

    paper_training = dict(epochs=10, batch_size=8, lr=1e-3, weight_decay=1e-4, step_size=30, gamma=0.1)

    @classmethod
    def small_config(cls) -> dict:
        return {"layers": [1, 1, 1, 1], "width": 8, "frames": 4}

    def __init__(
        self,
        *,
        layers: Sequence[int] = (3, 4, 6, 3),
        width: int = 64,
        stem_kernel: int | Sequence[int] = (3, 7, 7),
        temporal_kernels: Sequence[int] = (1, 1, 3, 3),
        num_classes: int = 2,
        dropout: float = 0.5,
        channels: int = 3,
        frames: int | None = None,
        bgr_to_rgb: bool = True,
        mean: Sequence[float] = (0.45, 0.45, 0.45),
        std: Sequence[float] = (0.225, 0.225, 0.225),
    ):
        super().__init__()
        layers = [int(n) for n in layers]
        temporal_kernels = [int(k) for k in temporal_kernels]
        stem_kernel = _triple(stem_kernel, "stem_kernel")
        if not layers or any(n < 1 for n in layers):
            raise ConfigError(f"resnet3d50: layers must be positive block counts, got {layers!r}")
        if len(temporal_kernels) != len(layers) or any(k < 1 or k % 2 == 0 for k in temporal_kernels):
            raise ConfigError(
                f"resnet3d50: temporal_kernels must be {len(layers)} odd positive integers, got {temporal_kernels!r}"
            )
        for key, value in dict(width=width, num_classes=num_classes, channels=channels).items():
            if not isinstance(value, int) or value < 1:
                raise ConfigError(f"resnet3d50: {key} must be a positive integer, got {value!r}")
        if frames is not None and (not isinstance(frames, int) or frames < 1):
            raise ConfigError(f"resnet3d50: frames must be None or a positive integer, got {frames!r}")
        if not 0.0 <= float(dropout) < 1.0:
            raise ConfigError(f"resnet3d50: dropout must be in [0, 1), got {dropout!r}")
        mean, std = [float(m) for m in mean], [float(s) for s in std]
        if len(mean) != channels or len(std) != channels or any(s <= 0 for s in std):
            raise ConfigError(f"resnet3d50: mean and std need {channels} values (std > 0)")
        if bgr_to_rgb and channels != 3:
            raise ConfigError("resnet3d50: bgr_to_rgb needs channels=3")

        self.channels, self.frames, self.bgr_to_rgb = channels, frames, bool(bgr_to_rgb)
        self._config = dict(
            layers=layers, width=width, stem_kernel=list(stem_kernel), temporal_kernels=temporal_kernels
        )
        self._config.update(num_classes=num_classes, dropout=float(dropout), channels=channels, frames=frames)
        self._config.update(bgr_to_rgb=bool(bgr_to_rgb), mean=mean, std=std)
        self.register_buffer("mean", torch.tensor(mean).view(1, channels, 1, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std).view(1, channels, 1, 1, 1), persistent=False)

        kt, kh, kw = stem_kernel
        conv = nn.Conv3d(
            channels, width, stem_kernel, stride=(1, 2, 2), padding=(kt // 2, kh // 2, kw // 2), bias=False
        )
        pool = nn.MaxPool3d((1, 3, 3), stride=(1, 2, 2), padding=(0, 1, 1))
        self.stem = nn.Sequential(
            OrderedDict(conv=conv, bn=nn.BatchNorm3d(width), relu=nn.ReLU(inplace=True), pool=pool)
        )

        stages, dim_in = [], width
        for i, (blocks, kt) in enumerate(zip(layers, temporal_kernels)):
            inner = width * 2**i  # output 4x inner; spatial stride 2 in the first block of stages 2-4
            stage = [Bottleneck(dim_in, inner, 4 * inner, kt, 1 if i == 0 else 2)]
            stage += [Bottleneck(4 * inner, inner, 4 * inner, kt, 1) for _ in range(blocks - 1)]
            stages.append(nn.Sequential(*stage))
            dim_in = 4 * inner
        self.stages = nn.Sequential(*stages)
        self.dropout = nn.Dropout(dropout)
        self.fc = nn.Linear(dim_in, num_classes)
        self._init_weights()

    def _init_weights(self) -> None:
        """Kaiming-normal convs, BN 1/0 (0 for each block's last BN, so blocks start as identities), fc N(0, 0.01)."""
        for m in self.modules():
            if isinstance(m, nn.Conv3d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm3d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        for m in self.modules():
            if isinstance(m, Bottleneck):
                nn.init.zeros_(m.bn_c.weight)
        nn.init.normal_(self.fc.weight, std=0.01)
        nn.init.zeros_(self.fc.bias)

    def _check_shape(self, x: Any) -> None:
        if not isinstance(x, Tensor):
            raise InputError(None, f"video must be a torch.Tensor, got {type(x).__name__}")
        t = "T" if self.frames is None else str(self.frames)
        ok = x.dim() == 5 and min(x.shape) >= 1 and x.shape[2] == self.channels
        if ok and self.frames is not None:
            ok = x.shape[1] == self.frames
        if not ok:
            raise InputError(
                None,
                f"video must have shape (B, {t}, {self.channels}, H, W) "
                f"(batch, frames, channels, height, width), got {tuple(x.shape)}",
            )

    def features(self, x: Tensor) -> Tensor:
        """(B, T, C, H, W) -> (B, 2048 * width / 64) clip features (before dropout and the Linear)."""
        x = rearrange(x, "b t c h w -> b c t h w")
        if self.bgr_to_rgb:
            x = x.flip(1)
        x = (x - self.mean) / self.std
        x = self.stages(self.stem(x))
        return x.mean(dim=(2, 3, 4))

    def forward(self, x: Tensor) -> Tensor:
        """(B, T, C, H, W) in [0, 1], BGR -> logits (B, num_classes). Checks the shape only."""
        self._check_shape(x)
        return self.fc(self.dropout(self.features(x)))

"""Heat maps of what a trained model looks at, drawn over the sensor (ViViT paper Fig. 6 style
attention, STNet paper Fig. 8 style marker relevance over the displacement field)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from slipsense.errors import InputError


def video_attention_figure(model, clip: np.ndarray, out: str | Path, title: str = "") -> Path:
    """ViViT spatial CLS attention (rollout, heads averaged) over each frame of ``clip``.

    ``clip``: uint8 ``(T, H, W, 3)`` BGR at the model's image size.
    """
    from slipsense.datasets import clip_to_tensor
    from slipsense.plots import _plt, save_figure

    if not hasattr(model, "cls_attention_map"):
        raise InputError(None, f"model {model.model_name!r} has no spatial attention to draw")
    x = clip_to_tensor(clip)[None]
    with torch.no_grad():
        att = model.cls_attention_map(x)[0].numpy()  # (T, Hp, Wp)
        p = torch.softmax(model(x), -1)[0, 1].item()
    plt = _plt()
    T = clip.shape[0]
    fig, axes = plt.subplots(1, T, figsize=(2.6 * T, 2.4))
    h, w = clip.shape[1:3]
    for t, ax in enumerate(np.atleast_1d(axes)):
        ax.imshow(clip[t, :, :, ::-1])
        ax.imshow(att[t], cmap="inferno", alpha=0.5, extent=(0, w, h, 0), interpolation="bilinear")
        ax.set_title(f"frame {t + 1}/{T}", fontsize=9)
        ax.axis("off")
    fig.suptitle(f"{title}  p(slip) = {p:.2f}")
    return save_figure(fig, out)


def marker_saliency_figure(
    model, window: np.ndarray, rest_xy: np.ndarray, out: str | Path, title: str = "", baseline: str = "rest"
) -> Path:
    """STNet/TemNet marker relevance for the slip class over the window's displacement field.

    ``window``: float32 ``(T, M, 3)`` marker positions (mm); ``rest_xy``: ``(M, 2)`` where each marker
    is drawn (its rest position). ``baseline``: what the relevance and the arrows measure from
    (:meth:`~slipsense.models.stnet.STNet.marker_saliency`; ``"rest"``: the gel at rest of a centred
    model, else the window's first frame).
    """
    from slipsense.plots import _plt, save_figure

    device = next(model.parameters()).device
    x = torch.from_numpy(np.ascontiguousarray(window, np.float32))[None].to(device)
    sal = model.marker_saliency(x, baseline=baseline)[0].detach().cpu().numpy()
    with torch.no_grad():
        p = torch.softmax(model(x), -1)[0, 1].item()
    from_rest = baseline == "rest" and getattr(model, "centred", False)
    disp = window[-1] - (model.reference.cpu().numpy() if from_rest else window[0])
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 4.4))
    sc = ax.scatter(rest_xy[:, 0], rest_xy[:, 1], c=sal, cmap="inferno", s=40)
    ax.quiver(
        rest_xy[:, 0],
        rest_xy[:, 1],
        disp[:, 0],
        disp[:, 1],
        angles="xy",
        scale_units="xy",
        scale=0.25,
        color="tab:cyan",
        width=0.004,
    )
    fig.colorbar(sc, ax=ax, label="relevance for slip")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    since = "from rest" if from_rest else "over the window"
    ax.set_title(f"{title}  p(slip) = {p:.2f}\narrows: displacement {since} (x4)", fontsize=9)
    return save_figure(fig, out)


def relevance_in_contact(model, x: np.ndarray, rest: np.ndarray, depth_mm: float = 0.05, batch: int = 64) -> dict:
    """Does the model look where the object touches (STNet paper, Fig. 8)? For marker windows ``x``
    ``(N, T, M, 3)`` (mm, indentation towards negative z) and the gel at ``rest`` ``(M, 3)``: the
    markers in contact are those whose last frame lies more than ``depth_mm`` below rest. Returns
    the mean share of each window's relevance (:meth:`marker_saliency`, baseline ``"rest"``) on its
    contact markers, the mean share of markers in contact, their ratio (1: no concentration) and
    how many windows had a contact."""
    device = next(model.parameters()).device
    shares, areas = [], []
    for a in range(0, len(x), batch):
        xb = np.ascontiguousarray(x[a : a + batch], np.float32)
        contact = (xb[:, -1, :, 2] - rest[None, :, 2]) < -depth_mm  # (b, M)
        rel = model.marker_saliency(torch.from_numpy(xb).to(device), baseline="rest").detach().cpu().numpy()
        keep = contact.any(axis=1) & (rel.sum(axis=1) > 0)
        shares += ((rel * contact).sum(axis=1)[keep] / rel.sum(axis=1)[keep]).tolist()
        areas += contact.mean(axis=1)[keep].tolist()
    if not shares:
        return {
            "relevance_in_contact": float("nan"),
            "markers_in_contact": float("nan"),
            "concentration": float("nan"),
            "windows": 0,
        }
    share, area = float(np.mean(shares)), float(np.mean(areas))
    return {
        "relevance_in_contact": share,
        "markers_in_contact": area,
        "concentration": share / area,
        "windows": len(shares),
    }

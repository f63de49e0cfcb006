"""Simulated binocular visuo-tactile sensor: 3D marker clouds for four motion patterns.

Reproduces the setting of the STNet paper (section III.A): a 22 x 21 mm elastomer with 23 x 24
markers (552 markers, 1656 values per frame) filmed at 20 Hz while one of six objects (cherry
tomato, earphone, screw, tape, pen, bottle) is stationary, pressed, rolled or slipped on it.
Samples are windows of 12 consecutive frames, stride 1. See ``studies/docs/simulator.md`` for the model
and pictures.

Frames and units
----------------
Positions are in the *gel frame*, in mm: origin on the rest contact surface at the gel centre,
``x`` along the 22 mm side, ``y`` along the 21 mm side, ``z`` along the surface normal pointing
away from the cameras, towards the object. At rest every marker has ``z = 0``; **pressing moves
markers towards the cameras, so indentation is negative z.** (The camera frame of
:mod:`studies.stnet.stereo` has the same axes, shifted by ``h_v``.) Markers are ordered row
by row: index ``iy * markers_x + ix``, ``x`` fastest.

Labels: the paper labels by motion pattern, so with ``label_rule="pattern"`` every window of a
slipping sequence is slip (1) and every other window is 0. Simulated slipping sequences start with
the tangential load already rising (partial slip at the contact edge from frame 0), so every
slipping window contains slip. ``label_rule="gross_slip"`` labels a slipping window 1 only if it
reaches the gross-slip frame.

Modules
-------
:mod:`studies.stnet.sim_model` holds :class:`SimConfig`, the marker grid, the elastomer's
response kernels and the objects; :mod:`studies.stnet.sim_sequence` moves the objects and
computes each frame (:func:`simulate_sequence`; its docstring describes the deformation model);
:mod:`slipsense.sensors.marker_npz` holds :class:`MarkerDataset` and the ``.npz`` format. This
module re-exports their public names and holds :func:`make_dataset`, which cuts and labels the
windows, :func:`save_dataset`, which writes them, and the figures.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from slipsense.atomic import write_with
from slipsense.progress import progress_bar
from slipsense.sensors.marker_npz import MarkerDataset, load_marker_npz
from slipsense.marker_sequences import save_marker_npz
from studies.stnet.sim_model import OBJECTS, PATTERNS, SLIP_PATTERN, SimConfig, displacement_field, rest_grid
from studies.stnet.sim_sequence import simulate_sequence

__all__ = [
    "FIGURE_OBJECTS",
    "OBJECTS",
    "PATTERNS",
    "SLIP_PATTERN",
    "MarkerDataset",
    "SimConfig",
    "displacement_field",
    "load_marker_npz",
    "main",
    "make_dataset",
    "plot_patterns",
    "rest_grid",
    "save_dataset",
    "simulate_sequence",
]


# ----------------------------------------------------------------------------- datasets


def _labels(pattern: str, gross: int, starts: np.ndarray, cfg: SimConfig) -> np.ndarray:
    if pattern != SLIP_PATTERN:
        return np.zeros(len(starts), np.int64)
    if cfg.label_rule == "pattern":
        return np.ones(len(starts), np.int64)
    last = starts + cfg.window - 1
    return ((gross >= 0) & (last >= gross)).astype(np.int64)


def make_dataset(cfg: SimConfig, progress: bool = True) -> MarkerDataset:
    """Simulate ``n_sequences`` per (object, pattern) and cut windows of ``window`` frames.

    Returns a :class:`MarkerDataset` with ``x (N, window, M, 3)`` float32; labels follow
    ``cfg.label_rule``; ``groups`` is the sequence id. Each sequence uses its own random stream
    ``default_rng([seed, object index, pattern index, k])``.
    """
    cfg.validate()
    jobs = [(o, p, k) for o in cfg.objects for p in cfg.patterns for k in range(cfg.n_sequences)]
    it = progress_bar(jobs, progress, "simulate")
    xs, ys, gs, ps, os_ = [], [], [], [], []
    for seq_id, (o, p, k) in enumerate(it):
        rng = np.random.default_rng([cfg.seed, OBJECTS.index(o), PATTERNS.index(p), k])
        seq, info = simulate_sequence(o, p, rng, cfg, return_info=True)
        starts = np.arange(0, len(seq) - cfg.window + 1, cfg.stride)
        win = np.lib.stride_tricks.sliding_window_view(seq, cfg.window, axis=0)  # (n, M, 3, W)
        xs.append(np.ascontiguousarray(win[starts].transpose(0, 3, 1, 2)))
        ys.append(_labels(p, info["gross_slip_frame"], starts, cfg))
        gs.append(np.full(len(starts), seq_id, np.int64))
        ps.append(np.full(len(starts), PATTERNS.index(p), np.int64))
        os_.append(np.full(len(starts), OBJECTS.index(o), np.int64))
    M = cfg.n_markers
    if not xs:
        empty = np.zeros(0, np.int64)
        return MarkerDataset(np.zeros((0, cfg.window, M, 3), np.float32), empty, empty, empty, empty, fps=cfg.fps)
    return MarkerDataset(
        np.concatenate(xs),
        np.concatenate(ys),
        np.concatenate(gs),
        np.concatenate(ps),
        np.concatenate(os_),
        fps=float(cfg.fps),
    )


def save_dataset(ds: MarkerDataset, path: str | Path) -> Path:
    """Write ``ds`` atomically as the documented marker ``.npz`` (see :func:`load_marker_npz`)."""
    arrays: dict[str, np.ndarray] = {
        "x": np.asarray(ds.x, np.float32),
        "groups": np.asarray(ds.groups, np.int64),
        "fps": np.asarray(ds.fps, np.float64),
    }
    if ds.y is not None:
        arrays["y"] = np.asarray(ds.y, np.int64)
    if ds.pattern is not None:
        arrays["pattern"] = np.asarray(ds.pattern, np.int64)
        arrays["pattern_names"] = np.asarray(ds.pattern_names, dtype=str)
    if ds.object is not None:
        arrays["object"] = np.asarray(ds.object, np.int64)
        arrays["object_names"] = np.asarray(ds.object_names, dtype=str)
    return save_marker_npz(arrays, path)


# ----------------------------------------------------------------------------- figures

#: Object shown for each pattern in the figures (small contacts make the lobes visible).
FIGURE_OBJECTS = {
    "stationary": "tape",
    "pressing": "cherry_tomato",
    "rolling": "cherry_tomato",
    "slipping": "cherry_tomato",
}


def _draw_field(ax, X: np.ndarray, disp: np.ndarray, shape: tuple[int, int], vlim: float, arrow_scale: float):
    """z displacement as a coloured background, xy displacement as arrows (magnified)."""
    ny, nx = shape
    mesh = ax.pcolormesh(
        X[:, 0].reshape(ny, nx),
        X[:, 1].reshape(ny, nx),
        disp[:, 2].reshape(ny, nx),
        cmap="RdBu_r",
        vmin=-vlim,
        vmax=vlim,
        shading="nearest",
        alpha=0.8,
    )
    ax.quiver(
        X[:, 0],
        X[:, 1],
        disp[:, 0] * arrow_scale,
        disp[:, 1] * arrow_scale,
        angles="xy",
        scale_units="xy",
        scale=1.0,
        width=0.005,
        headwidth=3.5,
        color="k",
    )
    ax.set_aspect("equal")
    ax.set_xlim(X[:, 0].min() - 0.6, X[:, 0].max() + 0.6)
    ax.set_ylim(X[:, 1].min() - 0.6, X[:, 1].max() + 0.6)
    return mesh


def plot_patterns(cfg: SimConfig, out_dir: str | Path, frames: int = 4, arrow_scale: float = 4.0) -> list[Path]:
    """One figure per pattern (``sim_<pattern>.png``) plus ``sim_objects.png``; returns the paths.

    Each pattern figure shows ``frames`` time points of one simulated sequence in a 2-column grid:
    background colour = z displacement (mm; blue = towards the cameras = indentation), arrows = xy
    displacement magnified ``arrow_scale`` times, red arrow = motion direction, green outline =
    contact. ``sim_objects.png`` shows the static footprint of each object. Written atomically.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    X = rest_grid(cfg)
    written: list[Path] = []
    shape = (cfg.markers_y, cfg.markers_x)
    gx_, gy_ = X[:, 0].reshape(shape), X[:, 1].reshape(shape)
    for pi, pattern in enumerate(PATTERNS):
        obj = FIGURE_OBJECTS[pattern]
        rng = np.random.default_rng([cfg.seed, 99, pi])
        seq, info = simulate_sequence(obj, pattern, rng, cfg, return_info=True, allow_empty=False)
        disp = displacement_field(seq, X)
        T = len(seq)
        idx = np.linspace(0, T - 1, frames).round().astype(int)
        vlim = max(float(np.abs(disp[..., 2]).max()), 0.05)
        ncol = 2
        nrow = int(math.ceil(frames / ncol))
        fig, axes = plt.subplots(
            nrow, ncol, figsize=(5.2 * ncol + 1.0, 5.0 * nrow), constrained_layout=True, squeeze=False
        )
        for ax, ti in zip(axes.ravel(), idx):
            mesh = _draw_field(ax, X, disp[ti], shape, vlim, arrow_scale)
            mask = info["contact"][ti].reshape(shape).astype(float)
            if mask.any() and not mask.all():
                ax.contour(gx_, gy_, mask, levels=[0.5], colors="limegreen", linewidths=1.5)
            if pattern in ("rolling", "slipping"):
                c = info["centre"][ti]
                e = info["direction"] * 3.0
                ax.annotate(
                    "",
                    xy=(c[0] + e[0], c[1] + e[1]),
                    xytext=(c[0], c[1]),
                    arrowprops=dict(arrowstyle="-|>", color="red", lw=2.5),
                )
            title = f"t = {ti / cfg.fps:.2f} s"
            if pattern == "slipping":
                g = info["gross_slip_frame"]
                stick = info["stick"][ti].sum() / max(info["contact"][ti].sum(), 1)
                title += (" gross slip" if 0 <= g <= ti else " partial slip") + f", stick {100 * stick:.0f}%"
            ax.set_title(title, fontsize=11)
            ax.set_xlabel("x (mm)")
            ax.set_ylabel("y (mm)")
        for ax in axes.ravel()[len(idx) :]:
            ax.set_visible(False)
        fig.colorbar(mesh, ax=axes, label="z displacement (mm)", shrink=0.85)
        fig.suptitle(f"{pattern}: {obj.replace('_', ' ')} (arrows: xy displacement x{arrow_scale:g})")
        path = out_dir / f"sim_{pattern}.png"
        write_with(path, lambda tmp: fig.savefig(tmp, dpi=72))
        plt.close(fig)
        written.append(path)

    fig, axes = plt.subplots(2, 3, figsize=(12, 7.6), constrained_layout=True)
    vlim = 0.0
    fields_ = []
    for oi, obj in enumerate(OBJECTS):
        rng = np.random.default_rng([cfg.seed, 98, oi])
        seq = simulate_sequence(obj, "stationary", rng, cfg, allow_empty=False)
        fields_.append(displacement_field(seq, X)[-1])
        vlim = max(vlim, float(np.abs(fields_[-1][:, 2]).max()))
    for ax, obj, disp in zip(axes.ravel(), OBJECTS, fields_):
        mesh = _draw_field(ax, X, disp, shape, vlim, arrow_scale)
        ax.set_title(obj.replace("_", " "))
    fig.colorbar(mesh, ax=axes, label="z displacement (mm)", shrink=0.8)
    fig.suptitle(f"static contact of each object (arrows x{arrow_scale:g})")
    path = out_dir / "sim_objects.png"
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=72))
    plt.close(fig)
    written.append(path)
    return written


def main(argv: list[str] | None = None) -> None:
    """``python -m studies.stnet.simulator --figures docs/img [--seed N]`` regenerates the figures."""
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figures", type=Path, default=Path("docs/img"), help="folder for sim_*.png")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    for p in plot_patterns(SimConfig(seed=args.seed), args.figures):
        print(p)


if __name__ == "__main__":
    main()

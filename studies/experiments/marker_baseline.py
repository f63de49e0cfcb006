"""Experiment ``marker-baseline``: can slip be told from stationary, pressing and rolling in the simulated
marker windows at all? A non-deep baseline on the very windows and split of experiment ``stnet``.

Each window ``(T, M, 3)`` (mm) becomes a few dozen numbers describing its displacement field (the
last frame against the first, and frame to frame): how far markers move and how many, how coherent
the motion is (a translation of the whole contact against the two opposite lobes of rolling), its
divergence and curl on the marker grid, the asymmetry between the leading and trailing sides of the
contact along the motion (the STNet paper's Fig. 6: slipping loads the tension side more), how deep
and wide the contact is and how that changes. Gradient boosting (scikit-learn) learns slip against
the rest on the training sequences; it is scored on the held-out sequences as STNet is. If it
separates the classes near perfectly, a network that does not has a training problem; if it does
not, the simulator's classes overlap.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from slipsense.errors import ConfigError

FEATURES = (
    "disp_mean",
    "disp_max",
    "disp_p90",
    "disp_std",
    "moving_fraction",
    "coherence",
    "net_shear",
    "div_mean",
    "div_abs",
    "curl_mean",
    "curl_abs",
    "asymmetry",
    "lead_trail_ratio",
    "speed_mean",
    "speed_max",
    "speed_last_third",
    "speed_first_third",
    "speed_cv",
    "depth",
    "depth_change",
    "contact_fraction",
    "contact_change",
    "contact_disp_mean",
    "outside_disp_mean",
)


#: features of the shear against the rest positions (where those are known: the simulator)
REST_FEATURES = (
    "rest_shear_mean",
    "rest_shear_max",
    "rest_coherence",
    "rest_asymmetry",
    "rest_curl_abs",
    "rest_shear_change",
)


def window_features(x: np.ndarray, grid: tuple[int, int], rest: np.ndarray | None = None) -> np.ndarray:
    """``(N, T, M, 3)`` marker windows (mm, markers row by row on a ``grid = (rows, cols)`` grid) ->
    ``(N, len(FEATURES))`` float64 features (see the module notes); with the markers' ``rest``
    positions ``(M, 3)`` also :data:`REST_FEATURES` (the gel's standing shear: steady sliding keeps
    the gel sheared while the markers stop moving within the window)."""
    x = np.asarray(x, dtype=np.float64)
    n, t, m, _ = x.shape
    rows, cols = grid
    if rows * cols != m:
        raise ConfigError(f"a {rows} x {cols} marker grid holds {rows * cols} markers, the windows {m}")
    d = x[:, -1] - x[:, 0]  # (N, M, 3)
    tan = d[..., :2]
    mag = np.linalg.norm(tan, axis=-1)  # (N, M)
    peak = mag.max(axis=1, keepdims=True) + 1e-9
    moving = (mag > 0.3 * peak).mean(axis=1)
    mean_vec = tan.mean(axis=1)  # (N, 2)
    net = np.linalg.norm(mean_vec, axis=-1)
    coherence = net / (mag.mean(axis=1) + 1e-9)
    field = tan.reshape(n, rows, cols, 2)
    dux_dx = np.gradient(field[..., 0], axis=2)
    duy_dy = np.gradient(field[..., 1], axis=1)
    duy_dx = np.gradient(field[..., 1], axis=2)
    dux_dy = np.gradient(field[..., 0], axis=1)
    div = (dux_dx + duy_dy).reshape(n, -1)
    curl = (duy_dx - dux_dy).reshape(n, -1)
    # contact: the markers pressed in (z below the window's own deepest tenth)
    z_last = x[:, -1, :, 2]
    depth = -z_last.min(axis=1)
    contact = z_last < -0.25 * (depth[:, None] + 1e-9)
    z_first = x[:, 0, :, 2]
    depth_first = -z_first.min(axis=1)
    contact_first = z_first < -0.25 * (depth_first[:, None] + 1e-9)
    pos = x[:, -1, :, :2]
    weight = np.where(contact, 1.0, 0.0)
    centre = (pos * weight[..., None]).sum(axis=1) / (weight.sum(axis=1, keepdims=True) + 1e-9)
    direction = mean_vec / (net[:, None] + 1e-9)
    along = ((pos - centre[:, None]) * direction[:, None]).sum(axis=-1)  # (N, M): ahead (>0) or behind
    ahead = (mag * (along > 0)).sum(axis=1)
    behind = (mag * (along < 0)).sum(axis=1)
    asymmetry = (ahead - behind) / (ahead + behind + 1e-9)
    ratio = np.log((ahead + 1e-6) / (behind + 1e-6))
    speed = np.linalg.norm(np.diff(x[..., :2], axis=1), axis=-1).mean(axis=2)  # (N, T-1) mean marker speed
    third = max(1, (t - 1) // 3)
    in_contact = (mag * contact).sum(axis=1) / (contact.sum(axis=1) + 1e-9)
    outside = (mag * ~contact).sum(axis=1) / ((~contact).sum(axis=1) + 1e-9)
    cols_out = [
        mag.mean(axis=1),
        mag.max(axis=1),
        np.percentile(mag, 90, axis=1),
        mag.std(axis=1),
        moving,
        coherence,
        net,
        div.mean(axis=1),
        np.abs(div).mean(axis=1),
        curl.mean(axis=1),
        np.abs(curl).mean(axis=1),
        asymmetry,
        ratio,
        speed.mean(axis=1),
        speed.max(axis=1),
        speed[:, -third:].mean(axis=1),
        speed[:, :third].mean(axis=1),
        speed.std(axis=1) / (speed.mean(axis=1) + 1e-9),
        depth,
        depth - depth_first,
        contact.mean(axis=1),
        contact.mean(axis=1) - contact_first.mean(axis=1),
        in_contact,
        outside,
    ]
    if rest is not None:
        shear = (x[:, -1] - np.asarray(rest, dtype=np.float64)[None])[..., :2]
        smag = np.linalg.norm(shear, axis=-1)
        svec = (shear * weight[..., None]).sum(axis=1) / (weight.sum(axis=1, keepdims=True) + 1e-9)
        snet = np.linalg.norm(svec, axis=-1)
        sdir = svec / (snet[:, None] + 1e-9)
        salong = ((pos - centre[:, None]) * sdir[:, None]).sum(axis=-1)
        s_ahead, s_behind = (smag * (salong > 0)).sum(axis=1), (smag * (salong < 0)).sum(axis=1)
        sf = shear.reshape(n, rows, cols, 2)
        scurl = (np.gradient(sf[..., 1], axis=2) - np.gradient(sf[..., 0], axis=1)).reshape(n, -1)
        first = np.linalg.norm((x[:, 0] - np.asarray(rest)[None])[..., :2], axis=-1)
        cols_out += [
            (smag * contact).sum(axis=1) / (contact.sum(axis=1) + 1e-9),
            smag.max(axis=1),
            snet / ((smag * weight).sum(axis=1) / (weight.sum(axis=1) + 1e-9) + 1e-9),
            (s_ahead - s_behind) / (s_ahead + s_behind + 1e-9),
            np.abs(scurl).mean(axis=1),
            smag.mean(axis=1) - first.mean(axis=1),
        ]
    return np.stack(cols_out, axis=1)


def fit_and_score(
    x: np.ndarray,
    y: np.ndarray,
    train: np.ndarray,
    test: np.ndarray,
    grid: tuple[int, int],
    seed: int = 0,
    rest: np.ndarray | None = None,
) -> dict[str, Any]:
    """Gradient boosting on :func:`window_features` of the ``train`` windows, scored on ``test``:
    precision, recall, F1, accuracy (threshold 0.5), the predicted probabilities and the features'
    importance (drop in held-out F1 when one feature is shuffled)."""
    try:
        from sklearn.ensemble import HistGradientBoostingClassifier
    except ImportError:
        raise ConfigError("the marker baseline needs scikit-learn: pip install scikit-learn") from None
    from slipsense.measures.clips import metrics_from

    f = window_features(x, grid, rest)
    names = FEATURES + (REST_FEATURES if rest is not None else ())
    clf = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.1, random_state=seed)
    clf.fit(f[train], y[train])

    def score(features):
        return metrics_from(clf.predict_proba(features)[:, 1], y[test])

    base = score(f[test])
    rng = np.random.default_rng(seed)
    importance = {}
    for k, name in enumerate(names):
        shuffled = f[test].copy()
        shuffled[:, k] = rng.permutation(shuffled[:, k])
        importance[name] = base["f1"] - score(shuffled)["f1"]
    return {"metrics": base, "probability": clf.predict_proba(f[test])[:, 1], "importance": importance}


def run_marker_baseline(settings, sim_sequences: int | None = None, sim_overrides: dict[str, Any] | None = None):
    """The baseline on experiment ``stnet``'s simulated windows and split (sequences held out per
    motion pattern), twice: on the windows' own motion (what a model given each window relative to its
    first frame sees) and with the gel's standing shear against its rest positions added. A row for
    all held-out windows and one per motion pattern, for each."""
    from studies.experiments.report import Report
    from studies.experiments.stnet import simulated_dataset
    from studies.stnet.sim_model import rest_grid
    from studies.stnet.simulator import PATTERNS, SimConfig

    rep = Report("marker-baseline", settings)
    ds, tr, te, sim_info = simulated_dataset(settings, sim_sequences, sim_overrides)
    x, y, pattern = ds.x, ds.y, ds.pattern
    cfg = SimConfig(seed=settings.data_seed, n_sequences=sim_info["n_sequences"], **(sim_overrides or {}))
    grid = (cfg.markers_y, cfg.markers_x)
    rep.config.update(simulation=sim_info, n_train=len(tr), n_test=len(te), features=list(FEATURES + REST_FEATURES))
    rows, results = [], {}
    for inputs, rest in (("window motion", None), ("window motion + shear against rest", rest_grid(cfg))):
        res = results[inputs] = fit_and_score(x, y, tr, te, grid, seed=settings.seed, rest=rest)
        m, p = res["metrics"], res["probability"]
        rows.append(
            {
                "features": inputs,
                "windows": "held-out sequences, all patterns",
                "n": len(te),
                "slip": int(y[te].sum()),
                "precision": m["precision"],
                "recall": m["recall"],
                "f1": m["f1"],
                "accuracy": m["accuracy"],
            }
        )
        for k, name in enumerate(PATTERNS):
            sel = pattern[te] == k
            if sel.any():
                rows.append(
                    {
                        "features": inputs,
                        "windows": f"held-out {name}",
                        "n": int(sel.sum()),
                        "slip": int(y[te][sel].sum()),
                        "called slip": float((p[sel] >= 0.5).mean()),
                    }
                )
        top = sorted(res["importance"].items(), key=lambda kv: -kv[1])[:5]
        rep.notes.append(
            f"{inputs}: most important (held-out F1 lost when shuffled) " + ", ".join(f"{k} {v:.3f}" for k, v in top)
        )
    rep.notes.insert(
        0,
        "gradient boosting (scikit-learn HistGradientBoostingClassifier, 300 iterations) on displacement-field "
        "features per window; the windows and split of experiment stnet",
    )

    def figure(plt):
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
        for ax, (inputs, res) in zip(axes, results.items()):
            for k, name in enumerate(PATTERNS):
                sel = pattern[te] == k
                if sel.any():
                    ax.hist(res["probability"][sel], bins=20, range=(0, 1), alpha=0.5, label=name)
            ax.set_title(f"{inputs}: F1 {res['metrics']['f1']:.3f}", fontsize=9)
            ax.set_xlabel("P(slip), held-out windows")
        axes[0].set_ylabel("windows")
        axes[0].legend(fontsize=8)
        return fig

    return {"rows": rows, "paths": rep.write(rows, None, figure)}

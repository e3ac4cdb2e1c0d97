"""PNG plots of an experiment (matplotlib, Agg, small files).

* ``error_by_<key>.png``: per method, the table metric against the gap length (or another grid key);
* ``convergence.png``: the showcase case's error against the truth (evaluation only) and the
  observed-data diagnostics per iteration, as in the Tucker paper's Fig. 4-5;
* ``trajectories.png``: recovered vs true trajectories of a few gap-bearing markers, the gaps
  shaded, as in the Tucker paper's Fig. 6.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .config import Config
from .rows import num as _num, ok as _ok, sort_key as _sort_key


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_plots(cfg: Config, rows: list[dict], out_dir: Path, runs_dir: Path, *, order: list[str],
                metric: str) -> list[Path]:
    """Every plot that the rows and the showcase arrays allow; returns the files written."""
    out = []
    for fn in (_error_by, _convergence, _trajectories):
        path = fn(cfg, rows, out_dir, runs_dir, order, metric)
        if path is not None:
            out.append(path)
    return out


def _x_key(cfg: Config) -> str | None:
    key = cfg.plots.get("x")
    if key:
        return key
    if len(cfg.grid.get("gap_length", [])) > 1:
        return "gap_length"
    return next((k for k, v in cfg.grid.items() if len(v) > 1), None)


def _error_by(cfg, rows, out_dir, runs_dir, order, metric):
    x = _x_key(cfg)
    ok = _ok(rows)
    if x is None or not ok:
        return None
    plt = _plt()
    recs = [r for r in cfg.recordings if any(row["recording"] == r for row in ok)]
    fig, axes = plt.subplots(1, len(recs), figsize=(min(4.2 * len(recs), 12), 3.4), squeeze=False,
                             sharey=False)
    for ax, rec in zip(axes[0], recs):
        for method in order:
            sel = [r for r in ok if r["recording"] == rec and r["method"] == method]
            xs = sorted({r[x] for r in sel}, key=_sort_key)
            if not xs:
                continue
            vals = [np.array([_num(r[metric]) for r in sel if r[x] == v]) for v in xs]
            pos = [_num(v) for v in xs]
            if any(np.isnan(pos)):                       # a categorical grid key
                pos = list(range(len(xs)))
                ax.set_xticks(pos, xs)
            ax.errorbar(pos, [v.mean() for v in vals],
                        yerr=[v.std(ddof=1) if len(v) > 1 else 0 for v in vals], marker="o",
                        ms=3, capsize=2, label=method)
        ax.set_title(Path(rec).stem, fontsize=9)
        ax.set_xlabel(x)
        ax.set_ylabel(metric)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    path = out_dir / f"error_by_{x}.png"
    _save(fig, path)
    plt.close(fig)
    return path


def _showcase(runs_dir: Path, order: list[str]) -> list[dict]:
    """The showcase arrays of each method, all of the same (recording, point, seed)."""
    found = []
    for method in order:
        path = runs_dir / "showcase" / f"{method}.npz"
        if path.exists():
            with np.load(path) as z:
                found.append({k: z[k] for k in z.files})
    if found and "key" in found[0]:
        where = list(found[0]["key"][:-1])
        found = [d for d in found if "key" in d and list(d["key"][:-1]) == where]
    return found


def _convergence(cfg, rows, out_dir, runs_dir, order, metric):
    data = [d for d in _showcase(runs_dir, order) if len(d["curve"]) > 1]
    if not data:
        return None
    plt = _plt()
    has = lambda k: any(k in list(d["history_keys"]) for d in data)  # noqa: E731
    obs_keys = [next((k for k in ("objective", "residual") if has(k)), None), "delta"]
    obs_keys = [k for k in obs_keys if k and has(k)]
    if any(_rank_keys(d) for d in data):
        obs_keys.append("ranks")
    fig, axes = plt.subplots(1, 1 + len(obs_keys), figsize=(3.8 * (1 + len(obs_keys)), 3.3),
                             squeeze=False)
    axes = axes[0]
    by_time = cfg.plots.get("convergence_x") == "time_s" and has("time_s")
    for i, d in enumerate(data):
        color, name = f"C{i}", str(d["method"])
        ck, hk = list(d["curve_keys"]), list(d["history_keys"])
        it = d["history"][:, hk.index("iter")]
        x_curve = d["curve"][:, ck.index("iter")]
        if by_time:         # seconds inside the solver at each iteration (the Lightning history)
            seconds = d["history"][:, hk.index("time_s")] if "time_s" in hk else it * np.nan
            x_curve = np.interp(x_curve, it, seconds)
            it = seconds
        axes[0].plot(x_curve, d["curve"][:, ck.index("rmse")], color=color, label=name)
        for ax, key in zip(axes[1:], obs_keys):
            if key == "ranks":
                for n, rk in enumerate(_rank_keys(d)):
                    ax.plot(it, d["history"][:, hk.index(rk)], color=color,
                            ls=("-", "--", ":", "-.")[n % 4], label=f"{name} {rk}")
            elif key in hk:
                ax.plot(it, d["history"][:, hk.index(key)], color=color, label=name)
    axes[0].set_title("RMSE vs truth (evaluation only)", fontsize=9)
    axes[0].set_ylabel("rmse")
    for ax, key in zip(axes[1:], obs_keys):
        ax.set_title(f"{key} (observed data)", fontsize=9)
        if key == "ranks":
            ax.legend(fontsize=6)
        else:
            ax.set_yscale("log")
    for ax in axes:
        ax.set_xlabel("solver time (s)" if by_time else "iteration")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    path = out_dir / "convergence.png"
    _save(fig, path)
    plt.close(fig)
    return path


def _rank_keys(d) -> list[str]:
    """History keys holding ranks (``R1``, ``R2``, ... or ``rank``)."""
    import re

    return [k for k in map(str, d["history_keys"]) if re.fullmatch(r"R\d+|rank", k)]


def _trajectories(cfg, rows, out_dir, runs_dir, order, metric, n_markers: int = 3):
    from ..metrics import gap_runs

    data = _showcase(runs_dir, order)
    if not data:
        return None
    plt = _plt()
    truth, mask, labels = data[0]["truth"], data[0]["mask"].astype(bool), data[0]["labels"]
    rate = float(data[0]["rate"])
    gapped = np.argsort(-mask.sum(axis=0))[:n_markers]
    gapped = [j for j in gapped if mask[:, j].any()]
    if not gapped:
        return None
    t = np.arange(truth.shape[0]) / rate
    fig, axes = plt.subplots(len(gapped), 1, figsize=(8, 2.2 * len(gapped)), squeeze=False,
                             sharex=True)
    runs = gap_runs(mask)
    for ax, j in zip(axes[:, 0], gapped):
        c = int(np.argmax(truth[mask[:, j], j].std(axis=0)))      # the coordinate that moves most
        for _, a, b in [r for r in runs if r[0] == j]:
            ax.axvspan(t[a], t[b - 1], color="0.85", lw=0)
        ax.plot(t, truth[:, j, c], color="k", lw=1.6, label="truth")
        for d in data:
            filled = d["filled"][:, j, c].copy()
            filled[~mask[:, j]] = np.nan
            ax.plot(t, filled, lw=1.1, label=str(d["method"]))
        ax.set_ylabel(f"{labels[j]} {'xyz'[c]}", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=min(4, len(data) + 1))
    axes[-1, 0].set_xlabel("time (s); gaps shaded")
    fig.tight_layout()
    path = out_dir / "trajectories.png"
    _save(fig, path)
    plt.close(fig)
    return path


def _save(fig, path: Path) -> None:
    """``fig`` as ``path``, atomically, through the guarded writer (a symlink there is replaced)."""
    from ..io.outputs import Outputs

    with Outputs() as out:
        out.write(path, lambda tmp: fig.savefig(tmp, dpi=90), "plot")

"""Closed-form vs gradient fits of the same model class (issue 7): ``tucker`` vs ``grad_tucker`` and
``cp`` vs ``grad_cp``, beside linear interpolation, under the Tucker paper's multi-gap protocol.

For every case (recording x gap length x seed) each method fills the same simulated gaps; the script
records RMSE over all entries and over the missing entries (mm), wall time and iterations, appends a
row to a CSV as soon as a case finishes (``--resume`` skips finished rows), and with ``--report``
prints the mean +- std table (markdown). ``--plot`` draws, for one case, each method's fit to the
OBSERVED data and (evaluation only, the solvers never see it) the error on the missing entries
against wall time: the loss curves of both fits on one plot.

Examples::

    OMP_NUM_THREADS=1 python scripts/grad_vs_closed.py --csv experiments/results/grad_vs_closed.csv
    python scripts/grad_vs_closed.py --report --csv experiments/results/grad_vs_closed.csv
    python scripts/grad_vs_closed.py --plot experiments/results/grad_vs_closed_loss.png \\
        --recordings hdm05_mm_01-02_03_120.c3d --gap-lengths 100 --seeds 0

The config experiments/grad_vs_closed.yaml describes the same grid for ``torchfill experiment``.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import time
from pathlib import Path

import numpy as np
import torch

import torchfill
from torchfill import gaps, metrics
from torchfill.solvers import available, get_solver
from torchfill.solvers.factorized import CPTensor, TuckerTensor

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TORCHFILL_DATA") or REPO / ".." / "shared" / "data").resolve()
RECORDINGS = ["hdm05_dg_06-03_03_120.c3d", "cmu_02_01.c3d", "hdm05_mm_01-02_03_120.c3d"]
#: label -> (registered method, hyperparameters); as in experiments/grad_vs_closed.yaml
SPECS = {"linear": ("linear", {}), "tucker": ("tucker", {}), "grad_tucker": ("grad_tucker", {}),
         "grad_tucker_cf": ("grad_tucker", {"init": "closed_form"}), "cp": ("cp", {}),
         "grad_cp": ("grad_cp", {})}
METHODS = list(SPECS)
FIELDS = ["recording", "frames", "gap_length", "seed", "method", "rmse", "rmse_missing", "time_s",
          "n_iter", "rank"]


def load(name: str, frames: int) -> np.ndarray:
    points = torchfill.read(DATA / name).points[:frames]
    keep = np.isfinite(points).all(axis=(0, 2))          # complete markers only (truth needed)
    return np.asarray(points[:, keep], dtype=np.float64)


def factorized(solver) -> torch.nn.Module | None:
    """The solver's Tucker/CP model (model_, tucker_ or cp_), for the observed-fit curve."""
    for key in ("model_", "tucker_", "cp_"):
        value = getattr(solver, key, None)
        if isinstance(value, (TuckerTensor, CPTensor)):
            return value
    return None


def run(P: np.ndarray, mask: np.ndarray, method: str, trace: bool = False) -> tuple[dict, list]:
    """Fill one case; with ``trace`` drive the loop by hand and record, per iteration, the model's
    RMSE on the observed entries and (evaluation only) on the missing ones, both in mm."""
    X = P.copy()
    X[mask] = np.nan
    Xt = torch.from_numpy(X)
    name, params = SPECS[method]
    solver = get_solver(name, **params)
    curve = []
    t0 = time.perf_counter()
    if not trace:
        solver.fit(Xt)
    else:
        solver.initialize(Xt)
        obs = torch.from_numpy(~mask)[..., None].expand_as(Xt)
        Pt = torch.from_numpy(P)
        paused = 0.0
        while not solver.converged_ and solver.n_iter_ < solver.max_iter:
            solver.step_and_record()
            t1 = time.perf_counter()
            with torch.no_grad():
                model = factorized(solver)
                Y = model() * solver.sigma_ + solver.mu_ if model is not None else solver.forward()
                E = Y - Pt
                fit = float(E[obs].pow(2).mean().sqrt())
                miss = float(E[~obs].pow(2).mean().sqrt())
            curve.append((t1 - t0 - paused, fit, miss))
            paused += time.perf_counter() - t1
        if hasattr(solver, "finalize"):
            solver.finalize()
    F = solver.transform(Xt).numpy()
    dt = time.perf_counter() - t0
    rank = getattr(getattr(solver, "model_", None), "rank", None) or getattr(solver, "chosen_rank_", None) \
        or getattr(solver, "rank_", None) or ""
    row = {"rmse": metrics.rmse(F, P, mask), "rmse_missing": metrics.rmse_missing(F, P, mask),
           "time_s": dt, "n_iter": solver.n_iter_, "rank": str(rank).replace(" ", "")}
    return row, curve


def cases(args):
    for rec in args.recordings:
        P = load(rec, args.frames)
        T, J, _ = P.shape
        for L in args.gap_lengths:
            if L >= T:
                continue
            for seed in args.seeds:
                mask = gaps.multi_gap(T, J, n_markers=min(20, J), gap_length=L, max_gaps=5, seed=seed)
                yield rec, P, L, seed, mask


def main_grid(args) -> None:
    path = Path(args.csv)
    done = set()
    if path.exists() and args.resume:
        with path.open() as f:
            done = {(r["recording"], r["gap_length"], r["seed"], r["method"]) for r in csv.DictReader(f)}
    new = not path.exists() or not args.resume
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w" if new else "a", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        if new:
            w.writeheader()
        for rec, P, L, seed, mask in cases(args):
            for method in args.methods:
                if SPECS[method][0] not in available():
                    print(f"skip {method}: not registered")
                    continue
                if (rec, str(L), str(seed), method) in done:
                    continue
                row, _ = run(P, mask, method)
                row = {"recording": rec, "frames": P.shape[0], "gap_length": L, "seed": seed,
                       "method": method, **row}
                w.writerow(row)
                f.flush()
                print(f"{rec} L={L} seed={seed} {method:12s} rmse={row['rmse']:.3f} "
                      f"miss={row['rmse_missing']:.3f} t={row['time_s']:.1f}s it={row['n_iter']} "
                      f"rank={row['rank']}", flush=True)


def report(args) -> None:
    rows = []
    for p in args.csv.split(","):
        with open(p) as f:
            rows += list(csv.DictReader(f))
    methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
    keys = sorted({(r["recording"], int(r["frames"]), int(r["gap_length"])) for r in rows})

    def cell(sel, field, digits=2):
        v = np.array([float(r[field]) for r in sel])
        return f"{v.mean():.{digits}f} ± {v.std(ddof=1) if len(v) > 1 else 0:.{digits}f}" if len(v) else "-"

    for field, title in (("rmse", "RMSE, all entries (mm)"), ("rmse_missing", "RMSE, missing entries (mm)"),
                         ("time_s", "wall time (s, under load)"), ("n_iter", "iterations")):
        print(f"\n{title}, mean ± std over seeds\n")
        print("| recording | frames | gap | " + " | ".join(methods) + " |")
        print("|---|---|---|" + "---|" * len(methods))
        for rec, T, L in keys:
            sel = [r for r in rows if (r["recording"], int(r["frames"]), int(r["gap_length"])) == (rec, T, L)]
            cells = [cell([r for r in sel if r["method"] == m], field, 1 if field in ("time_s", "n_iter") else 2)
                     for m in methods]
            print(f"| {rec.removesuffix('.c3d')} | {T} | {L} | " + " | ".join(cells) + " |")
    # gradient vs closed-form, case by case
    for cf, gr in (("tucker", "grad_tucker"), ("tucker", "grad_tucker_cf"), ("cp", "grad_cp")):
        ratios = []
        for r in rows:
            if r["method"] != gr:
                continue
            mate = [q for q in rows if q["method"] == cf and
                    (q["recording"], q["gap_length"], q["seed"]) == (r["recording"], r["gap_length"], r["seed"])]
            if mate:
                ratios.append(float(r["rmse"]) / max(float(mate[0]["rmse"]), 1e-12))
        if ratios:
            ratios = np.array(ratios)
            print(f"\n{gr} / {cf} RMSE ratio over {len(ratios)} cases: median {np.median(ratios):.3f}, "
                  f"mean {ratios.mean():.3f}, within 10 %: {(ratios <= 1.1).sum()}/{len(ratios)}, "
                  f"max {ratios.max():.3f}")


def plot(args) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rec, P, L, seed, mask = next(iter(cases(args)))
    fig, axes = plt.subplots(1, 2, figsize=(8.5, 3.2), dpi=80)
    styles = {"tucker": ("C0", "-"), "grad_tucker": ("C0", "--"), "grad_tucker_cf": ("C2", ":"),
              "cp": ("C3", "-"), "grad_cp": ("C3", "--")}
    for method in [m for m in args.methods if m in styles and SPECS[m][0] in available()]:
        row, curve = run(P, mask, method, trace=True)
        t, fit, miss = map(np.array, zip(*curve))
        c, ls = styles[method]
        label = f"{method} ({row['n_iter']} it, {row['time_s']:.1f} s)"
        axes[0].semilogy(t, fit, color=c, ls=ls, label=label)
        axes[1].semilogy(t, miss, color=c, ls=ls, label=label)
        print(f"{method}: rmse={row['rmse']:.3f} miss={row['rmse_missing']:.3f} it={row['n_iter']} "
              f"t={row['time_s']:.1f}s rank={row['rank']}")
    axes[0].set_title("model vs observed entries (the fit)", fontsize=9)
    axes[1].set_title("missing entries (evaluation only)", fontsize=9)
    for ax in axes:
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("RMSE (mm)")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7)
    fig.suptitle(f"{rec.removesuffix('.c3d')} ({P.shape[0]} frames), multi_gap 20 markers x "
                 f"{L} frames, <=5 gaps, seed {seed}", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.plot, dpi=80)
    print(f"wrote {args.plot} ({Path(args.plot).stat().st_size // 1024} KB)")


def ortho(args) -> None:
    """QR retraction vs torch.nn.utils.parametrizations.orthogonal vs free factors, on a synthetic
    exact-rank Tucker tensor (100 x 12 x 3, rank (4,3,2) + the centring term) with 30 % missing
    samples: relative error on the missing entries, steps, time, time per step."""
    from torchfill import ops
    g = torch.Generator().manual_seed(0)
    T, J, rank = 100, 12, (4, 3, 2)
    G = torch.randn(*rank, generator=g, dtype=torch.float64)
    A = [torch.linalg.qr(torch.randn(n, r, generator=g, dtype=torch.float64)).Q for n, r in zip((T, J, 3), rank)]
    X = ops.tucker_to_tensor(G, A) * 100 + 50
    mask = torch.rand(T, J, generator=g) < 0.3
    m = mask[..., None].expand_as(X)
    print("| ortho | optimizer | rel. error (missing) | steps | time (s) | ms / step |")
    print("|---|---|---|---|---|---|")
    for opt in ("adam", "lbfgs"):
        for o in ("qr", "param", "none"):
            best = None
            for _ in range(2):
                s = get_solver("grad_tucker", rank=(5, 4, 3), optimizer=opt, ortho=o, max_iter=1000)
                t0 = time.perf_counter()
                F = s.fit_transform(X, mask)
                dt = time.perf_counter() - t0
                best = dt if best is None else min(best, dt)
            err = float((F - X)[m].norm() / X[m].norm())
            print(f"| {o} | {opt} | {err:.1e} | {s.n_iter_} | {best:.2f} | {1e3 * best / s.n_iter_:.1f} |",
                  flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recordings", nargs="+", default=RECORDINGS)
    ap.add_argument("--frames", type=int, default=1000, help="first N frames of each recording")
    ap.add_argument("--gap-lengths", nargs="+", type=int, default=[100, 200])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--methods", nargs="+", default=METHODS)
    ap.add_argument("--csv", default=str(REPO / "experiments/results/grad_vs_closed.csv"))
    ap.add_argument("--resume", action="store_true", help="append, skipping finished cases")
    ap.add_argument("--report", action="store_true", help="print the tables from --csv (comma list)")
    ap.add_argument("--plot", help="draw the loss curves of the first case into this PNG")
    ap.add_argument("--ortho", action="store_true", help="measure the orthonormality options")
    args = ap.parse_args()
    if args.ortho:
        ortho(args)
    elif args.report:
        report(args)
    elif args.plot:
        plot(args)
    else:
        main_grid(args)


if __name__ == "__main__":
    main()

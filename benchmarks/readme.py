"""README.md's generated blocks: the "Which method when" table and the figures of its OpenSim
paragraph. The words are here; every number is computed from the stored results (the suites'
rows under experiments/results/ and the experiment runner's ``cases.csv``), so
``python -m benchmarks docs --check`` fails when a README number no longer matches them."""
from __future__ import annotations

import warnings

import numpy as np

from . import data
from .rows import num, read_csv

README = data.REPO / "README.md"


def _mean(rows: list[dict], method: str, key: str = "rmse") -> float:
    return float(np.nanmean([num(r.get(key)) for r in rows if r["method"] == method]))


def _cases(rows: list[dict]) -> int:
    return len({r["case"] for r in rows})


def experiment(name: str, by: list[str], metric: str = "rmse") -> dict[tuple, dict[str, float]]:
    """An experiment's stored ``cases.csv``: per table line (``by``) each method's mean over
    seeds, as the experiment's table.md shows it."""
    from torchfill.lightning.rows import read_rows, summarize

    cells = summarize(read_rows(data.RESULTS / name / "cases.csv"), by, "method", metric)
    return {k: {m: float(v.mean()) for m, v in c.items()} for k, c in cells.items()}


def line_mean(lines: dict[tuple, dict[str, float]], methods: list[str]) -> tuple[int, dict]:
    """Each method's mean over the table lines where all of ``methods`` have a value (the
    table.md's "mean of N rows")."""
    full = [c for c in lines.values() if all(m in c for m in methods)]
    return len(full), {m: float(np.mean([c[m] for c in full])) for m in methods}


def _real_gaps() -> dict:
    from .suites import masks, real_gaps

    out = {}
    for key, path in (("real", real_gaps.CSV), ("masks", masks.CSV)):
        rows = [r for r in read_csv(path) if not r["method"].startswith("peer:")]
        names = list(dict.fromkeys(r["method"] for r in rows))
        ratios = real_gaps.default_ratios(rows, names).values()
        out[key] = {"n": _cases(rows), "worst": float(np.nanmax(list(ratios))),
                    **{m: _mean(rows, m) for m in names},
                    **{f"{m} cpu": float(np.nanmedian([num(r.get("cpu")) for r in rows
                                                       if r["method"] == m])) for m in names}}
    return out


def _ik() -> dict:
    """The IK suite's summary per method, and its heaviest mask's rows (default, gaps left)."""
    from .suites import ik

    rows, methods, _ = ik.stored()
    summary = {s["method"]: s for s in ik.summarise(rows, methods)}
    heavy = max((r for r in rows if r["method"] == "default"), key=lambda r: r["missing_pct"])
    same = {r["method"]: r for r in rows if (r["recording"], r["source"], r["seed"])
            == (heavy["recording"], heavy["source"], heavy["seed"])}
    return {"summary": summary, "heavy": same}


def which_method() -> str:
    """The "Which method when" table (gaps | what the default does | measured | try)."""
    from .suites import segments, session

    rg, ik = _real_gaps(), _ik()["summary"]
    real, sim = rg["real"], rg["masks"]
    t2 = line_mean(experiment("tucker_table2", ["recording", "gap_length", "max_gaps"]),
                   ["pchip", "tucker_tnn"])
    a2 = line_mean(experiment("auto_table2", ["recording", "gap_length", "max_gaps"]),
                   ["auto", "tucker_tnn", "pma"])
    cp_lines = experiment("auto_cp", ["recording", "n_markers", "gap_length"])
    acp = line_mean(cp_lines, ["auto", "pma", "cp", "tucker_tnn"])
    (rec, markers, frames), worst = max(((k, c) for k, c in cp_lines.items()
                                         if "auto" in c and "tucker_tnn" in c),
                                        key=lambda kc: kc[1]["tucker_tnn"] / kc[1]["auto"])
    short = experiment("cp_tables", ["recording", "n_markers", "gap_length"])[
        ("cmu_02_01.c3d", "30", "20")]
    black = line_mean(experiment("pca_blackout", ["recording", "gap_length"], "gap_error"),
                      ["spline", "pca_blackout"])
    two_d = line_mean(experiment("pca_2d", ["recording", "n_gaps"], "gap_error"),
                      ["linear", "tucker_tnn", "pca_train"])
    seg = segments.ratio_table(read_csv(segments.CSV),
                               read_csv(segments.RUN)[0]["methods"].split(","))[1]
    ses = session.stored()
    end, every = session.stats(ses, session.END_SHARE), session.stats(ses)
    f1, f2 = (lambda x: f"{x:.1f}"), (lambda x: f"{x:.2f}")      # noqa: E731
    rows = [
        ["**any** (the default)",
         "`auto`: per gap, the methods that fill this recording's gaps of that kind best on its "
         "own observed data — spatial models at trial ends and for groups of missing markers, "
         "rigid segments where three segment-mates are seen, low-rank and interpolation inside — "
         "with an error estimate per sample",
         f"real gap patterns ({real['n']} cases): **{f1(real['default'])}** mean, `pma` "
         f"{f1(real['pma'])}, `tucker_tnn` {f1(real['tucker_tnn'])}; simulated gaps "
         f"({sim['n']} cases): **{f1(sim['default'])}**, `pma` {f1(sim['pma'])}; OpenSim IK: "
         f"{f2(ik['default']['rmse_all'])}° vs {f2(ik['gaps']['rmse_all'])}° with the gaps left "
         "([docs/ik.md](docs/ik.md))",
         f"`-m tucker_tnn` when time matters (median CPU s per real-gap case: "
         f"{f2(real['tucker_tnn cpu'])} vs {f2(real['default cpu'])})"],
        ["long gaps (100–200 frames) while most markers stay visible",
         "fills them from the other markers' motion",
         f"Tucker-paper layout (20 markers, mean of {t2[0]} lines): `tucker_tnn` "
         f"{f2(t2[1]['tucker_tnn'])}, PCHIP {f2(t2[1]['pchip'])}; with the constraints "
         f"({a2[0]} lines, seed 0): the default {f2(a2[1]['auto'])}, `tucker_tnn` "
         f"{f2(a2[1]['tucker_tnn'])}, `pma` {f2(a2[1]['pma'])}", "`-m tucker_tnn`"],
        ["many markers missing over one shared window of a short recording",
         "picks per gap kind on held-out data",
         f"`tucker_tnn` alone can fail ({f1(worst['tucker_tnn'])} on "
         f"{rec.removesuffix('.c3d')}, {markers} markers × {frames} frames; the default "
         f"{f1(worst['auto'])}); CP-paper layout mean ({acp[0]} lines): the default "
         f"**{f1(acp[1]['auto'])}**, `pma` {f1(acp[1]['pma'])}, `cp` {f1(acp[1]['cp'])}, "
         f"`tucker_tnn` {f1(acp[1]['tucker_tnn'])}", "`-m pma`"],
        ["short gaps (≤ 20 frames) of many markers at once",
         "interpolation competes in the hold-out",
         f"cmu_02_01, 30 of 41 markers × 20 frames: `tucker_tnn` {f2(short['tucker_tnn'])}, "
         f"spline **{f2(short['spline'])}**", "`-m spline`, `-m pchip`"],
        [f"a mix: dense occlusions, shared windows, near-still stretches ({sim['n']}-case mask "
         "suite)", "",
         f"mean: the default **{f1(sim['default'])}** (worst {f2(sim['worst'])}× the case's best "
         f"single method), `pma` {f1(sim['pma'])}, `li` {f1(sim['li'])}, `tucker_tnn` "
         f"{f1(sim['tucker_tnn'])}", "`-m pma`"],
        ["markers on a rigid segment (≥ 3 segment-mates seen)",
         "filled rigidly from the segment-mates (weighted Kabsch)",
         f"on the samples gapfill's rigid-body fill reaches ({seg['default'][2]} real-gap cases): "
         f"`rigid` {f2(seg['rigid'][0])}×, the default {f2(seg['default'][0])}× gapfill's RMSE "
         f"(worst case {f2(seg['default'][1])}×) ([docs/segments.md](docs/segments.md))",
         "`--segments FILE` for your own segments"],
        ["several trials of one subject",
         "`--session` (or `training=`): the spatial models learn from the other trials too",
         f"trial-end-dominated real gap patterns ({end['cases']} cases): {f1(end['alone'])} → "
         f"{f1(end['session'])} mm mean (ratio {end['ratio']:.3f}), worse by more than 5 % on "
         f"{every['worse']} of {every['cases']}; {f2(every['session_s'] / every['alone_s'])}× "
         "the time of the fill alone; a marker missing from the whole trial is placed from its "
         "segment-mates", "`--training DIR` of clean trials"],
        ["gaps at the start or end of the trial",
         "filled from the markers still seen (spatial models, rigid segments); without them "
         "extrapolated ≤ 0.25 s; the rest stays NaN", "", "`extrapolate=None` to fill all; check "
         "with `qc`"],
        ["whole frames with no marker seen (blackouts)",
         "interpolated in time, not invented; trial-end blackouts left NaN",
         f"spline: {f1(black[1]['spline'])} mean gap error over the blackout table "
         f"({black[0]} lines)",
         f"`-m pca_blackout --training other.c3d` ({f1(black[1]['pca_blackout'])})"],
        ["2-D keypoint tracks (OpenPose)",
         "the same choice in 2-D, among the methods that take 2-D data",
         f"PCA-paper 2-D protocol (side views, {two_d[0]} lines), mean gap error: `tucker_tnn` "
         f"{f1(two_d[1]['tucker_tnn'])}, linear {f1(two_d[1]['linear'])}",
         f"`-m pca_train --training other.c3d` ({f1(two_d[1]['pca_train'])})"],
        ["long recordings (> 6000 frames)",
         "overlapping windows, time linear in the length; the later windows reuse the first "
         "window's choice of methods, in worker processes",
         "time and memory: [docs/speed.md](docs/speed.md)", "`-m tucker_tnn`, `--window`"],
    ]
    sources = ("Sources (`python -m benchmarks docs` writes this table from them): "
               "experiments/results/real_gaps/rows.csv and mask_rows.csv (`python -m benchmarks "
               "real-gaps`, `masks`), ik/ (`ik`), segments/ (`segments`), session/ "
               "(`session`); the experiment runner's tucker_table2, auto_table2, auto_cp, "
               "cp_tables, pca_blackout and pca_2d (`torchfill experiment "
               "experiments/NAME.yaml`).")
    table = ["| gaps | what the default does | measured | try |", "|---|---|---|---|"]
    table += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(table) + "\n\n" + sources


def opensim() -> str:
    """The OpenSim paragraph's sentence on IK (the IK suite's stored rows)."""
    got = _ik()
    s, heavy = got["summary"], got["heavy"]
    d, g = s["default"], s["gaps"]
    better = d["masks"] - d["worse_than_gaps"]
    return (f"On {d['masks']} real gap masks laid onto OpenSim's example walk and run, IK on the "
            f"default's fill is {d['rmse_all']:.2f}° from IK on the complete recording (worst "
            f"hip/knee error {d['max_hip_knee']:.1f}°), against {g['rmse_all']:.2f}° with the "
            f"gaps left, and better than the gaps left on {better} of {d['masks']} masks; the "
            f"heaviest ({heavy['default']['missing_pct']:.0f} % of the samples missing): "
            f"{heavy['default']['rmse_all']:.2f}° against {heavy['gaps']['rmse_all']:.2f}° "
            "([docs/ik.md](docs/ik.md)).")


def doc_blocks() -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)        # means of columns a method lacks
        return {(README, "which_method"): which_method(), (README, "opensim_ik"): opensim()}

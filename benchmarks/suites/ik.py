"""Fills judged by the joint angles OpenSim inverse kinematics (IK) computes from them.

Two complete OpenSim example recordings get real gap masks (the gap patterns of the gapped
recordings in the data folder, laid onto them); each method fills them; OpenSim 4.6 IK with the
example model and IK setup turns every input into joint angles; those are compared with IK on the
complete recording. "gaps left" is IK on the gapped recording itself: OpenSim IK skips a marker
that is missing (NaN) in a frame, so leaving a gap is always an option, and a fill is worth
writing only where it beats that.

- ``osim_gait2392_subject01_walk1.trc`` (walking, 60 Hz, 151 frames) with the gait2392 model
  scaled to subject01 and its IK setup;
- ``osim_hamner_subject02_running.trc`` (running, 60 Hz; its first ``HAMNER_FRAMES`` frames, to
  keep a full run short) with the Hamner model of subject02 and its IK setup. Its dead marker
  (``L.Bicep``, all zeros, not an IK task) is dropped before anything else.

Per method and mask: joint-angle RMSE in degrees against IK on the complete recording over all
free rotational coordinates (not locked, not held by a coordinate task of the setup) and all
frames, over the frames with a gap, for hip / knee / ankle flexion (right and left) and pelvis
tilt; the largest single error (any coordinate, and hip/knee flexion); IK's marker error (mean
over frames of the RMS over the markers IK used, from the tool's marker-error output, in mm); the
masks where the fill's all-frames RMSE exceeds that of leaving the gaps; seconds to fill and to
run IK. The table goes to the page ``docs/ik.md`` (between its markers) and the rows to
``experiments/results/ik/``.

Usage::

    OMP_NUM_THREADS=1 python -m benchmarks ik [--methods default,auto] [--masks 12]
        [--doc docs/ik.md] [--results experiments/results/ik]

Needs ``opensim`` (``pip install opensim==4.6``) and the data folder (``TORCHFILL_DATA`` or the
``shared/data`` folder beside the repository) with its ``opensim/`` models and setups.
"""
from __future__ import annotations

import contextlib
import math
import os
import shlex
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import torchfill
from torchfill import gaps

from .. import data
from ..methods import run as run_method
from ..peers import PEERS
from ..rows import Rows, read_csv, write_csv
from ..tables import write_block

HELP = "fills judged by the joint angles of OpenSim inverse kinematics"
DOC = data.DOCS / "ik.md"
RESULTS = data.RESULTS / "ik"

#: Frames of the Hamner running trial used (10 s at 60 Hz in the file; IK costs 20-40 ms a frame there).
HAMNER_FRAMES = 240


@dataclass(frozen=True)
class Recording:
    name: str
    trc: str
    model: str
    setup: str
    frames: tuple[int, int] | None = None


RECORDINGS = {
    "gait2392": Recording("gait2392", "osim_gait2392_subject01_walk1.trc",
                          "opensim/gait2392/subject01_simbody.osim",
                          "opensim/gait2392/subject01_Setup_IK.xml"),
    "hamner": Recording("hamner", "osim_hamner_subject02_running.trc",
                        "opensim/hamner/subject02_registered.osim",
                        "opensim/hamner/Setup_IK.xml", (0, HAMNER_FRAMES)),
}

#: (recording, gapped source recording, seed), in the order ``--masks N`` takes them. The sources
#: are recordings with real occlusion gaps (PROVENANCE.md), long enough to cover the target.
CASES = [
    ("gait2392", "c3dorg_s26_walking_hybrid_1_1.c3d", 0),
    ("hamner", "c3dorg_s00_codamotion_gaitwands_20150204.c3d", 0),
    ("gait2392", "c3dorg_s26_walking_hybrid_1_4.c3d", 1),
    ("hamner", "ktk_c3d_sample_bts.c3d", 1),
    ("gait2392", "c3dorg_s26_capture0002.c3d", 2),
    ("hamner", "numediart_03_rolling.c3d", 2),
    ("gait2392", "c3dorg_s28_type1.c3d", 3),
    ("hamner", "c3dorg_s01_eb015pr.c3d", 3),
    ("gait2392", "c3dorg_s26_walking_hybrid_1_3.c3d", 4),
    ("hamner", "ktk_basket_sprint.c3d", 4),
    ("gait2392", "c3dorg_s26_walking_hybrid_1_5.c3d", 5),
    ("hamner", "c3dorg_s04_sub_labels.c3d", 5),
    ("gait2392", "c3dorg_s00_codamotion_gaitwands_20150204.c3d", 6),
    ("gait2392", "ktk_basket_sprint.c3d", 6),
    ("hamner", "c3dorg_s00_codamotion_gaitwands_20150204.c3d", 7),
]

N_MASKS = 12

#: name -> (what it is, fill keyword arguments); "gaps" is no fill (NaN left for IK to skip).
METHODS = {
    "gaps": ("gaps left (IK skips a missing marker)", None),
    "default": ("default as shipped (`fill(seq)`)", {}),
    "default_all": ("default, everything filled (`extrapolate=None`)", {"extrapolate": None}),
    "pma": ("pma, everything filled", {"method": "pma", "extrapolate": None}),
    "lgrnn": ("lgrnn, everything filled", {"method": "lgrnn", "extrapolate": None}),
    "auto": ("auto, everything filled", {"method": "auto", "extrapolate": None}),
    "pchip": ("pchip, everything filled", {"method": "pchip", "extrapolate": None}),
    "tucker_tnn": ("tucker_tnn, everything filled", {"method": "tucker_tnn", "extrapolate": None}),
}
#: Run unless ``--methods`` says otherwise (``auto`` too when it is not the default method).
DEFAULT_RUN = ("default", "default_all", "auto", "pma", "lgrnn", "pchip")

GROUPS = {
    "hip": ("hip_flexion_r", "hip_flexion_l"),
    "knee": ("knee_angle_r", "knee_angle_l"),
    "ankle": ("ankle_angle_r", "ankle_angle_l"),
    "pelvis_tilt": ("pelvis_tilt",),
}


def transplant_mask(source: torchfill.MarkerSequence, target: torchfill.MarkerSequence,
                    seed: int, markers: list[str] | None = None) -> np.ndarray:
    """The gap mask of ``source`` laid onto ``target`` (:func:`torchfill.gaps.transplant`): gap
    durations kept in seconds, cut at a seeded offset, each source marker on the target marker at
    the most similar place on the body (real occlusions hit neighbouring markers together). Only
    the target's ``markers`` (default all) get gaps: the IK benchmark passes the markers IK uses,
    so that no mask is spent on a marker IK ignores."""
    index = np.arange(target.n_markers) if markers is None else np.array(
        [j for j, label in enumerate(target.labels) if label in set(markers)])
    part = target.select(index)
    laid = gaps.transplant(source.mask, part.n_frames, part.n_markers, seed=seed,
                           rate_ratio=part.rate / source.rate,
                           source_layout=gaps.body_layout(source.points, source.labels),
                           target_layout=gaps.body_layout(part.points, part.labels))
    mask = np.zeros((target.n_frames, target.n_markers), bool)
    mask[:, index] = laid
    return mask


def ik_markers(rec: Recording) -> list[str]:
    """The markers the IK setup uses (applied marker tasks with a positive weight)."""
    osim = _opensim()
    tool = osim.InverseKinematicsTool(str(data.folder() / rec.setup))       # owns the task set
    tasks = tool.getIKTaskSet()
    return [tasks.get(i).getName() for i in range(tasks.getSize())
            if tasks.get(i).getConcreteClassName() == "IKMarkerTask" and tasks.get(i).getApply()
            and tasks.get(i).getWeight() > 0]


def load_recording(rec: Recording) -> torchfill.MarkerSequence:
    seq = torchfill.read(data.folder() / rec.trc)
    alive = ~seq.mask.all(axis=0)
    seq = seq.select(np.flatnonzero(alive))
    if rec.frames is not None:
        a, b = rec.frames
        seq = seq.with_points(seq.points[a:b])
    if seq.mask.any():
        raise SystemExit(f"{rec.trc}: expected a complete recording, found gaps")
    return torchfill.MarkerSequence(points=seq.points, labels=list(seq.labels), rate=seq.rate,
                                    units=seq.units)


# --------------------------------------------------------------------------------------------
# OpenSim
# --------------------------------------------------------------------------------------------
def _opensim():
    import opensim
    opensim.Logger.setLevelString("error")
    opensim.Logger.removeFileSink()              # no opensim.log in the working directory
    return opensim


def write_trc(seq: torchfill.MarkerSequence, path: Path) -> str:
    """Write ``seq`` as a TRC that OpenSim reads: through ``torchfill.write``; if OpenSim's reader
    rejects that file, through OpenSim's own TRC writer from the same arrays (a work-around for the
    benchmark only). Returns which writer made the file."""
    osim = _opensim()
    fresh = torchfill.MarkerSequence(points=seq.points, labels=list(seq.labels), rate=seq.rate,
                                     units=seq.units)
    torchfill.write(fresh, path)
    try:
        osim.TimeSeriesTableVec3(str(path))
        return "torchfill"
    except RuntimeError:
        pass
    path.unlink()
    table = osim.TimeSeriesTableVec3()
    table.setColumnLabels(list(seq.labels))
    for t in range(seq.n_frames):
        row = osim.RowVectorVec3(seq.n_markers)
        for j in range(seq.n_markers):
            x, y, z = (float(v) for v in seq.points[t, j])
            row[j] = osim.Vec3(x, y, z)
        table.appendRow(t / seq.rate, row)
    for key, value in (("DataRate", f"{seq.rate:g}"), ("CameraRate", f"{seq.rate:g}"),
                       ("Units", seq.units)):
        table.addTableMetaDataString(key, value)
    osim.TRCFileAdapter.write(table, str(path))
    return "opensim"


@dataclass
class IKResult:
    coords: list[str]
    angles: np.ndarray           # (T, C) degrees (rotational) / metres
    marker_rms: np.ndarray       # (T,) metres
    seconds: float
    writer: str = "torchfill"


def _read_sto(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    end = next(i for i, line in enumerate(lines) if line.strip().lower() == "endheader")
    names = lines[end + 1].split("\t")
    values = np.array([[float(v) for v in line.split()] for line in lines[end + 2:] if line.strip()])
    return [n.strip() for n in names], values.reshape(-1, len(names))


def run_ik(rec: Recording, seq: torchfill.MarkerSequence, folder: Path) -> IKResult:
    """OpenSim IK of ``seq`` with ``rec``'s model and setup; angles and marker errors per frame."""
    osim = _opensim()
    folder.mkdir(parents=True, exist_ok=True)
    trc = folder / "markers.trc"
    writer = write_trc(seq, trc)
    start = time.perf_counter()
    tool = osim.InverseKinematicsTool(str(data.folder() / rec.setup))
    tool.setName("ik")
    model = osim.Model(str(data.folder() / rec.model))
    tool.setModel(model)
    tool.set_marker_file(str(trc))
    tool.setStartTime(0.0)
    tool.setEndTime((seq.n_frames - 1) / seq.rate)
    tool.setResultsDir(str(folder))
    tool.set_output_motion_file(str(folder / "ik.mot"))
    tool.set_report_errors(True)
    tool.set_report_marker_locations(False)
    if not tool.run():
        raise RuntimeError(f"OpenSim IK failed on {trc}")
    seconds = time.perf_counter() - start
    names, values = _read_sto(folder / "ik.mot")
    _, errors = _read_sto(folder / "ik_ik_marker_errors.sto")
    if len(values) != seq.n_frames:
        raise RuntimeError(f"IK gave {len(values)} frames for {seq.n_frames}")
    return IKResult(names[1:], values[:, 1:], errors[:, 2], seconds, writer)


@contextlib.contextmanager
def _quiet_stdout():
    """OpenSim prints the model summary on stdout (C level); keep the table readable."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def free_rotations(rec: Recording) -> list[str]:
    """The model's rotational coordinates that IK solves from markers: not locked, not
    constrained, not held by an applied coordinate task of the setup."""
    osim = _opensim()
    model = osim.Model(str(data.folder() / rec.model))
    state = model.initSystem()
    tool = osim.InverseKinematicsTool(str(data.folder() / rec.setup))
    tasks = tool.getIKTaskSet()
    held = {tasks.get(i).getName() for i in range(tasks.getSize())
            if tasks.get(i).getApply() and tasks.get(i).getConcreteClassName() == "IKCoordinateTask"}
    coords = model.getCoordinateSet()
    out = []
    for i in range(coords.getSize()):
        c = coords.get(i)
        if (c.getMotionType() == 1 and not c.getLocked(state) and not c.isConstrained(state)
                and not c.isPrescribed(state) and c.getName() not in held):
            out.append(c.getName())
    return out


# --------------------------------------------------------------------------------------------
# Fill, IK, score
# --------------------------------------------------------------------------------------------
def label(method: str) -> str:
    if method.startswith("peer:"):
        return f"{PEERS[method[5:]][0]} (its gaps left)"
    return METHODS[method][0]


def fill_case(seq: torchfill.MarkerSequence, method: str) -> tuple[torchfill.MarkerSequence, float]:
    if method.startswith("peer:"):
        got = run_method(method, seq)
        return seq.with_points(got.points), got.timing.wall
    kwargs = METHODS[method][1]
    if kwargs is None:
        return seq, 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        out = torchfill.fill(seq, **kwargs)
        return out, time.perf_counter() - start


def score(ref: IKResult, got: IKResult, free: list[str], gap_frames: np.ndarray) -> dict:
    col = {name: i for i, name in enumerate(ref.coords)}
    idx = [col[n] for n in free]
    err = got.angles[:, idx] - ref.angles[:, idx]                           # (T, C) degrees

    def rmse(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(e ** 2))) if e.size else math.nan

    row = {"rmse_all": rmse(err), "rmse_gap": rmse(err[gap_frames])}
    for group, names in GROUPS.items():
        row[f"rmse_{group}"] = rmse(err[:, [free.index(n) for n in names if n in free]])
    row["max_err"] = float(np.abs(err).max())
    j = int(np.abs(err).max(axis=0).argmax())
    row["max_coord"] = free[j]
    hk = [free.index(n) for n in GROUPS["hip"] + GROUPS["knee"] if n in free]
    row["max_hip_knee"] = float(np.abs(err[:, hk]).max())
    row["marker_rms_mm"] = 1000.0 * float(np.mean(got.marker_rms))
    row["ik_s"] = got.seconds
    return row


def run(methods: list[str], n_masks: int, work: Path, done: Rows, log=print) -> list[dict]:
    cases = CASES[:n_masks]
    recs = {name: load_recording(RECORDINGS[name]) for name in {c[0] for c in cases}}
    refs, free = {}, {}
    markers = {name: ik_markers(RECORDINGS[name]) for name in recs}
    for name, seq in recs.items():
        with _quiet_stdout():
            refs[name] = run_ik(RECORDINGS[name], seq, work / name / "complete")
            free[name] = free_rotations(RECORDINGS[name])
        log(f"{name}: {seq.n_frames} frames, {seq.n_markers} markers ({len(markers[name])} used "
            f"by IK, the only ones given gaps), {len(free[name])} free "
            f"rotational coordinates, IK on the complete recording {refs[name].seconds:.1f} s")
    rows = []
    for k, (name, source_file, seed) in enumerate(cases):
        seq = recs[name]
        source = torchfill.read(data.folder() / source_file)
        mask = transplant_mask(source, seq, seed, markers[name])
        gapped = seq.with_points(np.where(mask[..., None], np.nan, seq.points))
        gap_frames = mask.any(axis=1)
        case = f"{name}/{Path(source_file).stem}/s{seed}"
        log(f"[{k + 1}/{len(cases)}] {case}: {mask.sum()} missing samples "
            f"({100 * mask.mean():.1f} %), {mask.any(axis=0).sum()} markers, "
            f"{gap_frames.sum()} frames with a gap")
        for method in methods:
            if done.done(recording=name, source=Path(source_file).stem, seed=seed, method=method):
                continue
            out, fill_s = fill_case(gapped, method)
            left = int((mask & ~np.isfinite(out.points).all(axis=2)).sum())
            if method != "gaps":
                assert np.array_equal(out.points[~mask], seq.points[~mask]), "observed changed"
            try:
                with _quiet_stdout():
                    got = run_ik(RECORDINGS[name], out, work / case / method)
                row = score(refs[name], got, free[name], gap_frames)
                row["writer"] = got.writer
            except RuntimeError as exc:
                row = {"error": str(exc).splitlines()[0]}
            row.update(recording=name, source=Path(source_file).stem, seed=seed, method=method,
                       missing_pct=100 * float(mask.mean()), nan_left=left, fill_s=fill_s)
            rows.append(row)
            done.add(row)
            if "error" in row:
                log(f"    {method:12s} IK FAILED: {row['error']}")
            else:
                log(f"    {method:12s} RMSE {row['rmse_all']:6.2f} deg (gap frames "
                    f"{row['rmse_gap']:6.2f}), max {row['max_err']:6.1f} ({row['max_coord']}), "
                    f"left NaN {left:5d}, fill {fill_s:5.1f} s, IK {row['ik_s']:4.1f} s"
                    + ("" if row["writer"] == "torchfill" else ", TRC via OpenSim's writer"))
    return rows


def summarise(rows: list[dict], methods: list[str]) -> list[dict]:
    base = {(r["recording"], r["source"], r["seed"]): r.get("rmse_all", math.nan)
            for r in rows if r["method"] == "gaps"}
    out = []
    for method in methods:
        mine = [r for r in rows if r["method"] == method]
        ok = [r for r in mine if "error" not in r]

        def mean(key):
            return float(np.mean([r[key] for r in ok])) if ok else math.nan

        worse = sum(r["rmse_all"] > base[(r["recording"], r["source"], r["seed"])] for r in ok)
        out.append({
            "method": method, "masks": len(mine), "ik_failed": len(mine) - len(ok),
            "rmse_all": mean("rmse_all"), "rmse_gap": mean("rmse_gap"),
            **{f"rmse_{g}": mean(f"rmse_{g}") for g in GROUPS},
            "max_err": max((r["max_err"] for r in ok), default=math.nan),
            "max_hip_knee": max((r["max_hip_knee"] for r in ok), default=math.nan),
            "marker_rms_mm": mean("marker_rms_mm"),
            "worse_than_gaps": None if method == "gaps" else int(worse),
            "nan_left": int(sum(r["nan_left"] for r in mine)),
            "fill_s_median": float(np.median([r["fill_s"] for r in mine])) if mine else math.nan,
            "ik_s_median": float(np.median([r["ik_s"] for r in ok])) if ok else math.nan,
            "trc_via_opensim": sum(r.get("writer") == "opensim" for r in mine),
        })
    return out


def table(summary: list[dict]) -> str:
    head = ("| input to IK | all frames | frames with a gap | hip flex. | knee | ankle | pelvis tilt "
            "| worst error (hip/knee) | IK marker error | worse than gaps left | samples left NaN "
            "| fill s | IK s |")
    lines = [head, "|---|" + "---:|" * 12]
    for s in summary:
        worse = "—" if s["worse_than_gaps"] is None else f"{s['worse_than_gaps']} of {s['masks']}"
        failed = f" (IK failed on {s['ik_failed']})" if s["ik_failed"] else ""
        lines.append(
            f"| {label(s['method'])}{failed} | {s['rmse_all']:.2f}° | {s['rmse_gap']:.2f}° "
            f"| {s['rmse_hip']:.2f}° | {s['rmse_knee']:.2f}° | {s['rmse_ankle']:.2f}° "
            f"| {s['rmse_pelvis_tilt']:.2f}° | {s['max_err']:.1f}° ({s['max_hip_knee']:.1f}°) "
            f"| {s['marker_rms_mm']:.1f} mm | {worse} | {s['nan_left']} "
            f"| {s['fill_s_median']:.2f} | {s['ik_s_median']:.2f} |")
    return "\n".join(lines)


def case_table(rows: list[dict], methods: list[str]) -> str:
    keys = sorted({(r["recording"], r["source"], r["seed"]) for r in rows},
                  key=lambda k: [(c[0], Path(c[1]).stem, c[2]) for c in CASES].index(k))
    lines = ["| mask | missing | " + " | ".join(methods) + " |",
             "|---|---:|" + "---:|" * len(methods)]
    by = {(r["recording"], r["source"], r["seed"], r["method"]): r for r in rows}
    for key in keys:
        cells = []
        for m in methods:
            r = by.get(key + (m,))
            cells.append("—" if r is None or "error" in r else f"{r['rmse_all']:.2f}° / {r['max_err']:.0f}°")
        pct = next(r["missing_pct"] for r in rows if (r["recording"], r["source"], r["seed"]) == key)
        lines.append(f"| {key[0]} ← {key[1]} (seed {key[2]}) | {pct:.1f} % | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_doc(path: Path, text: str) -> None:
    """Put ``text`` between the page's ``ik`` markers."""
    write_block(path, "ik", text, title="Fills judged by OpenSim inverse kinematics")


def add_arguments(p) -> None:
    p.add_argument("--methods", default=",".join(DEFAULT_RUN),
                   help="comma-separated, from: " + ", ".join(METHODS) + ", peer:NAME"
                   + " (gaps left is always run: the others are compared with it)")
    p.add_argument("--masks", type=int, default=N_MASKS,
                   help=f"how many masks, the first of the list (1-{len(CASES)}, "
                   f"default {N_MASKS})")
    p.add_argument("--doc", default=str(DOC), help="page to write the table into ('' : none)")
    p.add_argument("--results", default=str(RESULTS),
                   help="folder for the CSVs (resumable: rows there are not run again; '' : none)")
    p.add_argument("--redo", action="store_true", help="recompute rows already in --results")


def _labels() -> str:
    from torchfill.filling import default_method

    default = default_method()
    METHODS["default"] = (f"default as shipped (`fill(seq)`: {default})", METHODS["default"][1])
    METHODS["default_all"] = (f"default, everything filled (`extrapolate=None`: {default})",
                              METHODS["default_all"][1])
    return default


def main(args) -> int:
    default = _labels()
    methods = ["gaps"] + [m for m in args.methods.split(",") if m and m != "gaps" and not (
        m == default and args.methods == ",".join(DEFAULT_RUN))]     # the default is run already
    unknown = [m for m in methods if m not in METHODS and not m.startswith("peer:")]
    if unknown:
        raise SystemExit(f"ik: unknown method(s) {', '.join(unknown)}; expected some of "
                         f"{', '.join(METHODS)} or peer:NAME")
    if not 1 <= args.masks <= len(CASES):
        raise SystemExit(f"ik: --masks: expected 1 to {len(CASES)}, found {args.masks}")
    try:
        _opensim()
    except ImportError:
        raise SystemExit("ik: needs opensim (pip install opensim==4.6)") from None
    if not (data.folder() / "opensim").is_dir():
        raise SystemExit(f"ik: no OpenSim models under {data.folder() / 'opensim'}")
    folder = Path(args.results) if args.results else None
    done = Rows(folder / "ik_cases.csv" if folder else None, ("recording", "source", "seed", "method"))
    if args.redo:
        done.rows = [r for r in done.rows if r["method"] not in methods]
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_ik_") as tmp:
        run(methods, args.masks, Path(tmp), done)
    keys = {(name, Path(src).stem, str(seed)) for name, src, seed in CASES[:args.masks]}
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    command = "python -m benchmarks ik " + " ".join(shlex.quote(a) for a in sys.argv[2:])
    meta = {"command": f"OMP_NUM_THREADS={threads} {command.strip()}",
            "seconds": f"{time.perf_counter() - start:.0f}"}
    if folder:                                  # the page shows every stored run's methods
        runs = [r for r in read_csv(folder / "ik_run.csv") if r["command"] != meta["command"]
                and not set(r["methods"].split(",")) <= set(methods)]     # not rerun whole
        write_csv(folder / "ik_run.csv", runs + [meta | {"methods": ",".join(methods)}])
        rows, methods, meta = stored(folder)
    else:
        rows = [_typed(r) for r in done.rows if r["method"] in methods]
    rows = [r for r in rows if (r["recording"], r["source"], str(r["seed"])) in keys]
    summary = summarise(rows, methods)
    text = doc_text(rows, methods, summary, meta)
    print()
    print(text)
    if folder:
        write_csv(folder / "ik_summary.csv", summary)
    if args.doc:
        write_doc(Path(args.doc), text)
    return 0


def _typed(r: dict) -> dict:
    """A stored row with its numbers as floats (and ints for the counts)."""
    out = {}
    for k, v in r.items():
        if k in ("recording", "source", "method", "max_coord", "writer", "error") or v == "":
            out[k] = v
        else:
            out[k] = int(float(v)) if k in ("seed", "nan_left") else float(v)
    return out


def doc_text(rows: list[dict], methods: list[str], summary: list[dict], meta: dict) -> str:
    return (f"Generated by `{meta['command']}` "
            f"({len({(r['recording'], r['source'], r['seed']) for r in rows})} masks). "
            "Joint-angle RMSE against IK on the "
            "complete recording, mean over masks; worst error: the largest single error of any "
            "free rotational coordinate over all masks (in brackets: hip and knee flexion); "
            "IK marker error: mean over masks and frames of IK's RMS marker error; fill s / IK s: "
            "medians per mask. "
            f"{sum(r.get('writer') == 'opensim' for r in rows)} of {len(rows)} TRC files "
            "written by `torchfill.write` were rejected by OpenSim's reader (a row whose last "
            "marker is missing ends short) and were written by OpenSim's own TRC writer "
            "instead.\n\n" + table(summary)
            + "\n\nPer mask: RMSE over all frames / largest single error.\n\n"
            + case_table(rows, methods))


def _methods(runs: list[dict]) -> list[str]:
    """The methods of the stored runs, in order: a later run (``--redo`` of a few methods)
    replaces those methods' rows and keeps the others'."""
    return list(dict.fromkeys(m for r in runs for m in r["methods"].split(",")))


def stored(folder: Path = RESULTS) -> tuple[list[dict], list[str], dict] | None:
    """The stored rows, methods and commands of the stored runs (None when absent)."""
    runs = read_csv(folder / "ik_run.csv")
    if not runs:
        return None
    methods = _methods(runs)
    meta = {"command": "`, then `".join(r["command"] for r in runs)}
    rows = [_typed(r) for r in read_csv(folder / "ik_cases.csv") if r["method"] in methods]
    return rows, methods, meta


def doc_blocks() -> dict:
    got = stored()
    if got is None:
        return {}
    _labels()
    rows, methods, meta = got
    return {(DOC, "ik"): doc_text(rows, methods, summarise(rows, methods), meta)}

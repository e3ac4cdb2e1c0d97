"""The argument parser of every verb."""
from __future__ import annotations

import argparse

from .evaluate import _cmd_evaluate
from .experiment import _cmd_experiment
from .fill import _cmd_fill
from .info import _cmd_info, _cmd_methods
from .qc import _cmd_qc


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="torchfill", description=(
        "Fill gaps in motion-capture marker data (C3D, TRC, .npy/.npz/.csv) and 2-D keypoint "
        "tracks (OpenPose output folders)."))
    parser.add_argument("--version", action="version", version="torchfill 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in (_add_fill, _add_qc, _add_evaluate, _add_info, _add_methods, _add_experiment):
        add(sub)
    return parser


def _add_fill(sub) -> None:
    p = sub.add_parser("fill", help="fill the gaps of a recording and write the result",
                       description="Fill the gaps of IN and write OUT; everything else in the file "
                                   "is kept, filled C3D samples get residual 0.")
    p.add_argument("input", metavar="IN", nargs="+",
                   help="recording(s): files, folders or glob patterns (several need --out-dir)")
    p.add_argument("-o", "--output", metavar="OUT", help="output file (default: IN_filled.EXT)")
    p.add_argument("--out-dir", metavar="DIR", help="write each filled recording here, same name")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="fill N files at once in separate processes (default 1)")
    p.add_argument("--ray", metavar="ADDRESS", help="distribute the files as Ray tasks: 'auto' "
                   "(a running cluster), 'local' (start one here) or ray://HOST:PORT")
    p.add_argument("-m", "--method", help="method name (see 'torchfill methods'; default: the best)")
    p.add_argument("--max-gap", type=int, metavar="FRAMES", help="leave longer gaps unfilled")
    p.add_argument("--window", type=int, metavar="FRAMES",
                   help="fill longer recordings in overlapping windows of this many frames "
                        "(default 6000; 0: the whole recording at once)")
    p.add_argument("--training", nargs="+", metavar="FILE",
                   help="training recordings (files or folders): other trials of the same marker "
                        "set whose observed samples the spatial models and the default learn from "
                        "(methods with training data: 'torchfill methods -v')")
    p.add_argument("--session", action="store_true",
                   help="with several inputs: every input is training for the others of its "
                        "marker set (their observed samples only; read once, one pool per "
                        "marker set)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a method hyperparameter (repeatable), e.g. -p max_iter=200; "
                        "values as 'methods -v' shows them (True, None, (8, 8, 3)) or JSON")
    p.add_argument("--axes", metavar="TURN",
                   help="TRC output: turn every sample, 'zup-to-yup' (a lab's Z-up to OpenSim's "
                        "Y-up), 'yup-to-zup' or a signed permutation such as 'x,z,-y'")
    p.add_argument("--units", choices=("m", "cm", "mm"),
                   help="TRC output: write every sample in these units (OpenSim: m)")
    p.add_argument("--report", metavar="REPORT.html", help="also write the qc report of the fill "
                   "(several inputs: a folder, or a name with {stem})")
    p.add_argument("--report-json", metavar="REPORT.json",
                   help="also write the qc verdicts as JSON (one object per gap)")
    p.add_argument("--no-constraints", dest="constraints", action="store_false",
                   help="the method's own fill, as in its paper (no rigid donors, edge blending, "
                        "step limit, volume clamp or extrapolation limit)")
    p.add_argument("--dtype", choices=("float32", "float64"),
                   help="what the method computes in (default: its own, float32 for tucker and "
                        "tucker_tnn); observed samples are written as read either way")
    p.add_argument("--std", metavar="OUT.csv", help="write the estimated error std per filled "
                   "sample here (frames x markers, data units, NaN where observed); by default "
                   "the default method's estimate goes beside the output as OUT.EXT.std.csv, "
                   "where 'torchfill qc' finds it; 'none': not written")
    p.add_argument("--rejected", choices=("keep", "drop"), default=None,
                   help="gaps whose fill the qc verdict rejects: 'drop' leaves them NaN (counted "
                        "and named), 'keep' writes them, marked: a C3D records each fill's "
                        "verdict in its TORCHFILL parameter group, other formats in the std "
                        "file that qc reads; default: keep")
    p.add_argument("--extrapolate", metavar="SECONDS",
                   help="seconds a gap at a trial end may be extrapolated in time, in frames "
                        "too empty for a spatial fill (default 0.25); with a limit, markers never "
                        "seen in two consecutive frames, and uncertain fills of a marker whose "
                        "segment-mates are never observed, are left NaN too; 'none': no limit, "
                        "every sample filled")
    p.add_argument("--in-place", action="store_true",
                   help="write the fill onto IN itself (keeps the original as NAME.orig.EXT unless "
                        "--no-backup)")
    p.add_argument("--no-backup", action="store_true", help="with --in-place: keep no .orig copy")
    p.add_argument("--segments", metavar="FILE",
                   help="which markers move together: a YAML file as 'torchfill info IN "
                        "--segments' prints, 'names' (marker-set tables) or 'data' (found in the "
                        "recording); default: the tables when the labels fit, else the data")
    _add_run_options(p)
    p.set_defaults(run=_cmd_fill)


def _add_qc(sub) -> None:
    p = sub.add_parser("qc", help="which filled gaps to trust: a per-gap report (text + HTML)",
                       description="Judge the fill FILLED of IN gap by gap (interpolated or "
                                   "extrapolated, rigid donors, rigid deviation, edge jump, "
                                   "largest step, outside the volume) and write an HTML report.")
    p.add_argument("input", metavar="IN")
    p.add_argument("filled", metavar="FILLED")
    p.add_argument("-o", "--output", metavar="REPORT.html",
                   help="HTML report (default: FILLED with suffix .qc.html)")
    p.add_argument("--json", metavar="OUT.json", help="also write the verdicts as JSON, one object "
                   "per gap: marker, first_frame, last_frame (the file's numbering), verdict, "
                   "est_rmse (file units), reasons, segment ('-': print it instead of the table)")
    p.add_argument("--std", metavar="STD.csv",
                   help="the fill's error estimate ('fill --std' output): verdicts use it "
                        "(default: FILLED.std.csv beside FILLED, as 'fill' writes it, when it is "
                        "not older than FILLED)")
    p.add_argument("-m", "--method", help="the method that made FILLED (default: the default "
                   "method); a spatial method's trial-end fills in frames with enough markers "
                   "seen do not count as extrapolated in time")
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="no progress and no summary: only warnings and errors (-qq: only errors)")
    _add_pose_options(p)
    p.set_defaults(run=_cmd_qc)


def _add_evaluate(sub) -> None:
    p = sub.add_parser("evaluate", help="simulate gaps on complete markers and score methods",
                       description="Simulate gaps on the complete markers of IN, fill them with "
                                   "each method and print the metrics against the truth.")
    p.add_argument("input", metavar="IN")
    p.add_argument("-m", "--method", action="append", default=[],
                   help="method(s), repeatable or comma-separated (default: baselines + the best)")
    p.add_argument("--protocol", default="multi_gap",
                   choices=["multi_gap", "shared_window", "continuous_runs", "evenly_spaced",
                            "blackout", "random_entries"])
    p.add_argument("--markers", type=int, default=20, help="markers with gaps (default 20)")
    p.add_argument("--gap-length", type=int, default=100, help="frames per gap (default 100)")
    p.add_argument("--max-gaps", type=int, default=5, help="gaps per marker, at most (default 5)")
    p.add_argument("--rate", type=float, default=0.2, help="missing rate for random_entries")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="hyperparameter for a single method")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    _add_run_options(p)
    p.set_defaults(run=_cmd_evaluate)


def _add_info(sub) -> None:
    p = sub.add_parser("info", help="frames, markers, and gaps per marker")
    p.add_argument("input", metavar="IN")
    p.add_argument("--all-markers", action="store_true", help="list markers without gaps too")
    p.add_argument("--all-points", action="store_true",
                   help="include model outputs and virtual points (C3D)")
    p.add_argument("--segments", nargs="?", const="auto", metavar="SOURCE",
                   help="print the segments a fill uses (YAML to edit and pass back with fill "
                        "--segments FILE); SOURCE: 'names', 'data', a YAML file or the default")
    _add_pose_options(p)
    p.set_defaults(run=_cmd_info)


def _add_methods(sub) -> None:
    p = sub.add_parser("methods", help="list the registered methods")
    p.add_argument("-v", "--verbose", action="store_true", help="show hyperparameters and defaults")
    p.set_defaults(run=_cmd_methods)


def _add_experiment(sub) -> None:
    p = sub.add_parser("experiment", help="run an experiment config (YAML) with the Lightning runner")
    p.add_argument("config", metavar="CONFIG")
    p.add_argument("--resume", action="store_true", help="skip cases already finished")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (default 1)")
    p.add_argument("--limit", type=int, help="run at most this many cases")
    p.add_argument("--output", help="output folder (default: results/<name> beside the config)")
    p.add_argument("--report-only", action="store_true",
                   help="only rewrite table.md and the plots from the cases.csv there")
    p.add_argument("--ray", metavar="ADDRESS", help="run the cases as Ray tasks: 'auto', 'local' "
                   "or ray://HOST:PORT (every node needs the recordings at the same path)")
    p.set_defaults(run=_cmd_experiment)


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """-q, threads and pose options: shared by the verbs that fill."""
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="no progress and no summary: only warnings and errors (-qq: only errors)")
    _add_threads(p)
    _add_pose_options(p)


def _add_threads(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=int, metavar="N",
                   help="torch threads (default: OMP_NUM_THREADS, else the idle cores, at least 1)")


def _add_pose_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--min-confidence", type=float, metavar="C",
                   help="OpenPose folder: keypoints with confidence below C are missing "
                        "(default: only confidence 0)")

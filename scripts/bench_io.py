"""Time reading and writing recordings (torchfill.io vs the c3d package and ezc3d readers).

Usage: ``python scripts/bench_io.py [DATA_DIR] [--repeat N]``. Prints one markdown table row per
file: best-of-N wall time of each operation in milliseconds. "write-back" writes a sequence read
from the file back into a copy of it: unchanged (no filled samples) and with 5% of the samples
filled; "fresh" writes a new C3D through c3d.Writer.
"""
from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import torchfill
from torchfill.data import data_dir

DEFAULT = data_dir(Path(__file__).resolve().parents[1])
FILES = ["hdm05_bd_05-01_01_120.c3d", "cmu_135_02.c3d", "ktk_walk.c3d",
         "numediart_03_rolling.c3d", "biomechzoo_hockey_wrist_shot_009.c3d",
         "ktk_racing_full.c3d", "osim_hamner_subject02_running.trc"]


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * min(times)


def c3d_package_read(path):
    import c3d
    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return [p for _, p, _ in c3d.Reader(handle).read_frames()]


def ezc3d_read(path):
    import ezc3d
    return ezc3d.c3d(str(path))["data"]["points"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_dir", nargs="?", default=DEFAULT)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    data = Path(args.data_dir)
    print("| file | MB | frames x points | read | write-back, unchanged | write-back, 5% filled "
          "| fresh C3D | c3d pkg read | ezc3d read |")
    print("|---|---|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        for name in FILES:
            path = data / name
            if not path.is_file():
                continue
            seq = torchfill.read(path)
            out = Path(tmp) / name
            t_read = best(lambda: torchfill.read(path), args.repeat)
            t_same = best(lambda: torchfill.write(seq, out), args.repeat)
            mark = rng.random(seq.mask.shape) < 0.05
            points = seq.points.copy()
            points[mark] = np.nan_to_num(points[mark], nan=1.0) + 0.5
            filled = seq.with_points(points)
            filled.meta["filled"] = mark
            t_fill = best(lambda: torchfill.write(filled, out), args.repeat)
            fresh = seq.with_points(seq.points)
            fresh.source = None
            fresh_out = out.with_suffix(".fresh.c3d")
            t_fresh = best(lambda: torchfill.write(fresh, fresh_out), max(1, args.repeat // 2))
            if path.suffix == ".c3d":
                try:
                    t_pkg = f"{best(lambda: c3d_package_read(path), 1):.0f}"
                except Exception as err:  # the package fails on ktk_racing_full.c3d
                    t_pkg = f"fails ({type(err).__name__})"
                t_ez = f"{best(lambda: ezc3d_read(path), args.repeat):.0f}"
                shape = f"{seq.n_frames} x {seq.meta['c3d']['n_points']}"
            else:
                t_pkg = t_ez = "-"
                shape = f"{seq.n_frames} x {seq.n_markers}"
            print(f"| {name} | {path.stat().st_size / 1e6:.1f} | {shape} | {t_read:.0f} | "
                  f"{t_same:.0f} | {t_fill:.0f} | {t_fresh:.0f} | {t_pkg} | {t_ez} |")


if __name__ == "__main__":
    main()

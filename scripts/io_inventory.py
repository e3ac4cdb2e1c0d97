"""Inventory of the shared recordings as torchfill reads them (markdown table on stdout).

Usage: ``python scripts/io_inventory.py [DATA_DIR]``. For every .c3d/.trc/.csv file: points in
the file, markers kept, units, rate, missing % as read, the points excluded as non-markers, the
C3D storage (processor, word format), and whether ``torchfill info`` exits 0 on it.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import warnings
from collections import Counter
from pathlib import Path

import torchfill
from torchfill.cli import main as cli
from torchfill.data import data_dir

DEFAULT = data_dir(Path(__file__).resolve().parents[1])


def run() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", type=Path, default=DEFAULT, help="folder of recordings")
    data = parser.parse_args().data
    print("| file | points in file | frames x markers read | units | rate (Hz) | missing % | "
          "never observed | excluded as non-markers | storage | `info` |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path in sorted(p for p in data.iterdir() if p.suffix.lower() in (".c3d", ".trc", ".csv")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            seq = torchfill.read(path)
        c3d = seq.meta.get("c3d")
        in_file = c3d["n_points"] if c3d else seq.n_markers
        excluded = Counter(reason[len("model output ("):-1] if reason.startswith("model output")
                           else reason for _, _, reason in seq.meta.get("excluded", []))
        excluded_text = ", ".join(f"{n} {why}" for why, n in sorted(excluded.items())) or "-"
        storage = f"{c3d['processor']} {c3d['format']}" if c3d else path.suffix[1:].upper()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            code = cli(["info", str(path)])
        never = int(seq.mask.all(axis=0).sum())
        print(f"| {path.name} | {in_file} | {seq.n_frames} x {seq.n_markers} | {seq.units} | "
              f"{seq.rate:g} | {100 * seq.mask.mean():.2f} | {never} | {excluded_text} | "
              f"{storage} | {'ok' if code == 0 else f'exit {code}'} |")


if __name__ == "__main__":
    run()

"""Start-up time of the CLI: from process start until the fill itself begins.

Usage: ``python scripts/bench_startup.py [--repeat N]``. Each row is the median over N fresh
interpreters (``sys.executable``, this environment with ``OMP_NUM_THREADS`` as set; the commands
run interleaved, after one untimed round that writes the bytecode, so torchfill loads from .pyc
as when installed) of the wall time and the CPU time (user + system), each also as a ratio to
``import torch`` measured in the same run: the floor every fill pays, and on a shared, loaded
machine the ratios say more than the seconds.

- ``import torch`` (then ``os._exit``: the floor), ``import torch`` with the normal exit,
  ``import torchfill``;
- ``torchfill fill --help`` and ``torchfill methods`` (no fill, no torch);
- ``torchfill fill`` on the embedded sample with gaps (the demo's gappy copy,
  ``scripts/demo.sh``), stopped when ``fill()`` hands the first window to the solver: imports,
  argument parsing, the checks of every path, reading the file and ``fill()``'s validation and
  segments. A meta-path hook patches the window step after ``torchfill.filling`` loads; the
  child reports its wall clock and CPU time at the end of the read and at that step, then exits
  at once (nothing is filled or written). "Not importing torch" is that minus the time the
  child spent importing torch and NumPy (which ``import torch`` imports too): what torchfill
  adds to the floor plus Python's own start, measured in one process, so the load's noise on
  the torch import drops out.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: The child of the fill row: ``torchfill.cli.main`` with ``time.time()`` and ``time.process_time()``
#: recorded when the read ends and when the solver starts, printed as JSON; it exits there.
PROBE = r"""
import importlib.abc, importlib.machinery, json, os, sys, time
marks = {}

def mark(name):
    marks.setdefault(name, (time.time(), time.process_time()))

def stop():
    mark("solver")
    print("MARKS" + json.dumps(marks), flush=True)
    os._exit(0)

def patch(name, module):
    if name == "torchfill.io":
        read = module.read
        def timed_read(*a, **k):
            out = read(*a, **k)
            mark("read")
            return out
        module.read = timed_read
    elif name == "torchfill.filling":
        module._fill_window = lambda *a, **k: stop()

def timed(run, module):
    wall, cpu = time.time(), time.process_time()
    run(module)
    took = marks.get("floor", (0.0, 0.0))
    marks["floor"] = (took[0] + time.time() - wall, took[1] + time.process_time() - cpu)

class Hook(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name not in ("torchfill.io", "torchfill.filling", "torch", "numpy"):
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        run = spec.loader.exec_module
        def exec_module(module):
            if name in ("torch", "numpy"):       # the floor's imports, as the floor has them
                return timed(run, module)
            run(module)
            patch(name, module)
        spec.loader.exec_module = exec_module
        return spec

sys.meta_path.insert(0, Hook())
from torchfill.cli import main
sys.exit(main(sys.argv[1:]))
"""


#: The floor: ``import torch`` and exit at once, as the fill row stops (the interpreter's normal
#: exit with torch loaded adds its teardown, shown in the next row).
FLOOR = "import torch (floor)"


def gappy_sample(path: Path) -> None:
    """The demo's gappy copy of the embedded sample (scripts/demo.sh): 10 markers, up to 3 gaps
    of 60 frames, seed 1."""
    import numpy as np

    import torchfill
    from torchfill import gaps
    from torchfill.data import load_sample

    seq = load_sample()
    mask = gaps.multi_gap(seq.n_frames, seq.n_markers, n_markers=10, gap_length=60, max_gaps=3,
                          seed=1)
    gappy = seq.with_points(np.where(mask[..., None], np.nan, seq.points))
    gappy.source = None
    torchfill.write(gappy, path)


def _env() -> dict[str, str]:
    """This environment, writing bytecode: torchfill is timed from its .pyc files, as installed
    (the first, untimed round writes them)."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def run(argv: list[str], env: dict[str, str]) -> dict[str, float]:
    """Wall and CPU (user + system) seconds of one run of ``argv``, from just before it starts;
    for the probe also the wall and CPU seconds of its marks."""
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.time()
    done = subprocess.run(argv, check=True, capture_output=True, text=True, env=env)
    took = {"wall": time.time() - start}
    now = resource.getrusage(resource.RUSAGE_CHILDREN)
    took["cpu"] = now.ru_utime + now.ru_stime - used.ru_utime - used.ru_stime
    for line in done.stdout.splitlines():
        if line.startswith("MARKS"):
            for mark, (at, cpu) in json.loads(line[len("MARKS"):]).items():
                took[f"{mark} wall"], took[f"{mark} cpu"] = at - start * (mark != "floor"), cpu
    return took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    n = parser.parse_args().repeat
    print(f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '(unset)')}, "
          f"load {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores, median of {n} "
          "(the commands interleaved)")
    env, py = _env(), sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "sample_gappy.c3d"
        gappy_sample(src)
        commands = {FLOOR: [py, "-c", "import os, torch; os._exit(0)"],
                    "import torch, with the exit": [py, "-c", "import torch"],
                    "import torchfill": [py, "-c", "import torchfill"],
                    "torchfill fill --help": [py, "-m", "torchfill", "fill", "--help"],
                    "torchfill methods": [py, "-m", "torchfill", "methods"],
                    "torchfill fill SAMPLE": [py, "-c", PROBE, "fill", str(src),
                                              "-o", str(Path(tmp) / "out.c3d")]}
        runs = {name: [] for name in commands}
        for round_ in range(n + 1):
            for name, argv in commands.items():
                took = run(argv, env)
                if round_:                           # round 0 writes the bytecode
                    runs[name].append(took)
    floor = {k: statistics.median(r[k] for r in runs[FLOOR])
             for k in ("wall", "cpu")}
    rows = {name: {k: statistics.median(r[k] for r in rs) for k in ("wall", "cpu")}
            for name, rs in runs.items() if name != "torchfill fill SAMPLE"}
    fill = runs["torchfill fill SAMPLE"]
    for mark, label in (("read", "file read"), ("solver", "solver starts")):
        rows[f"torchfill fill SAMPLE: {label}"] = {
            k: statistics.median(r[f"{mark} {k}"] for r in fill) for k in ("wall", "cpu")}
    rows["  not importing torch (Python's start too)"] = {
        k: statistics.median(r[f"solver {k}"] - r[f"floor {k}"] for r in fill)
        for k in ("wall", "cpu")}
    print(f"{'':40s} {'wall':>7s} {'x floor':>8s} {'CPU':>7s} {'x floor':>8s}")
    for name, t in rows.items():
        print(f"{name:40s} {t['wall']:6.3f}s {t['wall'] / floor['wall']:8.2f} "
              f"{t['cpu']:6.3f}s {t['cpu'] / floor['cpu']:8.2f}")


if __name__ == "__main__":
    main()

"""Time, CPU time, peak memory and accuracy of fills.

``--long`` (the default mode): one HDM05 recording (hdm05_bd_05-01_01_120: 5920 frames, 41
markers, 120 Hz) played forward and backward to each length, so the motion stays continuous and
one subject's marker distances hold throughout; every 3 000-frame block gets the Tucker paper's
gaps (``gaps.multi_gap``: 20 markers, up to 5 gaps each) of a random length in 100..200 frames,
so the gap density is the same at every length. Each length runs in a fresh process: its peak
RSS (``resource.getrusage``), the largest peak of its children (the worker processes of the
later windows) and the largest sum of all their resident sizes (:class:`Resident`), the CPU
seconds of the process and of its children; besides the time and the RMSE, the error
estimate's checks (per-gap Spearman of estimated vs real error, share of filled coordinates
within 2 std).
``--device cuda`` hands the fill a torch tensor on that device (the time then includes the copies).

``--methods A,B`` instead times each method ``--repeat`` times on the first 3 000 frames of that
recording (median wall and CPU seconds, peak memory above the start, RMSE)::

    OMP_NUM_THREADS=2 nice python -m benchmarks speed --frames 3000 12000 36000 120000
    OMP_NUM_THREADS=1 nice python -m benchmarks speed --frames 12000 --window 600 1200 2400 0
    OMP_NUM_THREADS=1 nice python -m benchmarks speed --methods pma,tucker_tnn,rigid --repeat 3
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time

import numpy as np

from .. import data, methods
from ..rows import Rows
from ..scores import std_checks
from ..tables import markdown

HELP = "time, CPU, peak memory and accuracy on long recordings (--methods: per method)"
FILE = "hdm05_bd_05-01_01_120.c3d"
BLOCK = 3000
CSV = data.RESULTS / "speed" / "methods.csv"


def recording(frames: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth ``(frames, 41, 3)`` and its simulated-gap mask."""
    import torchfill
    from torchfill import gaps

    clip = torchfill.read(data.folder() / FILE).points
    period = np.concatenate([clip, clip[::-1]])                  # forward, then backward
    truth = np.concatenate([period] * -(-frames // len(period)))[:frames]
    rng = np.random.default_rng(seed)
    mask = np.zeros(truth.shape[:2], dtype=bool)
    for a in range(0, frames, BLOCK):
        n = min(BLOCK, frames - a)
        mask[a:a + n] = gaps.multi_gap(n, truth.shape[1], n_markers=20,
                                       gap_length=int(rng.integers(100, 201)),
                                       seed=int(rng.integers(2**31)))
    return truth, mask


def one(frames: int, method: str | None, window: int | None, device: str | None = None) -> dict:
    import torch

    import torchfill
    from torchfill import metrics

    truth, mask = recording(frames)
    given = np.where(mask[..., None], np.nan, truth)
    del truth                   # a user's process holds the gapped recording alone: the peak
    start, cpu = time.perf_counter(), _cpu()                    # RSS is the fill's
    with Resident() as resident:
        if device is None:
            out, std = torchfill.fill(given, method, window=window, return_std=True)
        else:
            out, std = (t.cpu().numpy() for t in torchfill.fill(
                torch.from_numpy(given).to(device), method, window=window, return_std=True))
    seconds = time.perf_counter() - start
    cpu = [now - before for now, before in zip(_cpu(), cpu)]
    truth, _ = recording(frames)
    assert np.array_equal(out[~mask], truth[~mask])
    rho, within, _ = std_checks(out, std, truth, mask)
    return {"frames": frames, "method": method or torchfill.default_method(),
            "window": window, "device": device or "numpy", "seconds": round(seconds, 2),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
            "children_peak_rss_mb": resident.children, "total_peak_rss_mb": resident.total,
            "cpu_s": round(cpu[0], 1), "children_cpu_s": round(cpu[1], 1),
            "rmse_missing_mm": round(metrics.rmse_missing(out, truth, mask), 2),
            "gap_error_mm": round(metrics.gap_error(out, truth, mask), 2),
            "std_spearman": round(rho, 2), "within_2std": round(within, 3)}


class Resident:
    """Resident memory of this process and its children while it is entered, sampled from /proc
    every ``every`` seconds: ``children``, the largest child's peak (``VmHWM``: its own, where
    ``RUSAGE_CHILDREN``'s ``ru_maxrss`` counts what a child shared with this process when it was
    forked), and ``total``, the largest sum of this process's and its children's resident sizes
    (MB; 0 without /proc)."""

    def __init__(self, every: float = 0.1):
        self.every, self.children, self.total = every, 0, 0
        self.stop = threading.Event()

    def __enter__(self) -> "Resident":
        self.thread = threading.Thread(target=self._sample, daemon=True)
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join()

    def _sample(self) -> None:
        me = os.getpid()
        if not os.path.isdir(f"/proc/{me}/task"):
            return
        while not self.stop.wait(self.every):
            pids = set()                     # a thread's children are listed under it
            for task in os.listdir(f"/proc/{me}/task"):
                try:
                    with open(f"/proc/{me}/task/{task}/children") as f:
                        pids.update(int(p) for p in f.read().split())
                except OSError:
                    pass
            now = _status(me)["VmRSS"]
            for pid in pids:
                kb = _status(pid)
                now += kb["VmRSS"]
                self.children = max(self.children, round(kb["VmHWM"] / 1024))
            self.total = max(self.total, round(now / 1024))


def _status(pid: int) -> dict:
    """``VmRSS`` and ``VmHWM`` of a process in kB (0 once it is gone)."""
    kb = {"VmRSS": 0, "VmHWM": 0}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                key = line.split(":")[0]
                if key in kb:
                    kb[key] = int(line.split()[1])
    except OSError:
        pass
    return kb


def _cpu() -> tuple[float, float]:
    """CPU seconds (user + system) of this process and of its finished children (the worker
    processes of a long recording's later windows)."""
    own, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime


def add_arguments(p) -> None:
    p.add_argument("--frames", type=int, nargs="+", default=[3000, 12000, 36000, 120000])
    p.add_argument("--window", type=int, nargs="+", default=[-1],
                   help="window lengths (0 = whole recording, -1 = the default)")
    p.add_argument("--method", default=None, help="the long recordings' method (default: fill's)")
    p.add_argument("--device", default=None, help="e.g. cuda: fill a torch tensor there")
    p.add_argument("--timeout", type=float, default=900)
    p.add_argument("--methods", help="instead: time these methods on 3 000 frames")
    p.add_argument("--repeat", type=int, default=3, help="with --methods: runs per method")
    p.add_argument("--csv", default=str(CSV), help="with --methods: rows ('' : none)")
    p.add_argument("--one", nargs=2, type=int, help=argparse.SUPPRESS)


def main(args) -> int:
    if args.one:
        from torchfill.windows import WINDOW
        window = {-1: WINDOW, 0: None}.get(args.one[1], args.one[1])
        print(json.dumps(one(args.one[0], args.method, window, args.device)))
        return 0
    if args.methods:
        return per_method(args.methods.split(","), args.repeat, args.csv)
    data.need(FILE)
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    for window in args.window:
        for frames in args.frames:
            cmd = [sys.executable, "-m", "benchmarks", "speed", "--one", str(frames), str(window)]
            cmd += ["--method", args.method] if args.method else []
            cmd += ["--device", args.device] if args.device else []
            try:
                res = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout,
                                     cwd=data.REPO)
                line = res.stdout.strip().splitlines()[-1] if res.returncode == 0 else \
                    f"failed: {res.stderr.strip().splitlines()[-1:]}"
            except subprocess.TimeoutExpired:
                line = f"frames {frames} window {window}: timed out after {args.timeout:.0f} s"
            print(line, flush=True)
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    return 0


def per_method(names: list[str], repeat: int, csv: str) -> int:
    """Each method ``repeat`` times on 3 000 frames: medians of wall, CPU and peak memory."""
    import torchfill

    from ..scores import rmse

    truth, mask = recording(BLOCK)
    seq = torchfill.MarkerSequence(points=np.where(mask[..., None], np.nan, truth),
                                   labels=[f"m{j}" for j in range(truth.shape[1])], rate=120.0,
                                   units="mm")
    rows = Rows(csv or None, ("method",))
    body = []
    for name in names:
        runs = [methods.run(name, seq) for _ in range(repeat)]
        row = {"method": name, "frames": BLOCK, "repeat": repeat,
               "wall": float(np.median([r.timing.wall for r in runs])),
               "cpu": float(np.median([r.timing.cpu for r in runs])),
               "peak_mb": float(np.median([r.timing.peak_mb for r in runs])),
               "rmse": rmse(runs[0].points, truth, mask)}
        rows.add(row)
        body.append([name, row["wall"], row["cpu"], row["peak_mb"], row["rmse"]])
        print(f"{name}: {row['wall']:.2f} s wall, {row['cpu']:.2f} s CPU, "
              f"{row['peak_mb']:.0f} MB, RMSE {row['rmse']:.2f} mm", flush=True)
    print(markdown(["method", "wall s", "CPU s", "peak MB", "RMSE mm"], body))
    return 0

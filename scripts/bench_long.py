"""Long recordings: time, peak memory and accuracy of the default fill against the frame count.

One HDM05 recording (hdm05_bd_05-01_01_120: 5920 frames, 41 markers, 120 Hz) played forward and
backward to each length, so the motion stays continuous and one subject's marker distances hold
throughout (concatenating different recordings put teleports and another subject's distances into
the truth: at 120 000 frames the 74 gaps across a junction came out at 89 mm after the constraints'
step limit, 8 mm before); every 3 000-frame block gets the Tucker paper's gaps (``gaps.multi_gap``:
20 markers, up to 5 gaps each) of a random length in 100..200 frames, so the gap density is the
same at every length.
Each length runs in a fresh process (peak RSS from ``resource.getrusage``); besides the time and
the RMSE, the error estimate's checks of the real-gap suite (per-gap Spearman of estimated vs real
error, share of filled coordinates within 2 std). The default's
candidates run side by side only with two threads or more (``OMP_NUM_THREADS=1``: one after the
other, 25 s instead of 15 s at 3 000 frames).

    OMP_NUM_THREADS=2 nice python scripts/bench_long.py --frames 3000 12000 36000 120000
    OMP_NUM_THREADS=1 nice python scripts/bench_long.py --frames 12000 --window 600 1200 2400 0

``--device cuda`` hands the fill a torch tensor on that device (the API keeps the device); the
time then includes the copies to and from it.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's torchfill, also in the per-length subprocesses
from torchfill.data import data_dir  # noqa: E402  (this checkout's, after the path)
from real_gap_suite import std_checks  # noqa: E402  (the suites' checks of the error estimate)

DATA = data_dir(ROOT)   # $TORCHFILL_DATA or ../shared/data
FILE = "hdm05_bd_05-01_01_120.c3d"
BLOCK = 3000


def recording(frames: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth ``(frames, 41, 3)`` and its simulated-gap mask."""
    import torchfill
    from torchfill import gaps

    clip = torchfill.read(DATA / FILE).points
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
    start = time.perf_counter()                                 # RSS is the fill's
    if device is None:
        out, std = torchfill.fill(given, method, window=window, return_std=True)
    else:
        out, std = (t.cpu().numpy() for t in torchfill.fill(
            torch.from_numpy(given).to(device), method, window=window, return_std=True))
    seconds = time.perf_counter() - start
    truth, _ = recording(frames)
    assert np.array_equal(out[~mask], truth[~mask])
    rho, within, _ = std_checks(out, std, truth, mask)
    return {"frames": frames, "method": method or torchfill.default_method(),
            "window": window, "device": device or "numpy", "seconds": round(seconds, 2),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
            "rmse_missing_mm": round(metrics.rmse_missing(out, truth, mask), 2),
            "gap_error_mm": round(metrics.gap_error(out, truth, mask), 2),
            "std_spearman": round(rho, 2), "within_2std": round(within, 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[3000, 12000, 36000, 120000])
    parser.add_argument("--window", type=int, nargs="+", default=[-1],
                        help="window lengths (0 = whole recording, -1 = the default)")
    parser.add_argument("--method", default=None)
    parser.add_argument("--device", default=None, help="e.g. cuda: fill a torch tensor there")
    parser.add_argument("--timeout", type=float, default=900)
    parser.add_argument("--one", nargs=2, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        from torchfill.windows import WINDOW
        window = {-1: WINDOW, 0: None}.get(args.one[1], args.one[1])
        print(json.dumps(one(args.one[0], args.method, window, args.device)))
        return
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    for window in args.window:
        for frames in args.frames:
            cmd = [sys.executable, __file__, "--one", str(frames), str(window)]
            if args.method:
                cmd += ["--method", args.method]
            if args.device:
                cmd += ["--device", args.device]
            try:
                res = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
                line = res.stdout.strip().splitlines()[-1] if res.returncode == 0 else \
                    f"failed: {res.stderr.strip().splitlines()[-1:]}"
            except subprocess.TimeoutExpired:
                line = f"frames {frames} window {window}: timed out after {args.timeout:.0f} s"
            print(line, flush=True)
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()

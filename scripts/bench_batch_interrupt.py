"""Ctrl-C on a batch: how soon does it stop writing, and what is left?

Makes N synthetic recordings, starts ``torchfill fill DIR --out-dir OUT --workers W`` in its own
session, waits until K outputs exist, sends SIGINT to the whole process group (what a terminal's
^C does), then watches OUT until 3 s after the command exited. Prints: seconds from the SIGINT to
the exit, files that appeared or changed after the SIGINT and when (seconds after it), temporary
files left, processes of the run still alive, the exit status and the last line of stderr.

    python scripts/bench_batch_interrupt.py [--files 40] [--workers 2] [--after 1] [--repeat 3]
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def make_inputs(folder: Path, n: int) -> None:
    rng = np.random.default_rng(0)
    t = np.linspace(0, 15, 1500)[:, None, None]
    for k in range(n):
        X = 500 + 100 * np.sin(2 * np.pi * t + rng.uniform(0, 6, (1, 12, 3)))
        X[300:420, 2] = np.nan
        X[800:850, 7] = np.nan
        np.savez(folder / f"t{k:02d}.npz", points=X,
                 labels=np.array([f"M{j}" for j in range(12)]), rate=100.0, units="mm")


def state(folder: Path) -> dict[str, int]:
    out = {}
    try:
        for entry in os.scandir(folder):
            try:
                out[entry.name] = entry.stat(follow_symlinks=False).st_mtime_ns
            except OSError:
                pass
    except OSError:
        pass
    return out


def tagged(tag: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if f"BENCH_TAG={tag}".encode() in (entry / "environ").read_bytes():
                    found.append(int(entry.name))
            except OSError:
                pass
    return found


def once(args, work: Path) -> dict:
    out = work / f"out-{uuid.uuid4().hex[:6]}"
    tag = uuid.uuid4().hex
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "BENCH_TAG": tag}
    proc = subprocess.Popen([sys.executable, "-m", "torchfill", "fill", str(work / "in"),
                             "--out-dir", str(out), "-m", "svt", "-p", "max_iter=300", "-p",
                             "tol=0", "--workers", str(args.workers), "-q"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    while len([n for n in state(out) if not n.startswith(".")]) < args.after:
        if proc.poll() is not None:
            raise SystemExit(f"the batch ended before {args.after} outputs: {proc.stderr.read()}")
        time.sleep(0.01)
    at_sigint = state(out)
    t0 = time.monotonic()
    os.killpg(proc.pid, signal.SIGINT)
    events: dict[str, float] = {}
    exited = None
    while exited is None or time.monotonic() - exited < 3.0:
        now = time.monotonic()
        if exited is None and proc.poll() is not None:
            exited = now
        for name, mtime in state(out).items():
            if at_sigint.get(name) != mtime and name not in events:
                events[name] = now - t0
        time.sleep(0.005)
    stderr = proc.stderr.read()
    final = state(out)
    return {"exit_s": exited - t0, "status": proc.returncode,
            "outputs_at_sigint": len([n for n in at_sigint if not n.startswith(".")]),
            "outputs_final": len([n for n in final if not n.startswith(".")]),
            "changed_after_sigint": sorted(events.items(), key=lambda kv: kv[1]),
            "temporary_left": [n for n in final if n.startswith(".")],
            "processes_left": tagged(tag),
            "last_stderr": stderr.strip().splitlines()[-1] if stderr.strip() else ""}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=40)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--after", type=int, default=1, help="outputs written before the ^C")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "in").mkdir()
        make_inputs(work / "in", args.files)
        print(f"{args.files} files, {args.workers} workers, ^C after {args.after} output(s); "
              f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
        for k in range(args.repeat):
            r = once(args, work)
            late = [f"{n} +{s:.3f}s" for n, s in r["changed_after_sigint"]]
            print(f"run {k + 1}: exit {r['status']} {r['exit_s']:.2f} s after SIGINT; outputs "
                  f"{r['outputs_at_sigint']} at SIGINT, {r['outputs_final']} at the end; "
                  f"changed after SIGINT: {late or 'none'}; temporary left: "
                  f"{r['temporary_left'] or 'none'}; processes left: "
                  f"{r['processes_left'] or 'none'}\n    stderr: {r['last_stderr']}")


if __name__ == "__main__":
    main()

"""Many recordings at once: ``torchfill fill A.c3d B.c3d ... --out-dir DIR``.

:func:`expand` turns files, folders and glob patterns into input paths; :func:`fill_file` fills
one file and returns a summary row instead of raising (a failing file never stops the others);
:func:`run` fills the jobs in this process, in ``workers`` processes, or as Ray tasks
(``ray_address``: ``"auto"``, ``"local"`` or a cluster address; ``pip install torchfill[ray]``),
yielding each row as its file finishes.
"""
from __future__ import annotations

import glob
import multiprocessing
import os
import time
import warnings
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

SUFFIXES = (".c3d", ".trc", ".npy", ".npz", ".csv")
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


@dataclass(frozen=True)
class Job:
    """One file to fill: where from, where to, and how."""

    input: str
    output: str
    method: str | None = None
    params: dict = field(default_factory=dict)
    max_gap: int | None = None
    training: tuple[str, ...] = ()


def expand(items: list[str]) -> list[Path]:
    """Files as given; folders as their recordings (sorted, not recursive); patterns via glob.
    A name that is neither an existing path nor a matching pattern is kept (it fails, reported)."""
    paths: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            paths.extend(sorted(p for p in path.iterdir()
                                if p.is_file() and p.suffix.lower() in SUFFIXES))
        elif not path.exists() and glob.has_magic(item):
            paths.extend(Path(p) for p in sorted(glob.glob(item, recursive=True)))
        else:
            paths.append(path)
    return list(dict.fromkeys(paths))


def outputs(inputs: list[Path], out_dir: Path) -> list[Path]:
    """``out_dir / name`` for each input; refuses to overwrite an input or write one name twice."""
    outs = [out_dir / p.name for p in inputs]
    seen: dict[Path, Path] = {}
    for src, dst in zip(inputs, outs):
        if dst.resolve() == src.resolve():
            raise ValueError(f"{src}: --out-dir would overwrite the input; choose another folder")
        if dst in seen:
            raise ValueError(f"{src}: same output name as {seen[dst]} in {out_dir}")
        seen[dst] = src
    return outs


def fill_file(job: Job) -> dict:
    """Read, fill and write one file; a summary row (``error`` set, nothing written, on failure)."""
    import torchfill

    row = {"file": job.input, "output": job.output, "frames": 0, "markers": 0, "missing": 0,
           "filled": 0, "seconds": 0.0, "warnings": [], "error": None}
    start = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            seq = torchfill.read(job.input)
            row.update(frames=seq.n_frames, markers=seq.n_markers, missing=int(seq.mask.sum()))
            params = dict(job.params)
            if job.training:
                params["training"] = [torchfill.read(p) for p in job.training]
            out = torchfill.fill(seq, job.method, max_gap=job.max_gap, **params)
            Path(job.output).parent.mkdir(parents=True, exist_ok=True)
            torchfill.write(out, job.output)
        row["filled"] = row["missing"] - int(out.mask.sum())
        row["warnings"] = [str(w.message) for w in caught
                           if not issubclass(w.category, (DeprecationWarning,
                                                          PendingDeprecationWarning))]
    except Exception as err:  # reported per file; the batch goes on
        text = " ".join(str(err).split()) or type(err).__name__
        if not isinstance(err, (ValueError, OSError, KeyError)):
            text = f"internal error: {type(err).__name__}: {text}"
        row["error"] = text if text.startswith(job.input) else f"{job.input}: {text}"
    row["seconds"] = round(time.perf_counter() - start, 3)
    return row


def run(jobs: list[Job], workers: int = 1, ray_address: str | None = None) -> Iterator[dict]:
    """Fill every job; yields the rows as files finish (in any order)."""
    if ray_address is not None:
        yield from _run_ray(jobs, ray_address)
    elif workers <= 1 or len(jobs) <= 1:
        yield from map(fill_file, jobs)
    else:  # fresh interpreters (a process using torch must not fork), one thread each
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=ctx) as pool:
            with _one_thread():   # workers start at submit and read the variables then
                futures = [pool.submit(fill_file, job) for job in jobs]
            for done in as_completed(futures):
                yield done.result()


@contextmanager
def _one_thread():
    """Set the BLAS/OpenMP thread variables to 1 for processes started inside, then restore."""
    saved = {k: os.environ.get(k) for k in _THREAD_VARS}
    os.environ.update({k: "1" for k in _THREAD_VARS})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _run_ray(jobs: list[Job], address: str) -> Iterator[dict]:
    yield from ray_map(fill_file, [(job,) for job in jobs], address)


def ray_map(func, args: list[tuple], address: str, kwargs: list[dict] | None = None) -> Iterator:
    """``func(*a, **k)`` for every ``a`` (and ``k``) as Ray tasks of one CPU each; yields the
    results as they finish. Connects to ``address`` unless Ray is already initialized in this
    process: ``"local"`` always starts a new Ray here (``ray.init(address=None)`` would instead join
    a cluster named by ``RAY_ADDRESS`` or left by ``ray start``), ``"auto"`` joins the running one."""
    try:
        import ray
    except ImportError:
        raise ValueError("--ray needs Ray: pip install 'torchfill[ray]'") from None
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, log_to_driver=False)
    remote = ray.remote(num_cpus=1)(func)
    pending = [remote.remote(*a, **k) for a, k in zip(args, kwargs or [{}] * len(args))]
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
    finally:
        if started:
            ray.shutdown()


def table(rows: list[dict]) -> str:
    """The end-of-batch summary, one line per file in input order."""
    head = f"{'file':<40} {'frames':>7} {'markers':>7} {'missing':>8} {'filled':>8} {'seconds':>8}  status"
    lines = [head, "-" * len(head)]
    for row in rows:
        name = Path(row["file"]).name
        status = "FAILED" if row["error"] else ("ok" if not row["warnings"] else
                                                f"ok, {len(row['warnings'])} warning(s)")
        lines.append(f"{name[-40:]:<40} {row['frames']:>7} {row['markers']:>7} {row['missing']:>8} "
                     f"{row['filled']:>8} {row['seconds']:>8.2f}  {status}")
    failed = sum(1 for row in rows if row["error"])
    lines.append(f"{len(rows) - failed} of {len(rows)} file(s) filled"
                 + (f", {failed} failed" if failed else ""))
    return "\n".join(lines)


__all__ = ["Job", "SUFFIXES", "expand", "fill_file", "outputs", "ray_map", "run", "table"]

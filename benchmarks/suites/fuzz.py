"""Fuzz the read -> fill -> write -> read path and check torchfill's promises.

A corpus of seed files (real recordings from ``../shared/data`` when present, plus synthetic C3D
(float and int16), TRC, CSV, NPZ and NPY files) is mutated (byte flips, truncations, insertions,
C3D header and parameter fields, special values in data words and text cells, line edits, odd
encodings, NPZ members) and each mutant goes through ``torchfill fill IN -o OUT -m linear`` and
``torchfill info IN`` in-process. The rules checked:

* no traceback and no internal error: exit 0, or exit 2 with exactly one line
  ``torchfill: error: <file>: <problem>`` naming the input or output;
* on exit 2 nothing is written (no OUT, no temporary file);
* on exit 0, OUT reads back; every sample observed in IN is bit-for-bit the same in OUT; and a
  write-back keeps everything else: a C3D changes only the words of filled samples and of gaps
  (which it writes as missing: residual -1), a TRC only the cells of filled samples, the record
  of them in line 1, and tabs and empty cells appended to rows (and to the X1 Y1 Z1 line) that
  OpenSim would read short; labels, rate and units are kept;
* unfilled samples are missing in the file's own convention: residual -1 in a C3D; in a TRC
  every data row has all its cells, and a row whose last cell is empty ends with a tab.

Usage::

    OMP_NUM_THREADS=1 nice python -m benchmarks fuzz -n 5000 --seed 0 --report fuzz.json

It prints the number of mutants, outcomes and rule violations (with examples).
"""
from __future__ import annotations

import contextlib
import io
import json
import signal
import sys
import tempfile
import time
import warnings
import zipfile
from collections import Counter
from pathlib import Path

import numpy as np

import torchfill
from torchfill import cli
from torchfill.io import c3d as c3d_io
from torchfill.sequence import MarkerSequence

from .. import data

HELP = "mutated C3D/TRC/CSV/NPZ/NPY files through read -> fill -> write -> read: the file rules"
SPECIAL_TEXT = ["nan", "NaN", "inf", "-inf", "1e400", "-1e400", "1e18", "1e34", "1e300", "-0",
                "0", "0.0", "", " ", "abc", "1,5", "0x10", "1e-320", "１２", "+", ".", "e5",
                "9" * 400, "1e", "--1", "\x00", "Ä"]
SPECIAL_F32 = [np.nan, np.inf, -np.inf, 1e18, 1e34, -3e38, 1e-40, 0.0, -0.0, 65536.0]
INTERESTING_U16 = [0, 1, 2, 255, 256, 0x7FFF, 0x8000, 0xFFFF]


class Timeout(BaseException):
    """A case ran past its time limit (a BaseException, so the CLI does not catch it)."""


# -- corpus ----------------------------------------------------------------------------------
def _synthetic(rng, T=None, J=None, labels=None) -> MarkerSequence:
    T = T or int(rng.integers(3, 80))
    J = J or int(rng.integers(1, 7))
    t = np.linspace(0, 1, T)[:, None, None]
    points = rng.uniform(-500, 1500) + rng.uniform(10, 400) * np.sin(
        2 * np.pi * t + rng.uniform(0, 6, (1, J, 3)))
    for _ in range(int(rng.integers(0, 4))):
        a = int(rng.integers(0, T))
        points[a:a + int(rng.integers(1, 12)), int(rng.integers(0, J))] = np.nan
    if rng.random() < 0.2:
        points[int(rng.integers(0, T)), 0, int(rng.integers(0, 3))] = np.nan   # partial sample
    labels = labels or [f"M{j}" for j in range(J)]
    return MarkerSequence(points=points, labels=labels, rate=float(rng.choice([50, 100, 120])))


def _int16_c3d(path: Path, seq: MarkerSequence, scale: float) -> None:
    import c3d as c3d_package
    writer = c3d_package.Writer(point_rate=seq.rate, analog_rate=0.0, point_scale=scale,
                                point_units="mm")
    writer.set_point_labels(seq.labels)
    ok = np.isfinite(seq.points).all(axis=2)
    frames = np.zeros(seq.points.shape[:2] + (5,), np.float32)
    frames[..., :3] = np.clip(np.where(ok[..., None], seq.points, 0), -3000, 3000)
    frames[..., 3] = np.where(ok, 0.0, -1.0)
    writer.add_frames([(f, np.zeros((0, 1), np.float32)) for f in frames])
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        writer.write(buf)
    path.write_bytes(buf.getvalue())


def build_corpus(folder: Path, rng, *, real: bool = True, max_bytes: int = 800_000) -> list[Path]:
    """Seed files: synthetic ones written into ``folder``, plus small real recordings."""
    folder.mkdir(parents=True, exist_ok=True)
    seeds = []
    odd = [["Épaule", "肘", "M2"], ["a,b", 'q"t', "dup", "dup"], ["x" * 40]]
    for k in range(6):
        labels = odd[k % 3] if k < 3 else None
        seq = _synthetic(rng, J=len(labels) if labels else None, labels=labels)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for suffix in (".c3d", ".trc", ".csv", ".npz", ".npy"):
                path = folder / f"syn{k}{suffix}"
                torchfill.write(seq, path)
                seeds.append(path)
        _int16_c3d(folder / f"syn{k}_i16.c3d", seq, 0.1 if k % 2 else 0.05)
        seeds.append(folder / f"syn{k}_i16.c3d")
    if real and data.folder().is_dir():
        seeds += sorted(p for p in data.folder().iterdir() if p.suffix.lower() in (".c3d", ".trc", ".csv")
                        and p.stat().st_size <= max_bytes)
    return seeds


# -- mutations -------------------------------------------------------------------------------
def _flip(raw: bytearray, rng, suffix) -> str:
    n = int(rng.integers(1, 10))
    hi = len(raw) if rng.random() < 0.5 else min(len(raw), 4096)
    for _ in range(n):
        if hi:
            raw[int(rng.integers(0, hi))] ^= int(rng.integers(1, 256))
    return f"flip{n}"


def _truncate(raw: bytearray, rng, suffix) -> str:
    cut = int(rng.integers(0, max(len(raw), 1)))
    del raw[cut:]
    return f"truncate@{cut}"


def _insert(raw: bytearray, rng, suffix) -> str:
    at = int(rng.integers(0, len(raw) + 1))
    raw[at:at] = rng.bytes(int(rng.integers(1, 64)))
    return f"insert@{at}"


def _c3d_header(raw: bytearray, rng, suffix) -> str:
    if len(raw) < 24:
        return "noop"
    word = int(rng.integers(0, 12))
    value = int(rng.choice(INTERESTING_U16)) if rng.random() < 0.7 else int(rng.integers(0, 65536))
    raw[2 * word:2 * word + 2] = value.to_bytes(2, "little")
    return f"header_word{word + 1}={value}"


def _layout(raw: bytearray):
    """The C3D layout of ``raw``, None where it does not parse (the mutation then flips bytes)."""
    try:
        return c3d_io.parse(bytes(raw), "x.c3d")
    except Exception:
        return None


def _c3d_param(raw: bytearray, rng, suffix) -> str:
    if (lay := _layout(raw)) is None:
        return _flip(raw, rng, suffix)
    params = [p for g in lay.params.values() for p in g.values() if p.data]
    if not params:
        return "noop"
    p = params[int(rng.integers(0, len(params)))]
    if p.type == 4:
        value = np.float32(rng.choice(SPECIAL_F32 + [-1.0, 1.0, 0.1])).tobytes()
    elif p.type == 2:
        value = int(rng.choice([0, 1, -1, 255, 32767, -32768])).to_bytes(2, "little", signed=True)
    else:
        value = rng.bytes(1) if p.type == 1 else "É肘\x00".encode()[:max(len(p.data), 1)]
    raw[p.offset:p.offset + len(value)] = value[:max(len(raw) - p.offset, 0)]
    return f"param_{p.group}:{p.name}"


def _c3d_values(raw: bytearray, rng, suffix) -> str:
    if (lay := _layout(raw)) is None:
        return _flip(raw, rng, suffix)
    n_words = lay.n_frames * lay.frame_words
    if not n_words:
        return "noop"
    for _ in range(int(rng.integers(1, 5))):
        w = int(rng.integers(0, n_words))
        at = lay.data_offset + w * lay.word_size
        if lay.is_float:
            value = np.float32(rng.choice(SPECIAL_F32)).astype(lay._endian + "f4").tobytes()
        else:
            value = np.int16(rng.choice([0, -1, 32767, -32768])).astype(
                lay._endian + "i2").tobytes()
        raw[at:at + len(value)] = value
    return "c3d_values"


def _text_cells(raw: bytearray, rng, suffix) -> str:
    lines = bytes(raw).split(b"\n")
    if len(lines) < 2:
        return "noop"
    sep = b"\t" if suffix == ".trc" else b","
    for _ in range(int(rng.integers(1, 5))):
        i = int(rng.integers(0, len(lines)))
        cells = lines[i].split(sep)
        k = int(rng.integers(0, len(cells)))
        cells[k] = str(rng.choice(SPECIAL_TEXT)).encode("utf-8")
        lines[i] = sep.join(cells)
    raw[:] = b"\n".join(lines)
    return "text_cells"


def _text_lines(raw: bytearray, rng, suffix) -> str:
    lines = bytes(raw).split(b"\n")
    i = int(rng.integers(0, len(lines)))
    op = int(rng.integers(0, 5))
    if op == 0:
        del lines[i]
    elif op == 1:
        lines.insert(i, lines[i])
    elif op == 2:
        lines[i] = lines[i].replace(b"\t", b",") if b"\t" in lines[i] else lines[i].replace(b",", b"\t")
    elif op == 3:
        lines = [ln + b"\r" for ln in lines]
    else:
        lines[i] = lines[i] + b"\t" * int(rng.integers(1, 4))
    raw[:] = b"\n".join(lines)
    return f"text_lines{op}"


def _encoding(raw: bytearray, rng, suffix) -> str:
    text = bytes(raw).decode("utf-8", "replace")
    op = int(rng.integers(0, 4))
    if op == 0:
        raw[:] = b"\xef\xbb\xbf" + bytes(raw)
    elif op == 1:
        raw[:] = text.encode("utf-16")
    elif op == 2:
        raw[:] = text.replace("M0", "Mé", 1).encode("latin-1", "replace")
    else:
        raw[:] = text.replace("M0", "M\u200b0\u00a0", 1).encode("utf-8")
    return f"encoding{op}"


def _npz_member(raw: bytearray, rng, suffix) -> str:
    try:
        with zipfile.ZipFile(io.BytesIO(bytes(raw))) as z:
            members = {n: z.read(n) for n in z.namelist()}
    except Exception:
        return _flip(raw, rng, suffix)
    key = str(rng.choice(["points", "labels", "rate", "units"]))
    choices = [np.array([np.nan]), np.array(-1.0), np.array(0.0), np.ones((2, 2)),
               np.zeros((0, 3, 3)), np.full((4, 2, 3), 1e300), np.array(["a"] * 7),
               np.ones((3, 2, 3), np.int16), np.array("Épaule"), np.array([1e400, 0, 0] * 3)]
    buf = io.BytesIO()
    np.save(buf, choices[int(rng.integers(0, len(choices)))], allow_pickle=False)
    members[f"{key}.npy"] = buf.getvalue() if rng.random() < 0.8 else rng.bytes(50)
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    raw[:] = out.getvalue()
    return f"npz_{key}"


OPERATORS = {
    ".c3d": [_flip, _truncate, _insert, _c3d_header, _c3d_param, _c3d_values, _c3d_values],
    ".trc": [_flip, _truncate, _insert, _text_cells, _text_cells, _text_lines, _encoding],
    ".csv": [_flip, _truncate, _insert, _text_cells, _text_cells, _text_lines, _encoding],
    ".npz": [_flip, _truncate, _insert, _npz_member, _npz_member],
    ".npy": [_flip, _truncate, _insert, _flip],
}


def mutate(raw: bytes, suffix: str, rng) -> tuple[bytes, str]:
    data = bytearray(raw)
    ops = OPERATORS[suffix]
    names = [ops[int(rng.integers(0, len(ops)))](data, rng, suffix)
             for _ in range(1 if rng.random() < 0.7 else 2)]
    return bytes(data), "+".join(names)


# -- checks ----------------------------------------------------------------------------------
def _cli(argv: list[str], limit: float) -> tuple[int | str, str]:
    err = io.StringIO()
    old = signal.signal(signal.SIGALRM, _raise_timeout)
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            status = cli.main(argv)
    except Timeout:
        status = "timeout"
    except BaseException as exc:                   # noqa: BLE001 - a traceback: a violation
        status = f"uncaught {type(exc).__name__}: {exc}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    return status, err.getvalue()


def _raise_timeout(signum, frame):
    raise Timeout()


def _read_quiet(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torchfill.read(path)


def check_case(src: Path, out: Path, limit: float = 60.0) -> tuple[str, list[str]]:
    """Run fill and info on ``src``; returns (outcome, rule violations)."""
    problems = []
    status, err = _cli(["info", str(src)], limit)
    problems += _check_status("info", status, err, [src.name])
    status, err = _cli(["fill", str(src), "-o", str(out), "-m", "linear", "-q"], limit)
    problems += _check_status("fill", status, err, [src.name, out.name])
    leftovers = [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}.")]
    if leftovers:
        problems.append(f"temporary file left: {leftovers}")
    if status != 0:
        if out.exists():
            problems.append("output written although the fill failed")
        return ("error" if status == 2 else "violation"), problems
    if not out.exists():
        return "violation", problems + ["exit 0 but no output"]
    try:
        before, after = _read_quiet(src), _read_quiet(out)
    except Exception as exc:                        # noqa: BLE001
        return "violation", problems + [f"output unreadable: {type(exc).__name__}: {exc}"]
    problems += _check_kept(src, out, before, after)
    return ("filled" if not problems else "violation"), problems


def _check_status(verb: str, status, err: str, names: list[str]) -> list[str]:
    lines = [ln for ln in err.splitlines() if ln and not ln.startswith("torchfill: warning:")]
    if status == 0:
        return [f"{verb}: exit 0 with stderr {lines[:2]}"] if lines else []
    if status != 2:
        return [f"{verb}: status {status}: {' | '.join(lines)[:300]}"]
    if len(lines) != 1 or not lines[0].startswith("torchfill: error: "):
        return [f"{verb}: not one error line: {lines[:3]}"]
    if not any(name in lines[0] for name in names):
        return [f"{verb}: error names no file: {lines[0][:200]}"]
    return []


def _check_kept(src: Path, out: Path, before: MarkerSequence, after: MarkerSequence) -> list[str]:
    problems = []
    if after.points.shape != before.points.shape:
        return [f"shape {before.points.shape} -> {after.points.shape}"]
    seen = np.isfinite(before.points)
    if not np.array_equal(before.points[seen], after.points[seen]):
        n = int((before.points[seen] != after.points[seen]).sum())
        problems.append(f"{n} observed coordinate(s) altered")
    if after.labels != before.labels:
        problems.append("labels changed")
    if src.suffix.lower() in (".npz", ".c3d", ".trc") and (
            after.units != before.units or not np.array_equal(after.rate, before.rate,
                                                              equal_nan=True)):
        problems.append(f"rate/units {before.rate}/{before.units} -> {after.rate}/{after.units}")
    filled = ~np.isfinite(before.points).all(axis=2) & np.isfinite(after.points).all(axis=2)
    if src.suffix.lower() == ".c3d":
        problems += _c3d_kept(src, out, before, filled) + _c3d_missing(out, after)
    elif src.suffix.lower() == ".trc":
        problems += _trc_kept(src, out, filled) + _trc_rows(out, after.n_markers)
    return problems


def _c3d_kept(src: Path, out: Path, before: MarkerSequence, filled: np.ndarray) -> list[str]:
    a, b = src.read_bytes(), out.read_bytes()
    if len(a) != len(b):
        return [f"C3D size {len(a)} -> {len(b)}"]
    diff = np.flatnonzero(np.frombuffer(a, np.uint8) != np.frombuffer(b, np.uint8))
    if not diff.size:
        return []
    lay = c3d_io.parse(a, src)
    word = (diff - lay.data_offset) // lay.word_size
    t, col = word // lay.frame_words, word % lay.frame_words
    allowed = set()
    index = before.meta["point_index"]
    gaps = ~np.isfinite(before.points).all(axis=2)          # filled, or written as missing
    for tt, j in zip(*np.nonzero(filled | gaps)):
        allowed.add((int(tt), int(index[j])))
    bad = [(int(x), int(c)) for x, c, d in zip(t, col, diff)
           if d < lay.data_offset or c >= 4 * lay.n_points or (int(x), int(c) // 4) not in allowed]
    return [f"C3D bytes changed outside filled samples: {len(bad)} (first word {bad[0]})"] \
        if bad else []


def _c3d_missing(out: Path, after: MarkerSequence) -> list[str]:
    """Every marker sample missing in OUT is stored with a negative 4th word (residual -1)."""
    raw = c3d_io.read_raw(out)
    index = np.asarray(after.meta["point_index"], dtype=np.int64)
    bad = ~np.isfinite(after.points).all(axis=2) & ~(raw.word[:, index] < 0)
    return [f"C3D: {int(bad.sum())} missing sample(s) not marked invalid"] if bad.any() else []


def _trc_rows(out: Path, J: int) -> list[str]:
    """Every data row of OUT has frame, time and 3 cells per marker, and one more (a trailing
    tab) when its last cell is empty (OpenSim drops a trailing empty token)."""
    from torchfill.io import trc as trc_io
    parsed = trc_io._load(out)
    n = 2 + 3 * J
    for i in parsed.data_lines:
        cells = parsed.lines[i].rstrip("\r\n").split("\t")
        if len(cells) < n or (len(cells) == n and not cells[-1].strip()):
            return [f"TRC line {i + 1}: {len(cells)} cells, OpenSim reads it short"]
    return []


def _trc_kept(src: Path, out: Path, filled: np.ndarray) -> list[str]:
    """Lines other than the data rows of filled samples are byte-identical; in those rows only
    the cells of filled samples changed."""
    from torchfill.io import trc as trc_io
    a, b = src.read_bytes().splitlines(), out.read_bytes().splitlines()
    if len(a) != len(b):
        return [f"TRC lines {len(a)} -> {len(b)}"]
    rows = trc_io._load(src).data_lines
    allowed = {rows[t]: set(np.flatnonzero(filled[t]).tolist())
               for t in np.flatnonzero(filled.any(axis=1))}
    record = b"torchfill-filled="
    for i, (x, y) in enumerate(zip(a, b)):
        if x == y:
            continue
        if i == 0:                                   # the record of the filled samples
            keep = [c for c in x.split(b"\t") if not c.strip().startswith(record)]
            got = [c for c in y.split(b"\t") if not c.strip().startswith(record)]
            while keep and not keep[-1].strip():
                keep.pop()
            if got != keep:
                return ["TRC line 1 changed beyond the record of the filled samples"]
            continue
        cx, cy = x.split(b"\t"), y.split(b"\t")
        if i not in allowed:                         # only padding: empty cells appended
            if cy[:len(cx)] != cx or any(c for c in cy[len(cx):]):
                return [f"TRC line {i + 1} changed, not a row with a filled sample"]
            continue
        cx += [b""] * (len(cy) - len(cx))
        bad = [k for k in range(len(cy)) if cx[k] != cy[k] and (k < 2 or (k - 2) // 3
                                                               not in allowed[i])]
        if bad or len(cx) > len(cy):
            return [f"TRC line {i + 1}: cells {bad[:5]} changed outside filled samples"]
    return []


# -- driver ----------------------------------------------------------------------------------
def run(n: int, seed: int = 0, *, real: bool = True, workdir: Path | None = None,
        limit: float = 60.0, log=None) -> dict:
    """Fuzz ``n`` mutants; returns counts and the violations found."""
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        tmp = Path(tmp)
        seeds = build_corpus(tmp / "corpus", rng, real=real)
        raw = {p: p.read_bytes() for p in seeds}
        outcomes, violations, by_op = Counter(), [], Counter()
        start = time.time()
        for i in range(n):
            src = seeds[int(rng.integers(0, len(seeds)))]
            suffix = src.suffix.lower()
            data, ops = mutate(raw[src], suffix, rng)
            case = tmp / f"case{i % 2}"
            case.mkdir(exist_ok=True)
            for old in case.iterdir():
                old.unlink()
            mutant = case / f"in_{i}{suffix}"
            mutant.write_bytes(data)
            outcome, problems = check_case(mutant, case / f"out_{i}{suffix}", limit)
            outcomes[outcome] += 1
            by_op[(suffix, ops.split("@")[0].split("=")[0], outcome)] += 1
            if problems:
                violations.append({"case": i, "seed_file": src.name, "mutation": ops,
                                   "problems": problems})
                if log:
                    print(f"[{i}] {src.name} {ops}: {problems}", file=log, flush=True)
            if log and (i + 1) % 250 == 0:
                print(f"{i + 1}/{n} {dict(outcomes)} violations {len(violations)} "
                      f"{time.time() - start:.0f} s", file=log, flush=True)
    return {"n": n, "seed": seed, "seeds": len(seeds), "outcomes": dict(outcomes),
            "violations": violations, "seconds": time.time() - start,
            "by_operator": {"|".join(k): v for k, v in sorted(by_op.items())}}


def add_arguments(p) -> None:
    p.add_argument("-n", type=int, default=5000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-real", action="store_true", help="synthetic seeds only")
    p.add_argument("--report", help="write the full result as JSON here")


def main(args) -> int:
    result = run(args.n, args.seed, real=not args.no_real, log=sys.stdout)
    print(f"mutants {result['n']} from {result['seeds']} seed files, outcomes "
          f"{result['outcomes']}, rule violations {len(result['violations'])}, "
          f"{result['seconds']:.0f} s")
    if args.report:
        Path(args.report).write_text(json.dumps(result, indent=1, default=str))
    return 1 if result["violations"] else 0


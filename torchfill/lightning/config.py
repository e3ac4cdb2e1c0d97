"""Experiment configs (YAML): loading, ``base:`` inheritance, validation and the case grid.

A config names recordings, one gap protocol with a grid of its keyword arguments, seeds, methods
with their hyperparameters, metrics and the table layout (see ``experiments/README.md``). A config
may start from another with ``base: other.yaml`` and override only what changes (deep merge: nested
mappings merge key by key, everything else is replaced, ``~`` removes an inherited entry).
"""
from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

KNOWN_KEYS = {"name", "base", "description", "data_dir", "results_dir", "recordings", "training",
              "frames", "segments", "protocol", "grid", "seeds", "methods", "metrics", "table",
              "references", "plots", "showcase", "device", "dtype", "log", "projection", "fill"}
DEFAULT_METRICS = ["rmse", "ave", "std", "rmse_missing", "gap_error"]
#: Keys whose relative paths are resolved against the folder of the config file that sets them.
PATH_KEYS = ("data_dir", "results_dir")
#: ``training: self`` = the rest of the test recording (the segment cut out; needs ``segments``).
SELF = "self"
#: The ``fill:`` entries a config may set: ``torchfill.fill``'s arguments for every case, over
#: the papers' protocol (``torchfill.lightning.runner.PAPER``; ``dtype`` over the config's, null:
#: the method's own), and ``sequence: true`` (the case goes to fill as a MarkerSequence: labels,
#: rate, units); ``fill: {sequence: true, constraints: true, extrapolate: 0.25, window: 6000,
#: dtype: null}`` scores what ``torchfill fill`` returns.
FILL_KEYS = ("constraints", "extrapolate", "window", "segments", "dtype", "sequence")


@dataclass(frozen=True)
class Method:
    """One column of the experiment: a label, the registered solver name and its hyperparameters."""

    label: str
    solver: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Case:
    """One solver run: recording x grid point x seed x method. ``key`` identifies it in cases.csv."""

    recording: str
    point: tuple[tuple[str, Any], ...]
    seed: int
    method: Method

    @property
    def key(self) -> tuple[str, ...]:
        return (self.recording, *(str(v) for _, v in self.point), str(self.seed), self.method.label)

    @property
    def slug(self) -> str:
        """A file-name-safe identifier (per-case log folders)."""
        grid = "_".join(f"{k}{v}" for k, v in self.point)
        stem = Path(self.recording).stem
        return f"{stem}__{grid}__s{self.seed}__{self.method.label}".replace("/", "-").replace(" ", "")


@dataclass
class Config:
    """A validated experiment config (see ``experiments/README.md`` for the schema)."""

    path: Path
    name: str
    data_dir: Path
    results_dir: Path
    recordings: list[str]
    protocol: str
    grid: dict[str, list]
    seeds: list[int]
    methods: list[Method]
    metrics: list[str]
    table: dict[str, Any]
    training: list[str] = field(default_factory=list)
    frames: tuple[int, int] | None = None
    segments: tuple[int, int] | None = None          # (length, count) test segments per recording
    references: dict[str, list[dict]] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)  # methods listed but not registered
    plots: dict[str, Any] = field(default_factory=dict)
    showcase: dict[str, Any] = field(default_factory=dict)
    device: str = "cpu"
    dtype: str = "float64"
    log: bool = True
    projection: str | None = None      # "side_view": 2-D side views of the recordings
    fill: dict[str, Any] = field(default_factory=dict)   # fill()'s protocol arguments (FILL_KEYS)
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def keys(self) -> list[str]:
        """The columns between ``recording`` and ``seed`` in ``cases.csv``: segment, grid keys."""
        return (["segment"] if self.segments else []) + list(self.grid)

    def points(self) -> list[tuple[tuple[str, Any], ...]]:
        """The cartesian product of the segment indices and the grid, in config order."""
        axes = ({"segment": list(range(self.segments[1]))} if self.segments else {}) | self.grid
        keys = list(axes)
        return [tuple(zip(keys, values)) for values in itertools.product(*axes.values())]

    def cases(self, methods: list[Method] | None = None) -> list[Case]:
        """Every case, ordered recording > segment > grid point > seed > method."""
        methods = self.methods if methods is None else methods
        return [Case(rec, point, seed, m) for rec in self.recordings for point in self.points()
                for seed in self.seeds for m in methods]

    def recording_path(self, name: str) -> Path:
        return self.data_dir / name


def deep_merge(base: dict, over: dict) -> dict:
    """``over`` on top of ``base``: mappings merge recursively, other values are replaced, and a
    null (``~``) in ``over`` removes the inherited entry (e.g. ``methods: {pchip: ~}``)."""
    out = dict(base)
    for key, value in over.items():
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def _load_raw(path: Path, seen: tuple[Path, ...] = ()) -> dict:
    """One config file merged onto its ``base:`` chain; relative ``data_dir``/``results_dir`` are
    made absolute against the folder of the file that sets them."""
    import yaml

    if path in seen:
        raise ValueError(f"{seen[0]}: circular base: chain {' -> '.join(map(str, seen + (path,)))}")
    if not path.is_file():
        where = f"{seen[-1].name}: base " if seen else ""
        raise ValueError(f"{where}{path}: no such config file")
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ValueError(f"{path.name}: not valid YAML ({' '.join(str(err).split())})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path.name}: expected a mapping at the top level, found {type(raw).__name__}")
    for key in PATH_KEYS:
        if isinstance(raw.get(key), str):
            raw[key] = str((path.parent / raw[key]).resolve())
    if "base" in raw:
        base = _load_raw((path.parent / str(raw["base"])).resolve(), seen + (path,))
        raw = deep_merge(base, {k: v for k, v in raw.items() if k != "base"})
    return raw


def load_config(path) -> Config:
    """Read, merge and validate a config without reading any recording.

    Every problem is a one-line ``ValueError`` starting with the config file's name: unknown keys,
    protocols, metrics or table rows, a bad grid, seeds, frames or segments, a recording or training
    recording that is not in ``data_dir``, a bad hyperparameter. Methods that are not registered are
    listed in ``skipped``. Relative folders are resolved against the config file's folder
    (``data_dir``, default ``../../shared/data``; env ``TORCHFILL_DATA`` overrides it); results go
    to ``<results_dir>/<name>`` (default ``results/`` beside the config file).
    """
    from .. import gaps

    path = Path(path).resolve()
    raw = _load_raw(path)

    def bad(msg: str) -> ValueError:
        return ValueError(f"{path.name}: {msg}")

    unknown = set(raw) - KNOWN_KEYS
    if unknown:
        raise bad(f"unknown key(s) {sorted(unknown)}; expected some of {sorted(KNOWN_KEYS)}")
    for key in ("recordings", "protocol", "methods"):
        if key not in raw:
            raise bad(f"missing required key {key!r}")
    name = _name(raw.get("name"), path, bad)
    env = os.environ.get("TORCHFILL_DATA")
    data_dir = Path(env).resolve() if env else Path(raw.get("data_dir") or
                                                    path.parent / "../../shared/data").resolve()
    results_dir = Path(raw.get("results_dir") or path.parent / "results")
    recordings = _str_list(raw["recordings"], "recordings", bad)
    training = _str_list(raw.get("training", []), "training", bad)
    protocol = str(raw["protocol"])
    if protocol not in gaps.PROTOCOLS:
        raise bad(f"unknown protocol {protocol!r}; expected one of {', '.join(gaps.PROTOCOLS)}")
    grid = _grid(raw.get("grid") or {}, bad)
    seeds = raw.get("seeds", [0])
    seeds = list(seeds) if isinstance(seeds, (list, tuple)) else [seeds]
    if not seeds or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        raise bad(f"seeds expected a list of ints, found {raw.get('seeds')!r}")
    frames, segments = _frames(raw.get("frames"), raw.get("segments"), bad)
    methods, skipped = _methods(raw["methods"], bad)
    metric_names = _metrics(raw.get("metrics", DEFAULT_METRICS), bad)
    keys = (["segment"] if segments else []) + list(grid)
    table = _table(raw.get("table"), keys, metric_names, bad)
    references = _references(raw.get("references"), table, bad)
    if raw.get("projection") not in (None, "side_view"):
        raise bad(f"projection expected 'side_view' or none, found {raw.get('projection')!r}")
    _check_files(data_dir, recordings + training, "recording", bad)
    for m in methods:
        own = m.params.get("training")
        if own == SELF and not segments:
            raise bad(f"methods.{m.label}: training: self needs `segments:` (the rest of the "
                      "recording outside the test segment)")
        if own not in (None, SELF):
            _check_files(data_dir, _str_list(own, f"methods.{m.label}.training", bad),
                         f"methods.{m.label}: training recording", bad)
    return Config(path=path, name=name, data_dir=data_dir,
                  results_dir=results_dir, recordings=recordings, protocol=protocol, grid=grid,
                  seeds=seeds, methods=methods, metrics=metric_names, table=table,
                  training=training, frames=frames, segments=segments, references=references,
                  skipped=skipped, plots=dict(raw.get("plots") or {}),
                  showcase=dict(raw.get("showcase") or {}), device=str(raw.get("device", "cpu")),
                  dtype=str(raw.get("dtype", "float64")), log=bool(raw.get("log", True)),
                  projection=raw.get("projection"), fill=_fill(raw.get("fill"), bad), raw=raw)


def _fill(value, bad) -> dict[str, Any]:
    value = {} if value is None else value
    if not isinstance(value, dict) or set(value) - set(FILL_KEYS):
        raise bad(f"fill expected a mapping with some of {', '.join(FILL_KEYS)}, found {value!r}")
    return dict(value)


def _grid(grid, bad) -> dict[str, list]:
    if not isinstance(grid, dict):
        raise bad(f"grid expected a mapping of protocol arguments to lists, found {grid!r}")
    grid = {str(k): (list(v) if isinstance(v, (list, tuple)) else [v]) for k, v in grid.items()}
    if any(not v for v in grid.values()):
        raise bad("grid has an empty list")
    if "segment" in grid:
        raise bad("grid key 'segment' is reserved (use `segments: {length: L, count: n}`)")
    return grid


def _frames(frames, segments, bad):
    if frames is not None:
        if not (isinstance(frames, (list, tuple)) and len(frames) == 2
                and all(isinstance(f, int) for f in frames) and 0 <= frames[0] < frames[1]):
            raise bad(f"frames expected [start, stop] with 0 <= start < stop, found {frames!r}")
        frames = (int(frames[0]), int(frames[1]))
    if segments is not None:
        if frames is not None:
            raise bad("frames and segments exclude each other")
        if not (isinstance(segments, dict) and set(segments) == {"length", "count"}
                and all(isinstance(v, int) and v > 0 for v in segments.values())):
            raise bad(f"segments expected {{length: frames, count: n}} with positive ints, "
                      f"found {segments!r}")
        segments = (segments["length"], segments["count"])
    return frames, segments


def _metrics(value, bad) -> list[str]:
    from .rows import SCORE_METRICS

    names = _str_list(value, "metrics", bad)
    missing = [m for m in names if m not in SCORE_METRICS]
    if missing:
        raise bad(f"unknown metric(s) {missing}; expected some of {SCORE_METRICS}")
    return names


def _table(value, keys: list[str], metric_names: list[str], bad) -> dict[str, Any]:
    table = dict(value or {})
    unknown = set(table) - {"rows", "columns", "metric", "digits"}
    if unknown:
        raise bad(f"table: unknown key(s) {sorted(unknown)}; "
                  "expected rows, columns, metric, digits")
    rows = table.get("rows", ["recording", *keys])
    table["rows"] = [rows] if isinstance(rows, str) else list(rows)
    table.setdefault("columns", "method")
    table.setdefault("metric", metric_names[0])
    table.setdefault("digits", 2)
    for key in table["rows"] + [table["columns"]]:
        if key not in ("recording", "seed", "method", *keys):
            raise bad(f"table key {key!r} is neither 'recording', 'seed', 'method' "
                      f"nor one of {keys}")
    if table["metric"] not in metric_names:
        raise bad(f"table metric {table['metric']!r} is not in metrics {metric_names}")
    return table


def _references(value, table: dict, bad) -> dict[str, list[dict]]:
    """``{label: [{<table row keys>..., <metric>: value}, ...]}``: published numbers shown as a
    column beside the methods (e.g. the paper's or the authors' code's)."""
    from .rows import SCORE_METRICS

    if value is None:
        return {}
    if not isinstance(value, dict):
        raise bad(f"references expected a mapping of label to a list of rows, found {value!r}")
    out = {}
    for label, entries in value.items():
        if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
            raise bad(f"references.{label} expected a list of mappings, found {entries!r}")
        for e in entries:
            extra = set(e) - set(table["rows"]) - set(SCORE_METRICS)
            if extra or not set(table["rows"]) <= set(e):
                raise bad(f"references.{label}: {e} expected the table rows {table['rows']} "
                          f"and metric values")
        out[str(label)] = [{k: str(v) if k in table["rows"] else float(v) for k, v in e.items()}
                           for e in entries]
    return out


def _name(value, path: Path, bad) -> str:
    """The experiment's name: one plain folder name (results go to ``<results_dir>/<name>``, and
    nowhere else: no separators, no ``..``, no control characters)."""
    name = path.stem if value is None or value == "" else value
    if isinstance(name, (int, float)) and not isinstance(name, bool):
        name = str(name)
    if not isinstance(name, str) or name in (".", "..") or name != name.strip() \
            or any(c in name for c in "/\\") or any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise bad(f"name expected a plain folder name (no '/', '\\', '..' or control characters), "
                  f"found {value!r}")
    return name


def _check_files(data_dir: Path, names: list[str], what: str, bad) -> None:
    for name in names:
        if not (data_dir / name).is_file():
            raise bad(f"{what} {name} not found in {data_dir}")


def _str_list(value, key: str, bad) -> list[str]:
    value = [value] if isinstance(value, str) else value
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise bad(f"{key} expected a list of names, found {value!r}")
    if key == "recordings" and not value:
        raise bad("recordings is empty")
    return list(value)


def _methods(value, bad) -> tuple[list[Method], list[str]]:
    """``{label: {params}}``; a ``method:`` entry in params picks the solver (default: the label),
    so one solver can appear twice with different hyperparameters (``tucker_r10: {method: tucker}``).
    Returns the registered methods (hyperparameters checked by building each solver once) and the
    labels of those that are not registered."""
    from ..solvers import available, get_solver

    if isinstance(value, (list, tuple)):
        value = {str(v): {} for v in value}
    if not isinstance(value, dict) or not value:
        raise bad(f"methods expected a mapping of method name to hyperparameters, found {value!r}")
    out, skipped = [], []
    for label, params in value.items():
        params = {} if params is None else params
        if not isinstance(params, dict):
            raise bad(f"methods.{label} expected a mapping of hyperparameters, found {params!r}")
        params = dict(params)
        method = Method(str(label), str(params.pop("method", label)), params)
        if method.solver not in available():
            skipped.append(method.label)
            continue
        try:
            get_solver(method.solver, **{k: v for k, v in params.items()
                                         if k not in ("training", "constraints")})
        except (TypeError, ValueError) as err:
            raise bad(f"methods.{label}: {' '.join(str(err).split())}") from None
        out.append(method)
    return out, skipped

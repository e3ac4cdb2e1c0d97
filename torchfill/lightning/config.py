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

import yaml

#: The repository root (configs' ``data_dir`` and default output folders are relative to it).
REPO_ROOT = Path(__file__).resolve().parents[2]

KNOWN_KEYS = {"name", "base", "description", "data_dir", "recordings", "training", "frames",
              "protocol", "grid", "seeds", "methods", "metrics", "table", "plots", "showcase",
              "device", "dtype", "log", "projection"}
DEFAULT_METRICS = ["rmse", "ave", "std", "rmse_missing", "gap_error"]


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
    """A validated experiment config."""

    path: Path
    name: str
    data_dir: Path
    recordings: list[str]
    protocol: str
    grid: dict[str, list]
    seeds: list[int]
    methods: list[Method]
    metrics: list[str]
    table: dict[str, Any]
    training: list[str] = field(default_factory=list)
    frames: tuple[int, int] | None = None
    plots: dict[str, Any] = field(default_factory=dict)
    showcase: dict[str, Any] = field(default_factory=dict)
    device: str = "cpu"
    dtype: str = "float64"
    log: bool = True
    projection: str | None = None      # "side_view": 2-D side views of the recordings
    raw: dict[str, Any] = field(default_factory=dict)

    def points(self) -> list[tuple[tuple[str, Any], ...]]:
        """The cartesian product of the grid, in config order."""
        keys = list(self.grid)
        return [tuple(zip(keys, values)) for values in itertools.product(*self.grid.values())]

    def cases(self, methods: list[Method] | None = None) -> list[Case]:
        """Every case, ordered recording > grid point > seed > method."""
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
    if path in seen:
        raise ValueError(f"{seen[0]}: circular base: chain {' -> '.join(map(str, seen + (path,)))}")
    if not path.is_file():
        where = f"{seen[-1]}: base " if seen else ""
        raise ValueError(f"{where}{path}: no such config file")
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ValueError(f"{path}: not valid YAML ({' '.join(str(err).split())})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: expected a mapping at the top level, found {type(raw).__name__}")
    if "base" in raw:
        base = _load_raw((path.parent / str(raw["base"])).resolve(), seen + (path,))
        raw = deep_merge(base, {k: v for k, v in raw.items() if k != "base"})
    return raw


def load_config(path) -> Config:
    """Read, merge and validate a config; every problem is a one-line ``ValueError`` naming it."""
    from .. import gaps, metrics

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
    name = str(raw.get("name") or path.stem)
    env = os.environ.get("TORCHFILL_DATA")
    data_dir = Path(env) if env else REPO_ROOT / str(raw.get("data_dir", "../shared/data"))
    recordings = _str_list(raw["recordings"], "recordings", bad)
    training = _str_list(raw.get("training", []), "training", bad)
    protocol = str(raw["protocol"])
    if protocol not in gaps.PROTOCOLS:
        raise bad(f"unknown protocol {protocol!r}; expected one of {', '.join(gaps.PROTOCOLS)}")
    grid = raw.get("grid") or {}
    if not isinstance(grid, dict):
        raise bad(f"grid expected a mapping of protocol arguments to lists, found {grid!r}")
    grid = {str(k): (list(v) if isinstance(v, (list, tuple)) else [v]) for k, v in grid.items()}
    if any(not v for v in grid.values()):
        raise bad("grid has an empty list")
    seeds = raw.get("seeds", [0])
    seeds = list(seeds) if isinstance(seeds, (list, tuple)) else [seeds]
    if not seeds or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        raise bad(f"seeds expected a list of ints, found {raw.get('seeds')!r}")
    methods = _methods(raw["methods"], bad)
    metric_names = _str_list(raw.get("metrics", DEFAULT_METRICS), "metrics", bad)
    known = set(metrics.score(*_tiny()))
    missing = [m for m in metric_names if m not in known]
    if missing:
        raise bad(f"unknown metric(s) {missing}; expected some of {sorted(known)}")
    table = dict(raw.get("table") or {})
    table.setdefault("rows", ["recording", *grid])
    table.setdefault("columns", "method")
    table.setdefault("metric", metric_names[0])
    for key in (table["rows"] if isinstance(table["rows"], list) else [table["rows"]]):
        if key not in ("recording", "seed", *grid):
            raise bad(f"table row {key!r} is neither 'recording', 'seed' nor a grid key {list(grid)}")
    frames = raw.get("frames")
    if frames is not None:
        if not (isinstance(frames, (list, tuple)) and len(frames) == 2):
            raise bad(f"frames expected [start, stop], found {frames!r}")
        frames = (int(frames[0]), int(frames[1]))
    if raw.get("projection") not in (None, "side_view"):
        raise bad(f"projection expected 'side_view' or none, found {raw.get('projection')!r}")
    return Config(path=path, name=name, data_dir=data_dir, recordings=recordings,
                  protocol=protocol, grid=grid, seeds=seeds, methods=methods,
                  metrics=metric_names, table=table, training=training, frames=frames,
                  plots=dict(raw.get("plots") or {}), showcase=dict(raw.get("showcase") or {}),
                  device=str(raw.get("device", "cpu")), dtype=str(raw.get("dtype", "float64")),
                  log=bool(raw.get("log", True)), projection=raw.get("projection"), raw=raw)


def _tiny():
    import numpy as np

    return np.zeros((2, 1, 3)), np.zeros((2, 1, 3)), np.zeros((2, 1), dtype=bool)


def _str_list(value, key: str, bad) -> list[str]:
    value = [value] if isinstance(value, str) else value
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise bad(f"{key} expected a list of names, found {value!r}")
    if key == "recordings" and not value:
        raise bad("recordings is empty")
    return list(value)


def _methods(value, bad) -> list[Method]:
    """``{label: {params}}``; a ``method:`` entry in params picks the solver (default: the label),
    so one solver can appear twice with different hyperparameters (``tucker_r10: {method: tucker}``)."""
    if isinstance(value, (list, tuple)):
        value = {str(v): {} for v in value}
    if not isinstance(value, dict) or not value:
        raise bad(f"methods expected a mapping of method name to hyperparameters, found {value!r}")
    out = []
    for label, params in value.items():
        params = {} if params is None else params
        if not isinstance(params, dict):
            raise bad(f"methods.{label} expected a mapping of hyperparameters, found {params!r}")
        params = dict(params)
        solver = str(params.pop("method", label))
        out.append(Method(str(label), solver, params))
    return out

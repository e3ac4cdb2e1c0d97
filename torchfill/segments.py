"""Segments: which markers move together (one rigid body each), from names, data or a user file.

A :class:`Segments` is an ordered mapping ``segment name -> list of marker labels``. A label may
belong to several segments (a knee marker sits on the thigh and at the joint with the shank); the
reconstruction picks, per sample, the segment whose visible mates predict it best. Three sources,
one format:

* **names** (:meth:`Segments.from_names`): built-in tables of the common marker sets (Vicon
  Plug-in Gait / full body, HDM05 and CMU (the same Vicon set with waist markers), Helen Hayes,
  CAST-style 4-marker cluster plates (``R_THIGH_1..4``), the OpenSim gait2392 / Hamner /
  Rajagopal sets, Qualisys sport and animation sets). Labels are matched case-insensitively,
  ignoring ``.``, ``_``, ``-`` and blanks and a subject prefix (``Reed:LASI``); each subject prefix
  gets its own segments (``Derrick:pelvis``).
* **data** (:meth:`Segments.from_data`): near-rigid clusters. For the pairs of near neighbours
  only (each marker's ``CLUSTER_NEIGHBOURS`` nearest in a few frames: the cost grows linearly with
  the markers, never with their square), the distance while both are observed has a robust spread
  ``s`` (1.4826 x MAD) over time: skin markers on one bone keep their distance within a few mm,
  markers across a moving joint do not. Average linkage on ``s`` (a cluster pair's mean over its
  measured pairs) merges the most rigid first; the cut is the first merge at which the number of
  clusters of at least three markers (what a Kabsch fit needs) is largest -- no threshold in mm, so
  the clusters do not depend on the units. A marker left in a smaller group gets a segment of its
  own: the group and its most rigid neighbours up to three markers, and so does a group of two
  or more that a merge below the cut folded into a larger cluster (one height cuts the whole
  body: a joint the trial leaves still folds its pair into the neighbour segment), where that
  segment is not inside one already found. A marker as rigid with another cluster as that
  cluster's members are with each other (a knee marker: thigh and shank) belongs to both, as in
  the name tables.
* **a user file** (:func:`load`): the YAML that :meth:`Segments.to_yaml` writes (``torchfill info
  --segments`` prints it for the segments in use), so a user can check, edit and pass it back
  (``fill(..., segments=path)``, ``torchfill fill --segments FILE``).

Of torchfill it imports only :mod:`torchfill.metrics` and its name tables
(:mod:`torchfill.segment_names`; numpy only, no torch).
"""
from __future__ import annotations

import heapq
import json
import re
from collections import OrderedDict
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from .metrics import norm_last
from .segment_names import _SEGMENTS_OF, TABLE

__all__ = ["Segments", "resolve", "completed", "load", "pair_stats", "neighbour_pairs", "normalize",
           "agreement", "purity"]

#: Each marker's nearest neighbours (in a few frames) whose pair distances are measured: the
#: candidates of the data-found segments and of the constraints' rigid pairs.
NEIGHBOURS = 12
#: Frames (evenly spaced) in which the nearest neighbours are looked up.
NEIGHBOUR_FRAMES = 5
#: Pair statistics read at most this many frames, evenly spaced.
PAIR_FRAMES = 12000
#: Pairs are measured this many (frame, pair) entries at a time (1 MB arrays stay in the cache).
PAIR_BLOCK = 1 << 17
#: Data-found segments: each marker's nearest neighbours (in a few frames) whose spreads the
#: clustering reads (more than ``NEIGHBOURS``: average linkage reads the pairs between two
#: clusters; 16 agreed with the tables as all pairs did on the 13 recordings of
#: ``python -m benchmarks segments``, 12 left one 8 points lower).
CLUSTER_NEIGHBOURS = 16
#: Two clusters merge only where at least this share of the pairs between them was measured.
MEASURED = 0.5
#: Data-found clusters grow to at most this many markers (a body segment carries a few; a dense
#: surface would otherwise merge into one cluster).
MAX_SIZE = 24
#: The near-neighbour segments (``mates``) take neighbours whose relative spread s / d is at most
#: three times this.
RELATIVE_SPREAD = 0.05
#: Segments found from the data for a fill also give each marker its own: itself and this many
#: most rigid neighbours (clusters alone left many samples without three mates).
DATA_MATES = 5
#: ... for recordings of at most this many markers (a dense surface has clusters enough).
MATES_UP_TO = 300
#: A fill finds no segments in the data of more markers than this (a dense surface: its points
#: are each other's donors through the constraints' rigid pairs). On the 6 890-point body of
#: a dense-point benchmark the clusters took the linear fill's RMSE on the gaps from 4.35
#: to 4.30 mm at twice the time (17 -> 35 s); ``segments="data"`` still finds them.
DENSE = 300

def normalize(label: str) -> tuple[str, str]:
    """``(prefix, name)`` of a label: the subject prefix before the last ``:`` and the marker
    name in lower case without ``.``, ``_``, ``-`` or blanks
    (``"Reed:L.ASI" -> ("Reed", "lasi")``)."""
    prefix, _, name = str(label).rpartition(":")
    return prefix, re.sub(r"[\s._\-]+", "", name).lower()


class Segments(OrderedDict):
    """Ordered mapping ``segment name -> list of marker labels`` (one rigid body each).

    Build with :meth:`from_names`, :meth:`from_data`, :func:`load` (a user's YAML) or from a plain
    dict; print with :meth:`to_yaml`. ``source`` says where they came from ("names", "data",
    "user", or "names+data": :func:`resolve`'s tables completed from the data); ``sources`` gives
    each segment's own.
    """

    source: str = "user"

    def __init__(self, items=(), source: str = "user"):
        super().__init__()
        for name, members in (items.items() if isinstance(items, Mapping) else items):
            self[str(name)] = [str(m) for m in members]
        self.source = source
        self.sources = {name: source for name in self}

    def merged(self, other: "Segments", names: Iterable[str]) -> "Segments":
        """These segments followed by those of ``other`` named in ``names`` (each keeping its
        source; ``source`` becomes ``"self+other"``)."""
        out = Segments(self, source=f"{self.source}+{other.source}")
        out.sources = {name: self.sources.get(name, self.source) for name in self}
        for name in names:
            out[name] = list(other[name])
            out.sources[name] = other.sources.get(name, other.source)
        return out

    # -- building -----------------------------------------------------------------------------
    @classmethod
    def from_names(cls, labels: Iterable[str], min_size: int = 2) -> "Segments":
        """Segments of the built-in tables that at least ``min_size`` of ``labels`` belong to, in
        table order, one set per subject prefix (named ``prefix:segment`` when there are
        several prefixes)."""
        labels = [str(x) for x in labels]
        by_prefix: dict[str, dict[str, list[str]]] = {}
        for label in labels:
            prefix, name = normalize(label)
            for seg in _SEGMENTS_OF.get(name, []):
                by_prefix.setdefault(prefix, {}).setdefault(seg, [])
                if label not in by_prefix[prefix][seg]:
                    by_prefix[prefix][seg].append(label)
        out = cls(source="names")
        several = len(by_prefix) > 1
        for prefix, segs in by_prefix.items():
            for seg in TABLE:
                members = segs.get(seg, [])
                if len(members) >= min_size:
                    out[f"{prefix}:{seg}" if several and prefix else seg] = members
        return out

    @classmethod
    def from_data(cls, X, labels: Iterable[str] | None = None, observed=None, *,
                  min_size: int = 3, neighbours: int = CLUSTER_NEIGHBOURS, mates: int = 0,
                  relative_spread: float = RELATIVE_SPREAD) -> "Segments":
        """Near-rigid clusters of the observed samples of ``X`` (T, J, 3) (see the module
        docstring), each of at least ``min_size`` markers; a marker may be in several. Named
        ``cluster1, cluster2, ...`` in the order of their first marker. With ``mates > 0``, also
        one segment per marker (``near:LABEL``): the marker and its ``mates`` most rigid
        neighbours within ``3 x relative_spread`` of their distance (the reconstruction's donors
        where a cluster is missing in a frame)."""
        X = np.asarray(X, dtype=np.float64)
        J = X.shape[1]
        labels = [str(x) for x in labels] if labels is not None else [str(j) for j in range(J)]
        stats = pair_stats(X, observed, neighbours=neighbours, orientation=False)
        groups = _cluster(J, stats, min_size)
        out = cls(((f"cluster{i + 1}", [labels[j] for j in g]) for i, g in enumerate(groups)),
                  source="data")
        if mates > 0 and J <= MATES_UP_TO:
            rel = stats.relative
            ok = np.isfinite(rel) & (rel <= 3 * relative_spread)
            a = np.concatenate([stats.j[ok], stats.k[ok]])
            b = np.concatenate([stats.k[ok], stats.j[ok]])
            r = np.concatenate([stats.spread[ok], stats.spread[ok]])     # absolute: the error
            order = np.lexsort((r, a))
            a, b = a[order], b[order]
            for j in range(J):
                near = b[a == j][:mates]
                if near.size >= min_size:
                    out[f"near:{labels[j]}"] = [labels[j]] + [labels[k] for k in near]
        return out

    # -- use ------------------------------------------------------------------------------------
    def indices(self, labels: Iterable[str]) -> "OrderedDict[str, list[int]]":
        """``segment -> marker indices`` into ``labels`` (exact label first, else the same
        normalised name with the same or no prefix; members not found are skipped)."""
        labels = [str(x) for x in labels]
        exact = {lab: j for j, lab in enumerate(labels)}
        norm: dict[tuple[str, str], list[int]] = {}
        bare: dict[str, list[int]] = {}
        for j, lab in enumerate(labels):
            p, n = normalize(lab)
            norm.setdefault((p.lower(), n), []).append(j)
            bare.setdefault(n, []).append(j)
        out: OrderedDict[str, list[int]] = OrderedDict()
        for seg, members in self.items():
            seg_prefix = seg.rpartition(":")[0].lower()
            idx: list[int] = []
            for m in members:
                if m in exact:
                    hit = [exact[m]]
                else:
                    p, n = normalize(m)
                    hit = norm.get((p.lower(), n), [])
                    if not hit and not p:
                        hit = norm.get((seg_prefix, n), []) or bare.get(n, [])
                        if len(hit) > 1:            # one per subject: not this segment's
                            hit = []
                idx += [j for j in hit if j not in idx]
            out[seg] = idx
        return out

    def membership(self, labels: Iterable[str]) -> list[list[str]]:
        """For each label, the segments it belongs to."""
        labels = list(labels)
        out: list[list[str]] = [[] for _ in labels]
        for seg, idx in self.indices(labels).items():
            for j in idx:
                out[j].append(seg)
        return out

    def to_yaml(self) -> str:
        """The YAML a user can edit and pass back (``segments:`` then one flow list a line)."""
        where = {"names": "the name tables", "data": "the data", "user": "a user's file",
                 "names+data": "the name tables, then the data (markers the tables leave out)"
                 }.get(self.source, self.source)
        lines = ["# torchfill segments: name -> marker labels (one rigid body each; a marker may",
                 f"# be in several). From {where};",
                 "# each line's source in its comment. Edit and pass back with --segments FILE",
                 "# or fill(..., segments=FILE).", "segments:"]
        sources = getattr(self, "sources", {})
        for seg, members in self.items():
            lines.append(f"  {json.dumps(seg)}: [{', '.join(json.dumps(m) for m in members)}]"
                         f"  # {sources.get(seg, self.source)}")
        if not self:
            lines[-1] = "segments: {}"
        return "\n".join(lines) + "\n"

    def __repr__(self) -> str:
        return f"Segments({dict(self)!r}, source={self.source!r})"


# ------------------------------------------------------------------------------------------------
# Reading a user's file

def load(path) -> Segments:
    """A user's segments file (the YAML of :meth:`Segments.to_yaml`; a top-level ``segments:``
    key is optional). Raises ``ValueError`` naming the file and the problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ValueError(f"{path}: cannot read the segments file ({e.strerror or e})") from None
    try:
        return parse(text)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


def parse(text: str) -> Segments:
    """Segments from YAML text (``yaml.safe_load`` when PyYAML is installed, else the subset that
    :meth:`Segments.to_yaml` writes)."""
    try:
        import yaml
    except ImportError:                                           # pragma: no cover
        data = _parse_subset(text)
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise ValueError(f"not valid YAML ({str(e).splitlines()[0]})") from None
    if isinstance(data, Mapping) and set(data) == {"segments"}:
        data = data["segments"]
    if data is None:
        data = {}
    return _validated(data)


def _parse_subset(text: str) -> dict:
    out: dict = {}
    for n, line in enumerate(text.splitlines(), 1):
        s = line.split(" #")[0].strip() if not line.lstrip().startswith("#") else ""
        if not s or s in ("segments:", "segments: {}"):
            continue
        key, sep, rest = s.partition(": ")
        try:
            out[json.loads(key) if key.startswith('"') else key] = json.loads(rest)
        except (json.JSONDecodeError, ValueError):
            raise ValueError(f"line {n}: expected 'name: [\"label\", ...]' "
                             "(install pyyaml for full YAML)") from None
    return out


def _validated(data) -> Segments:
    if not isinstance(data, Mapping):
        raise ValueError(f"segments must map a segment name to a list of marker labels, "
                         f"found {type(data).__name__}")
    for name, members in data.items():
        if isinstance(members, (str, bytes)) or not isinstance(members, Iterable):
            raise ValueError(f"segment {name!r}: expected a list of marker labels, found "
                             f"{type(members).__name__}")
    return Segments(data, source="user")


def resolve(segments, labels: Iterable[str] | None, X=None, observed=None) -> Segments:
    """The segments a fill uses. ``segments``: a :class:`Segments` or dict (used as given), a
    path to a YAML file, ``"names"`` (the tables), ``"data"`` (found from ``X``), or None / "auto":
    the tables when they cover at least three segments of three markers, completed from the data
    for the markers they leave out (:func:`completed`: a prop, a stick, a cluster of unknown
    names), else found from the data up to ``DENSE`` markers (a dense surface: none, see
    ``DENSE``)."""
    if isinstance(segments, Segments):
        return segments
    if isinstance(segments, Mapping):
        return _validated(segments)
    labels = list(labels) if labels is not None else None
    if isinstance(segments, Path) or (isinstance(segments, str)
                                      and segments not in ("names", "data", "auto")):
        return load(segments)
    if segments not in (None, "names", "data", "auto"):
        raise ValueError(f"segments: expected a dict, a YAML path, 'names', 'data' or None, "
                         f"found {type(segments).__name__}")
    if segments in (None, "auto", "names") and labels is not None:
        named = Segments.from_names(labels)
        if segments == "names" or sum(len(m) >= 3 for m in named.values()) >= 3:
            if segments == "names" or X is None or np.shape(X)[1] > DENSE:
                return named
            return completed(named, labels, X, observed)
    if X is None or (segments != "data" and np.shape(X)[1] > DENSE):
        return Segments(source="data")
    return Segments.from_data(X, labels, observed, mates=DATA_MATES)


#: The name prefix of a segment that completes the others (see :func:`completed`): it fills a
#: sample only where no other segment does.
COMPLETION = "data:"


def completed(named: Segments, labels: list[str], X, observed=None) -> Segments:
    """``named`` and the data-found segments (:meth:`Segments.from_data` with ``DATA_MATES``)
    made only of markers the tables leave out (a stick, a puck, a cluster of unknown names),
    named ``COMPLETION + name``: a completion fills a sample only where no other segment does.
    A data-found segment that mixes such markers with named ones is left out: completing the
    named markers too made the default's fills worse (see docs/segments.md)."""
    named_idx = named.indices(labels)
    covered = {j for idx in named_idx.values() for j in idx}
    unnamed = {labels[j] for j in range(len(labels)) if j not in covered}
    if not unnamed:
        return named
    found = Segments.from_data(X, labels, observed, mates=DATA_MATES)
    keep = [s for s, m in found.items() if set(m) <= unnamed]
    if not keep:
        return named
    found = Segments(((COMPLETION + s, found[s]) for s in keep), source="data")
    return named.merged(found, list(found))


# ------------------------------------------------------------------------------------------------
# Pair statistics of near neighbours (shared with the constraints' rigid pairs)

def neighbour_pairs(X, observed=None, k: int = NEIGHBOURS, frames: int = NEIGHBOUR_FRAMES
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(j, k)`` (j < k, sorted) of each marker's ``k`` nearest markers in ``frames``
    evenly spaced frames with the most markers observed; all pairs when there are at most
    ``k + 1`` markers. Memory and time grow with ``J * k``, not ``J ** 2``."""
    X = np.asarray(X, dtype=np.float64)
    T, J = X.shape[:2]
    if observed is None:
        observed = np.isfinite(X).all(axis=2)
    if J <= k + 1:
        a, b = np.triu_indices(J, 1)
        return a.astype(np.int64), b.astype(np.int64)
    from scipy.spatial import cKDTree

    count = observed.sum(axis=1)
    order = np.argsort(-count, kind="stable")
    pick = order[:max(1, T // 4)] if T > 4 else order   # among the fullest quarter of frames
    pick = np.sort(pick)[np.unique(np.linspace(0, len(pick) - 1, frames).round().astype(int))]
    found = []
    for t in pick:
        idx = np.flatnonzero(observed[t])
        if idx.size < 2:
            continue
        kk = min(k + 1, idx.size)
        _, nn = cKDTree(X[t, idx]).query(X[t, idx], k=kk)
        a = np.repeat(idx, kk - 1)
        b = idx[nn[:, 1:].ravel()]
        found.append(np.stack([np.minimum(a, b), np.maximum(a, b)], 1))
    if not found:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    P = np.unique(np.concatenate(found), axis=0)
    return P[:, 0].astype(np.int64), P[:, 1].astype(np.int64)


class PairStats:
    """Distance statistics of some marker pairs while both are observed (all arrays per pair).

    ``j``, ``k``: the pair's markers (j < k); ``distance``: median; ``spread``: 1.4826 x MAD;
    ``wide``: 95th percentile of ``|distance - median|``; ``count``: frames seen together;
    ``J``: markers in the recording; ``direction`` (n, 3): mean unit vector from ``k`` to ``j``;
    ``cone``: 95th percentile of its angle (radians) to ``direction``: the orientations of the
    pair the distances were measured over.
    """

    def __init__(self, j, k, distance, spread, wide, count, J, direction=None, cone=None):
        self.j, self.k = j, k
        self.distance, self.spread, self.wide, self.count, self.J = distance, spread, wide, count, J
        self.direction, self.cone = direction, cone

    @property
    def relative(self) -> np.ndarray:
        """Spread relative to the distance (NaN where never seen together)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.spread / self.distance

    def lookup(self, a, b) -> np.ndarray:
        """Index of each pair ``(a[i], b[i])`` in these statistics, -1 where not measured."""
        a, b = np.asarray(a), np.asarray(b)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = self.j * self.J + self.k
        want = lo * self.J + hi
        pos = np.searchsorted(key, want)
        pos = np.clip(pos, 0, max(key.size - 1, 0))
        ok = key.size > 0
        hit = (key[pos] == want) if ok else np.zeros(want.shape, bool)
        return np.where(hit, pos, -1)


def pair_stats(X, observed=None, pairs: tuple[np.ndarray, np.ndarray] | None = None, *,
               neighbours: int = NEIGHBOURS, min_frames: int = 20,
               orientation=True, spread=True) -> PairStats:
    """:class:`PairStats` of ``pairs`` (default: :func:`neighbour_pairs`) over at most
    ``PAIR_FRAMES`` evenly spaced frames, a block of pairs at a time. Pairs seen together in fewer
    than ``min_frames`` frames get NaN statistics. ``orientation=False``: no ``direction`` and
    ``cone`` (None; half of the time: what the segments and the rigid fill's weights need); a
    bool per pair: those of these pairs only (NaN for the others; each pair's own bits).
    ``spread``: likewise the ``spread`` and ``wide`` of some pairs only (a scale needs medians)."""
    X = np.asarray(X, dtype=np.float64)
    if observed is None:
        observed = np.isfinite(X).all(axis=2)
    observed = np.asarray(observed, dtype=bool)
    if pairs is None:
        pairs = neighbour_pairs(X, observed, k=neighbours)
    j, k = (np.asarray(p, dtype=np.int64) for p in pairs)
    order = np.lexsort((k, j))
    j, k = j[order], k[order]
    stride = -(-X.shape[0] // PAIR_FRAMES)
    Xt = np.ascontiguousarray(np.moveaxis(X[::stride], 0, 2))     # (J, D, T): a marker's rows
    obs = np.ascontiguousarray(observed[::stride].T)              # (J, T): gathers copy rows
    T = obs.shape[1]
    n = j.size
    med, mad, wide = (np.full(n, np.nan) for _ in range(3))
    turn = np.broadcast_to(np.asarray(orientation, dtype=bool), (n,))[order]
    spreads = np.broadcast_to(np.asarray(spread, dtype=bool), (n,))[order]
    cone = np.full(n, np.nan) if orientation is not False else None
    direction = np.full((n, X.shape[2]), np.nan) if orientation is not False else None
    count = np.zeros(n, np.int64)
    block = max(1, PAIR_BLOCK // max(T, 1))
    for a in range(0, n, block):
        jb, kb = j[a:a + block], k[a:a + block]
        both = obs.take(jb, axis=0) & obs.take(kb, axis=0)                 # (n, T)
        V = Xt.take(jb, axis=0) - Xt.take(kb, axis=0)                      # (n, D, T)
        D = _norm_coords(V)                                                # (n, T)
        D[~both] = np.nan
        c = both.sum(axis=1)
        with np.errstate(all="ignore"):
            S = np.sort(D, axis=1)
            m = _col_quantile(S.T, c, 0.5)
            s, w = _spreads(S, m, c, spreads[a:a + block])
        keep = c >= min_frames
        med[a:a + block] = np.where(keep, m, np.nan)
        mad[a:a + block] = np.where(keep, s, np.nan)
        wide[a:a + block] = np.where(keep, w, np.nan)
        at = turn[a:a + block]
        if at.all():
            direction[a:a + block], cone[a:a + block] = _orientation(V, D, c, keep)
        elif at.any():
            direction[a:a + block][at], cone[a:a + block][at] = _orientation(
                V[at], D[at], c[at], keep[at])
        count[a:a + block] = c
    return PairStats(j, k, med, mad, wide, count, X.shape[1], direction, cone)


def _spreads(S: np.ndarray, m: np.ndarray, c: np.ndarray, rows: np.ndarray):
    """1.4826 x the median and the 95th percentile of ``|D - m|`` for the ``rows`` of the sorted
    distances ``S`` (n, T) (``c`` finite each, median ``m``); NaN in the other rows."""
    s, w = np.full(m.shape, np.nan), np.full(m.shape, np.nan)
    if rows.any():
        dev = np.abs(S[rows] - m[rows, None])   # |D - m| in the order of S: falls, then rises
        dev.sort(axis=1)                        # (numpy sorts that shape faster)
        c = c[rows]
        s[rows] = 1.4826 * _col_quantile(dev.T, c, 0.5)
        w[rows] = _col_quantile(dev.T, c, 0.95)
    return s, w


def _norm_coords(V: np.ndarray) -> np.ndarray:
    """:func:`torchfill.metrics.norm_last` over the coordinates of ``V`` (n, D, T): its bits."""
    if not 0 < V.shape[1] < 8:
        return norm_last(np.ascontiguousarray(np.moveaxis(V, 1, -1)))
    s = V[:, 0] * V[:, 0]
    for c in range(1, V.shape[1]):
        s += V[:, c] * V[:, c]
    return np.sqrt(s, out=s)


def _orientation(V: np.ndarray, D: np.ndarray, c: np.ndarray, keep: np.ndarray):
    """Mean unit vector of each pair's difference ``V`` (n, D, T) over its frames with a finite
    distance ``D`` (n, T), and the 95th percentile of the angle to it (NaN where not ``keep``)."""
    fin = np.isfinite(D)
    U = np.zeros(V.shape)
    with np.errstate(all="ignore"):
        np.divide(V, D[:, None], out=U, where=fin[:, None])
        U = U.transpose(2, 0, 1).copy()     # (T, n, D): the sum's order and einsum's bits
        m = U.sum(axis=0)
        m /= np.linalg.norm(m, axis=-1, keepdims=True)
        turn = np.clip(np.einsum("tnd,nd->tn", U, m), -1.0, 1.0)
        R = np.negative(turn.T, out=np.empty(D.shape))  # -cos: the angles' order (arccos falls)
        R[~fin] = -np.inf                       # below every angle's: out of the top
        cone = _top_quantile(R, c, 0.95, lambda x: np.arccos(-x))
    return np.where(keep[:, None], m, np.nan), np.where(keep, cone, np.nan)


def _top_quantile(R: np.ndarray, n: np.ndarray, q: float, f) -> np.ndarray:
    """:func:`_col_quantile` of each row of ``R`` (m, T) whose ``n`` values that count are its
    largest (the others -inf; NaN among them last, as a sort puts it), for ``q`` near 1: from
    the row's top values only (a partition, then a sort of those: not a sort of the row)."""
    T = R.shape[1]
    top = min(T, int((1 - q) * T) + 3)      # > (1 - q)(n - 1) + 2: the two order statistics
    if top == 0:
        return np.full(R.shape[0], np.nan)
    S = np.partition(R, T - top, axis=1)[:, T - top:]
    S.sort(axis=1)
    return _col_quantile(S.T, n, q, f, shift=top - n)


def _col_quantile(S: np.ndarray, n: np.ndarray, q: float, f=None, shift=None) -> np.ndarray:
    """``np.nanquantile(D, q, axis=0)`` (linear) from ``S = np.sort(D, axis=0)`` (NaNs last)
    and the finite counts ``n`` per column, without numpy's per-column loop (NaN where n = 0).
    ``f``: a non-decreasing map, the quantile of ``f(D)`` from the two order statistics of
    ``D`` it needs (``f`` applied to two values a column, not to all of ``D``). ``shift`` (per
    column): the order statistics lie that much further down ``S`` (a column's top rows)."""
    p = q * np.maximum(n - 1, 0)
    lo = np.floor(p).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    at = (lo, hi) if shift is None else (np.clip(x + shift, 0, len(S) - 1) for x in (lo, hi))
    a, b = (np.take_along_axis(S, x[None], axis=0)[0] for x in at)
    if f is not None:
        a, b = f(a), f(b)
    return np.where(n > 0, a + (b - a) * (p - lo), np.nan)


def _cluster(J: int, stats: PairStats, least: int) -> list[list[int]]:
    """The data-found segments as sorted marker indices, ordered by their first marker: the
    clusters of the cut :func:`_linkage` makes, with their joint markers
    (:func:`_joints`), and each marker left in a smaller group grown to ``least`` markers by its
    most rigid neighbours (:func:`_grow`); a group of two or more that the cut folded into a
    cluster (:func:`_absorbed`) is grown so too where that is not inside a segment found already
    (a still elbow: the upper arm's pair joined the forearm; grown, it takes the shoulder)."""
    ok = np.isfinite(stats.spread)
    nb: list[dict[int, float]] = [{} for _ in range(J)]
    for a, b, x in zip(stats.j[ok].tolist(), stats.k[ok].tolist(), stats.spread[ok].tolist()):
        nb[a][b] = nb[b][a] = x
    merges = _linkage(nb, least)
    groups, height = _groups(J, merges)
    found = [g + _joints(g, h, nb) for g, h in zip(groups, height) if len(g) >= least]
    found += [_grow(g, least, nb) for g in groups if len(g) < least]
    unique = {tuple(sorted(g)) for g in found if len(g) >= least}
    inner = {tuple(sorted(_grow(g, least, nb))) for g in _absorbed(J, merges, least)}
    unique |= {g for g in inner if len(g) >= least and not any(set(g) <= set(o) for o in unique)}
    return [list(g) for g in sorted(unique)]


def _linkage(nb: list[dict[int, float]], least: int) -> list[tuple[int, int, float]]:
    """Average linkage (UPGMA) along the measured pairs, ``nb[j][k]`` the spread of pair (j, k),
    cut at the first merge where the number of clusters of at least ``least`` markers is largest:
    the merges ``(a, b, height)`` up to there, merged clusters numbered ``J, J + 1, ...``, the
    height the mean spread of the measured pairs between ``a`` and ``b``. Two clusters merge only
    where at least ``MEASURED`` of their pairs were measured and up to ``MAX_SIZE`` markers. The
    linkage stops once the markers still in smaller clusters cannot raise the count."""
    J = len(nb)
    link = [{k: [x, 1] for k, x in d.items()} for d in nb]     # cluster -> [sum, pairs]
    size = [1] * J
    heap = [(x, a, b) for a in range(J) for b, x in nb[a].items() if a < b]
    heapq.heapify(heap)
    merges: list[tuple[int, int, float]] = []
    count = best = stop = 0
    small = J if least > 1 else 0                  # markers in clusters of fewer than least
    while heap and count + small // least > best:
        h, a, b = heapq.heappop(heap)
        if link[a] is None or link[b] is None:
            continue
        n = size[a] + size[b]
        new: dict[int, list] = {}
        for c in (a, b):
            for o, (x, m) in link[c].items():
                if o not in (a, b):
                    e = new.setdefault(o, [0.0, 0])
                    e[0] += x
                    e[1] += m
                    del link[o][c]
        c = len(size)
        for o, e in new.items():
            link[o][c] = e
            if e[1] >= MEASURED * size[o] * n and size[o] + n <= MAX_SIZE:
                heapq.heappush(heap, (e[0] / e[1], o, c))
        link += [new]
        link[a] = link[b] = None
        size.append(n)
        merges.append((a, b, h))
        if n >= least:
            count += 1 - (size[a] >= least) - (size[b] >= least)
            small -= size[a] * (size[a] < least) + size[b] * (size[b] < least)
        if count > best:
            best, stop = count, len(merges)
    return merges[:stop]


def _groups(J: int, merges) -> tuple[list[list[int]], list[float]]:
    """The groups after ``merges`` and the height of each one's last merge (0: one marker)."""
    members = {j: [j] for j in range(J)}
    height = {j: 0.0 for j in range(J)}
    for i, (a, b, h) in enumerate(merges):
        members[J + i] = members.pop(a) + members.pop(b)
        height[J + i] = h
    return list(members.values()), [height[c] for c in members]


def _absorbed(J: int, merges, least: int) -> list[list[int]]:
    """Groups of two to ``least - 1`` markers that one of ``merges`` joined to a cluster of at
    least ``least``: rigid bodies of their own below the cut, which the one height of the cut
    (set where another part of the body reaches the most clusters) folded into a neighbour."""
    members = {j: [j] for j in range(J)}
    out = []
    for i, (a, b, _) in enumerate(merges):
        for x, y in ((a, b), (b, a)):
            if 2 <= len(members[x]) < least <= len(members[y]):
                out.append(members[x])
        members[J + i] = members.pop(a) + members.pop(b)
    return out


def _mean_spread(g: list[int], nb: list[dict[int, float]]) -> dict[int, tuple[float, int]]:
    """For each marker outside ``g`` measured with some of it: (mean spread to them, pairs)."""
    acc: dict[int, list] = {}
    for x in g:
        for y, v in nb[x].items():
            if y not in g:
                e = acc.setdefault(y, [0.0, 0])
                e[0] += v
                e[1] += 1
    return {y: (e[0] / e[1], e[1]) for y, e in acc.items()}


def _joints(g: list[int], height: float, nb: list[dict[int, float]]) -> list[int]:
    """Markers outside cluster ``g`` as rigid with it as its members are with each other (mean
    spread at most the cluster's merge height, measured with at least ``MEASURED`` of it)."""
    return sorted(y for y, (m, n) in _mean_spread(g, nb).items()
                  if m <= height and n >= MEASURED * len(g))


def _grow(g: list[int], least: int, nb: list[dict[int, float]]) -> list[int]:
    """Group ``g`` with its most rigid neighbours (smallest mean spread) up to ``least``."""
    g = list(g)
    while len(g) < least:
        cand = _mean_spread(g, nb)
        if not cand:
            break
        g.append(min(cand, key=lambda y: (cand[y][0], y)))
    return g


def _matched(found: Segments, named: Segments, labels: list[str]):
    """Markers of the named segments of three or more, and each found segment's markers with the
    named segment it shares most markers with (None where it shares none)."""
    named_idx = {s: set(i) for s, i in named.indices(labels).items() if len(i) >= 3}
    markers = set().union(*named_idx.values()) if named_idx else set()
    out = []
    for idx in found.indices(labels).values():
        idx = set(idx)
        best = max(named_idx, key=lambda n: len(named_idx[n] & idx)) if named_idx else None
        out.append((idx, named_idx[best] if best is not None and named_idx[best] & idx else None))
    return markers, out


def agreement(found: Segments, named: Segments, labels: Iterable[str]) -> float:
    """Share of the memberships of the named segments that the found segments agree with: over
    the markers of named segments of three or more, each found segment is matched to the named
    segment it shares most markers with, and a marker agrees when its found segment's match is one
    of its named segments (a marker in no found segment disagrees). Extra found segments never
    lower it: read it with :func:`purity`."""
    markers, match = _matched(found, named, list(labels))
    if not markers:
        return float("nan")
    agree = sum(any(m in idx and hit is not None and m in hit for idx, hit in match)
                for m in markers)
    return agree / len(markers)


def purity(found: Segments, named: Segments, labels: Iterable[str]) -> float:
    """Share of the found memberships (of markers of named segments of three or more) that lie in
    the named segment their found segment is matched to (as in :func:`agreement`): a found segment
    that mixes two named ones, or one marker with two unrelated mates, lowers it."""
    markers, match = _matched(found, named, list(labels))
    total = sum(len(idx & markers) for idx, _ in match)
    if not total:
        return float("nan")
    return sum(len(idx & markers & hit) for idx, hit in match if hit is not None) / total

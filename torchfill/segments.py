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
  only (each marker's ``NEIGHBOURS`` nearest in a few frames: the cost grows linearly with the
  markers, never with their square), the distance while both are observed has a median ``d`` and a
  robust spread ``s`` (1.4826 x MAD); a pair is as rigid as ``s / d`` is small. Skin markers move
  5-15 mm on a segment, so there is no absolute cut: pairs join, most rigid first, into clusters
  while every known pair of the merged cluster stays within ``RELATIVE_SPREAD``.
* **a user file** (:func:`load`): the YAML that :meth:`Segments.to_yaml` writes (``torchfill info
  --segments`` prints it for the segments in use), so a user can check, edit and pass it back
  (``fill(..., segments=path)``, ``torchfill fill --segments FILE``).

This module imports no other torchfill module.
"""
from __future__ import annotations

import json
import re
from collections import OrderedDict
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

__all__ = ["Segments", "resolve", "load", "pair_stats", "neighbour_pairs", "normalize",
           "agreement"]

#: Each marker's nearest neighbours (in a few frames) whose pair distances are measured: the
#: candidates of the data-found segments and of the constraints' rigid pairs.
NEIGHBOURS = 12
#: Frames (evenly spaced) in which the nearest neighbours are looked up.
NEIGHBOUR_FRAMES = 5
#: Pair statistics read at most this many frames, evenly spaced.
PAIR_FRAMES = 12000
#: Pairs are measured this many (frame, pair) entries at a time (8 MB per float64 array).
PAIR_BLOCK = 1 << 20
#: Data-found segments: a merged cluster's known pairs must all have a relative spread s / d at
#: most this (skin markers on one segment: 0.2-5 %; across a moving joint: 5-30 %). Of 0.02 /
#: 0.03 / 0.05 with complete or average linkage, 0.05 complete agreed best with the named tables
#: on HDM05, CMU, Plug-in Gait, OpenSim and Qualisys cluster recordings (scripts/eval_segments.py).
RELATIVE_SPREAD = 0.05
#: Data-found clusters grow to at most this many markers (a body segment carries a few; a dense
#: surface would otherwise merge into one cluster at a cost quadratic in its size).
MAX_SIZE = 24
#: Segments found from the data for a fill also give each marker its own: itself and this many
#: most rigid neighbours (clusters alone left many samples without three mates).
DATA_MATES = 5
#: ... for recordings of at most this many markers (a dense surface has clusters enough).
MATES_UP_TO = 300

# --------------------------------------------------------------------------------------------
# Name tables. Marker names are normalised (lower case, no separators); "#" stands for the side
# letter (l / r) and makes a left and a right segment. A marker may appear in several segments.

_SIDED = {
    # Vicon Plug-in Gait / full body, HDM05, CMU (the same set with LFWT..RBWT waist markers)
    "upper_arm": ["#sho", "#upa", "#elb"],
    "forearm": ["#elb", "#frm", "#fra", "#wra", "#wrb"],
    "hand": ["#wra", "#wrb", "#fin"],
    "thigh": ["#thi", "#thi2", "#kne", "#thap", "#thad", "#kax", "#kd1", "#kd2",
              # CAST-style clusters (Qualisys walking_hybrid), Rajagopal, numbered plates
              "#thigh1", "#thigh2", "#thigh3", "#thigh4", "#th1", "#th2", "#th3", "#th4",
              # OpenSim gait2392 / Hamner
              "#thighupper", "#thighfront", "#thighrear",
              # Helen Hayes (thigh wand), BTS
              "#bar1", "#knee1", "#kne1", "#kne2", "#suppat", "#knjntln",
              # Codamotion wands, Qualisys sports
              "#postfem", "#antfem", "#fle", "#fme", "#ftc", "#knee", "#knm", "#kne_med"],
    "shank": ["#kne", "#tib", "#shn", "#tiap", "#tiad", "#ank", "#mal", "#mall",
              "#shank1", "#shank2", "#shank3", "#shank4", "#sk1", "#sk2", "#sk3", "#sk4",
              "#tb1", "#tb2", "#tb3", "#sh1", "#sh2", "#sh3", "#sh4",
              "#shankupper", "#shankfront", "#shankrear",
              "#bar2", "#tubtib", "#posttib", "#anttib", "#ankle", "#fal", "#tam", "#ankm",
              "#knee"],
    "foot": ["#ank", "#hee", "#toe", "#mt5", "#fmh", "#vmh", "#heel", "#mt1", "#met", "#met1",
             "#cal", "#toetip", "#midfootsup", "#midfootlat", "#toelat", "#toemed",
             "#fcc", "#fm1", "#fm2", "#fm5", "#ft1", "#ft2", "#ft3", "#mal", "#mall"],
    # OpenSim / Rajagopal / Hamner upper limb
    "upper_arm_osim": ["#acromium", "#bicep", "#biceps", "#elbow", "#ua1", "#ua2", "#ua3",
                       "#lel", "#mel", "#shoulder", "#acr"],
    "forearm_osim": ["#elbow", "#forearm", "#wrist", "#wristmed", "#wristlat", "#fasuperior",
                     "#faradius", "#faulna", "#lel", "#mel"],
}
_CENTRAL = {
    "head": ["lfhd", "rfhd", "lbhd", "rbhd", "rtemple", "ltemple", "tophead", "head", "hf", "hb"],
    "thorax": ["c7", "t10", "clav", "strn", "rbak", "rbac", "sternum", "th12", "rclavicle",
               "lclavicle", "rcla", "lcla"],
    "pelvis": ["lasi", "rasi", "lpsi", "rpsi", "sacr", "sacrum", "lfwt", "rfwt", "lbwt", "rbwt",
               "vsacral", "s2", "lasis", "rasis", "lpsis", "rpsis", "lias", "rias", "lips", "rips",
               "lsacwand", "rsacwand", "sacr1", "rasi1", "lasi1", "pv1", "pv2", "pv3", "pv4"],
}


def _table() -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for name, members in _CENTRAL.items():
        out[name] = list(members)
    for name, members in _SIDED.items():
        seg = name.replace("_osim", "")
        for side in "lr":
            out.setdefault(f"{side}_{seg}", [])
            out[f"{side}_{seg}"] += [m.replace("#", side) for m in members]
    return out


#: segment name -> normalised marker names (see the comments above for the marker sets).
TABLE = _table()
_SEGMENTS_OF: dict[str, list[str]] = {}
for _seg, _names in TABLE.items():
    for _n in _names:
        if _seg not in _SEGMENTS_OF.setdefault(_n, []):
            _SEGMENTS_OF[_n].append(_seg)


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
    "user").
    """

    source: str = "user"

    def __init__(self, items=(), source: str = "user"):
        super().__init__()
        for name, members in (items.items() if isinstance(items, Mapping) else items):
            self[str(name)] = [str(m) for m in members]
        self.source = source

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
                  relative_spread: float = RELATIVE_SPREAD, min_size: int = 3,
                  neighbours: int = NEIGHBOURS, mates: int = 0) -> "Segments":
        """Near-rigid clusters of the observed samples of ``X`` (T, J, 3) (see the module
        docstring); clusters of fewer than ``min_size`` markers are left out. Named
        ``cluster1, cluster2, ...`` in the order of their first marker. With ``mates > 0``, also
        one segment per marker (``near:LABEL``): the marker and its ``mates`` most rigid
        neighbours within ``3 x relative_spread`` (the reconstruction's donors where a cluster is
        too small or missing in a frame)."""
        X = np.asarray(X, dtype=np.float64)
        J = X.shape[1]
        labels = [str(x) for x in labels] if labels is not None else [str(j) for j in range(J)]
        stats = pair_stats(X, observed, neighbours=neighbours)
        groups = _cluster(J, stats, relative_spread)
        groups = sorted((sorted(g) for g in groups if len(g) >= min_size), key=lambda g: g[0])
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
        lines = ["# torchfill segments: name -> marker labels (one rigid body each; a marker may",
                 f"# be in several). Found from the {self.source}; edit and pass back with",
                 "# --segments FILE or fill(..., segments=FILE).", "segments:"]
        for seg, members in self.items():
            lines.append(f"  {json.dumps(seg)}: [{', '.join(json.dumps(m) for m in members)}]")
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
    the tables when they cover at least three segments of three markers, else found from the
    data."""
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
            return named
    if X is None:
        return Segments(source="data")
    return Segments.from_data(X, labels, observed, mates=DATA_MATES)


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
    ``J``: markers in the recording.
    """

    def __init__(self, j, k, distance, spread, wide, count, J):
        self.j, self.k = j, k
        self.distance, self.spread, self.wide, self.count, self.J = distance, spread, wide, count, J

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
               neighbours: int = NEIGHBOURS, min_frames: int = 20) -> PairStats:
    """:class:`PairStats` of ``pairs`` (default: :func:`neighbour_pairs`) over at most
    ``PAIR_FRAMES`` evenly spaced frames, a block of pairs at a time. Pairs seen together in fewer
    than ``min_frames`` frames get NaN statistics."""
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
    Xs, obs = X[::stride], observed[::stride]
    T = Xs.shape[0]
    n = j.size
    med, mad, wide = (np.full(n, np.nan) for _ in range(3))
    count = np.zeros(n, np.int64)
    block = max(1, PAIR_BLOCK // max(T, 1))
    for a in range(0, n, block):
        jb, kb = j[a:a + block], k[a:a + block]
        both = obs[:, jb] & obs[:, kb]
        D = np.linalg.norm(Xs[:, jb] - Xs[:, kb], axis=-1)
        D[~both] = np.nan
        c = both.sum(axis=0)
        with np.errstate(all="ignore"):
            m = _col_quantile(np.sort(D, axis=0), c, 0.5)
            dev = np.sort(np.abs(D - m), axis=0)
            s = 1.4826 * _col_quantile(dev, c, 0.5)
            w = _col_quantile(dev, c, 0.95)
        keep = c >= min_frames
        med[a:a + block] = np.where(keep, m, np.nan)
        mad[a:a + block] = np.where(keep, s, np.nan)
        wide[a:a + block] = np.where(keep, w, np.nan)
        count[a:a + block] = c
    return PairStats(j, k, med, mad, wide, count, X.shape[1])


def _col_quantile(S: np.ndarray, n: np.ndarray, q: float) -> np.ndarray:
    """``np.nanquantile(D, q, axis=0)`` (linear) from ``S = np.sort(D, axis=0)`` (NaNs last)
    and the finite counts ``n`` per column, without numpy's per-column loop (NaN where n = 0)."""
    p = q * np.maximum(n - 1, 0)
    lo = np.floor(p).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    a = np.take_along_axis(S, lo[None], axis=0)[0]
    b = np.take_along_axis(S, hi[None], axis=0)[0]
    return np.where(n > 0, a + (b - a) * (p - lo), np.nan)


def _cluster(J: int, stats: PairStats, limit: float) -> list[list[int]]:
    """Agglomerate markers along the measured pairs, most rigid (smallest s / d) first; two
    clusters merge only while every measured pair between them is within ``limit`` and at least
    half of the possible pairs between them were measured (near neighbours of each other)."""
    rel = stats.relative
    ok = np.isfinite(rel) & (rel <= limit)
    order = np.argsort(rel[ok], kind="stable")
    pj, pk = stats.j[ok][order], stats.k[ok][order]
    good = {(int(a), int(b)) for a, b in zip(stats.j[ok], stats.k[ok])}
    measured = {(int(a), int(b)) for a, b in zip(stats.j, stats.k)}
    member = list(range(J))
    groups: dict[int, list[int]] = {j: [j] for j in range(J)}
    for a, b in zip(pj, pk):
        ga, gb = member[a], member[b]
        if ga == gb:
            continue
        A, B = groups[ga], groups[gb]
        if len(A) + len(B) > MAX_SIZE:
            continue
        n_meas = n_good = 0
        for x in A:
            for y in B:
                key = (min(x, y), max(x, y))
                if key in measured:
                    n_meas += 1
                    n_good += key in good
        if n_good < n_meas or 2 * n_meas < len(A) * len(B):
            continue
        if len(A) < len(B):
            ga, gb, A, B = gb, ga, B, A
        A += B
        for y in B:
            member[y] = ga
        del groups[gb]
    return list(groups.values())


def agreement(found: Segments, named: Segments, labels: Iterable[str]) -> float:
    """Share of the memberships of the named segments that the found segments agree with: over
    the markers of named segments of three or more, each found segment is matched to the named
    segment it shares most markers with, and a marker agrees when its found segment's match is one
    of its named segments (a marker in no found segment disagrees)."""
    labels = list(labels)
    named_idx = {s: set(i) for s, i in named.indices(labels).items() if len(i) >= 3}
    found_idx = {s: set(i) for s, i in found.indices(labels).items()}
    markers = set().union(*named_idx.values()) if named_idx else set()
    if not markers:
        return float("nan")
    match = {}
    for s, idx in found_idx.items():
        best = max(named_idx, key=lambda n: len(named_idx[n] & idx))
        match[s] = best if named_idx[best] & idx else None
    agree = 0
    for m in markers:
        mine = [s for s, idx in found_idx.items() if m in idx]
        agree += any(match[s] is not None and m in named_idx[match[s]] for s in mine)
    return agree / len(markers)

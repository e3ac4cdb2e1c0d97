"""OpenPose output folders: one ``*_keypoints.json`` per frame (``--write_json``).

Reading
-------
Each file is one frame, in the order of the frame number in its name (the last run of digits).
``pose_keypoints_2d`` holds ``x, y, confidence`` per keypoint; the layout (BODY_25, COCO, MPI) is
named from the keypoint count. A keypoint with confidence 0 (OpenPose's "not detected"), or below
``min_confidence``, is missing (NaN); the confidences are kept in ``meta["confidence"]`` (T, J),
NaN in frames with no person. ``key="pose_keypoints_3d"`` reads the ``x, y, z, confidence`` quads of
OpenPose's 3-D reconstruction instead.

One person is tracked. A frame with several people (OpenPose does not keep their order between
frames) contributes the one nearest (mean keypoint distance over keypoints seen in both) to the
person chosen in the previous frame; the first choice is the person with the largest total
confidence. A warning says so. The index chosen in each frame is ``meta["person"]`` (-1: none).
``person_id`` is not used (OpenPose leaves it -1 unless its experimental tracking is on).

Writing
-------
A sequence read from a folder is written back as the same files: the tracked person's filled
keypoints get their new ``x, y`` and a confidence (below); every other value (observed keypoints
and their confidences bit for bit), field and person of each JSON is kept. The person also gets
``"torchfill_filled": [j, ...]``, the indices of its filled keypoints (other readers ignore an
unknown field; :func:`read` returns them as ``meta["filled"]``, so that a second fill keeps them
but does not fit to them). Files with nothing filled are copied byte for byte; the others are
re-serialized compactly, as OpenPose writes them (numbers keep their exact value). A frame that
had no person but gets filled keypoints gains one person, ``person_id [-1]``, unfilled keypoints
``0, 0, 0`` (OpenPose's "not detected"). Any other ``(T, J, 2)`` sequence is written as new files
``<folder name>_<frame>_keypoints.json`` (confidence ``meta["confidence"]`` where it holds one
for an observed keypoint, else 1; missing keypoints ``0, 0, 0``). All files are built before
anything is written.

The confidence of a filled keypoint (``fill_confidence=None``, the default) comes from the fill's
error estimate ``meta["std"]`` (pixels, ``fill(..., return_std=True)``)::

    c = c_ref * exp(-(std / s) ** 2 / 2)

``c_ref`` is the median confidence of that keypoint where observed (1 without confidences);
``s`` is 5 % of the person's size (the median over frames of the diagonal of the box around the
observed keypoints; 10 px if no frame has two), so a fill whose error is as large as 5 % of the
body keeps 61 % of the keypoint's usual confidence and one at 10 % keeps 14 % (Pose2Sim's default
threshold, 0.3, then drops it). Without ``meta["std"]`` the error is unknown and
``c = c_ref * UNKNOWN_STD_SHARE``. ``fill_confidence=VALUE`` (in [0, 1]) gives every filled
keypoint that value instead. Confidences are rounded to 6 decimals, as OpenPose prints them.
"""
from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np

from . import FileFormatError
from ..sequence import MarkerSequence
from ._common import atomic_write, filled_samples, unwritten_edits

BODY_25 = ("Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist",
           "MidHip", "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar",
           "LEar", "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel")
COCO = ("Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "RHip",
        "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar")
MPI = ("Head", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "RHip",
       "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "Chest")
LAYOUTS = {25: ("BODY_25", BODY_25), 18: ("COCO", COCO), 15: ("MPI", MPI)}
PATTERN = "*_keypoints.json"
#: The field a person gets listing its filled keypoints (indices).
FILLED_FIELD = "torchfill_filled"
#: Size of a person relative to which a fill's std is judged (see the module notes).
SCALE_SHARE = 0.05
#: Confidence share of a filled keypoint whose fill has no error estimate.
UNKNOWN_STD_SHARE = 0.5


def _fail(path, problem: str):
    raise FileFormatError(f"{path}: {problem}")


# -- reading ---------------------------------------------------------------------------------------
def frame_files(folder: Path) -> list[Path]:
    """The ``*_keypoints.json`` files of ``folder``, in frame order."""
    if not folder.is_dir():
        _fail(folder, "no such folder")
    files = [f for f in folder.glob(PATTERN) if f.is_file()]
    if not files:
        _fail(folder, f"no OpenPose {PATTERN} files in this folder")

    def order(f: Path):
        digits = re.findall(r"\d+", f.name[:-len("_keypoints.json")])
        return (int(digits[-1]) if digits else -1, f.name)
    return sorted(files, key=order)


def _filled_field(person, n: int, path: Path, i: int) -> list[int]:
    """The keypoint indices a person's ``torchfill_filled`` field lists (checked)."""
    value = person.get(FILLED_FIELD, []) if isinstance(person, dict) else []
    if not (isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool)
                                            and 0 <= v < n for v in value)):
        _fail(path, f"people[{i}].{FILLED_FIELD} expected keypoint indices 0-{n - 1}")
    return value


def parse_frame(path: Path, key: str, width: int) -> tuple[dict, list[np.ndarray | None]]:
    """The JSON object of one frame and, per person, its keypoints as ``(J, width)`` (None when
    the person has none under ``key``)."""
    try:
        obj = json.loads(path.read_bytes())
    except json.JSONDecodeError as err:
        _fail(path, f"not valid JSON ({err.msg} at line {err.lineno} column {err.colno})")
    except UnicodeDecodeError:
        _fail(path, "not valid JSON (not UTF-8 text)")
    except OSError as err:
        _fail(path, f"cannot read ({err.strerror or err})")
    if not isinstance(obj, dict) or not isinstance(obj.get("people"), list):
        _fail(path, "not an OpenPose keypoints file (no 'people' list)")
    people = []
    for i, person in enumerate(obj["people"]):
        values = person.get(key, []) if isinstance(person, dict) else None
        if not isinstance(values, list):
            _fail(path, f"people[{i}].{key} expected a list of numbers")
        if not values:
            people.append(None)
            continue
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                   for v in values):
            _fail(path, f"people[{i}].{key} holds a value that is not a finite number")
        if len(values) % width:
            _fail(path, f"people[{i}].{key} has {len(values)} values, not a multiple of {width}")
        people.append(np.array(values, dtype=np.float64).reshape(-1, width))
    return obj, people


def _choose(people: list[np.ndarray | None], previous: np.ndarray | None) -> int:
    """Index of the tracked person in one frame (-1: none); see the module notes."""
    present = [i for i, p in enumerate(people) if p is not None]
    if len(present) <= 1:
        return present[0] if present else -1
    score = {i: float(people[i][:, -1].clip(min=0).sum()) for i in present}
    if previous is not None:
        dist = {}
        for i in present:
            both = (people[i][:, -1] > 0) & np.isfinite(previous[:, 0])
            if both.any():
                dist[i] = float(np.linalg.norm(people[i][both, :-1] - previous[both], axis=1).mean())
        if dist:
            return min(dist, key=dist.get)
    return max(present, key=score.get)


def read(path, *, min_confidence: float = 0.0, key: str = "pose_keypoints_2d",
         rate: float = 30.0, include_filled: bool = False,
         markers_only: bool = True) -> MarkerSequence:
    """Read an OpenPose output folder into a ``(T, J, 2)`` :class:`MarkerSequence` (pixels).

    ``rate`` is the video frame rate (not stored by OpenPose; 30 by default). Keypoints a
    person's ``torchfill_filled`` field lists are read whatever their confidence, and
    ``meta["filled"]`` marks them. ``include_filled=True`` also takes a keypoint with confidence
    0 but coordinates other than (0, 0) (OpenPose writes an undetected keypoint as 0, 0, 0) for
    a fill (folders written before the field existed). ``markers_only`` is accepted for a uniform
    signature and ignored.
    """
    folder = Path(path)
    if not (isinstance(min_confidence, (int, float)) and 0.0 <= min_confidence <= 1.0):
        _fail(folder, f"min_confidence expected a number in [0, 1], found {min_confidence!r}")
    width = 4 if key.endswith("_3d") else 3
    files = frame_files(folder)
    points, conf, chosen, crowded, marked = [], [], [], 0, []
    J, previous = None, None
    for f in files:
        obj, people = parse_frame(f, key, width)
        i = _choose(people, previous)
        crowded = max(crowded, sum(p is not None for p in people))
        chosen.append(i)
        if i < 0:
            points.append(None)
            conf.append(None)
            marked.append([])
            continue
        K = people[i]
        if J is None:
            J = K.shape[0]
        elif K.shape[0] != J:
            _fail(f, f"{K.shape[0]} keypoints, the frames before have {J}")
        seen = (K[:, -1] > 0) & (K[:, -1] >= min_confidence)
        marked.append(_filled_field(obj["people"][i], K.shape[0], f, i))
        seen[marked[-1]] = True                       # torchfill's fills, whatever confidence
        if include_filled:
            seen |= (K[:, -1] == 0) & (K[:, :-1] != 0).any(axis=1)
        points.append(np.where(seen[:, None], K[:, :-1], np.nan))
        conf.append(K[:, -1])
        previous = points[-1]
    if J is None:
        _fail(folder, f"no person with {key} in any of the {len(files)} frames")
    empty = np.full((J, width - 1), np.nan)
    P = np.stack([p if p is not None else empty for p in points])
    C = np.stack([c if c is not None else np.full(J, np.nan) for c in conf])
    layout, names = LAYOUTS.get(J, (None, None)) if width == 3 else (None, None)
    if crowded > 1:
        warnings.warn(f"{folder}: up to {crowded} people per frame; tracking one (nearest to the "
                      "previous frame's choice, see meta['person'])", UserWarning, stacklevel=2)
    meta = {"format": "openpose", "layout": layout, "key": key, "files": [f.name for f in files],
            "person": chosen, "confidence": C, "min_confidence": float(min_confidence)}
    filled = np.zeros(P.shape[:2], dtype=bool)
    for t, js in enumerate(marked):
        filled[t, js] = True
    if include_filled:
        filled |= (C == 0) & np.isfinite(P).all(axis=2)
    filled &= np.isfinite(P).all(axis=2)
    if filled.any():
        meta["filled"] = filled
    return MarkerSequence(points=P, labels=list(names or (f"K{j}" for j in range(J))),
                          rate=float(rate), units="px", source=folder, meta=meta)


# -- writing ---------------------------------------------------------------------------------------
def write(seq: MarkerSequence, path, *, fill_confidence: float | None = None) -> None:
    """Write ``seq`` as an OpenPose folder (see the module notes); nothing is written on error.

    ``fill_confidence``: the confidence of every filled keypoint, in [0, 1] (default: derived
    from ``meta["std"]``, see the module notes).
    """
    folder = Path(path)
    if not isinstance(seq, MarkerSequence):
        _fail(folder, f"expected a MarkerSequence to write, found {type(seq).__name__}")
    if fill_confidence is not None and not (
            isinstance(fill_confidence, (int, float)) and not isinstance(fill_confidence, bool)
            and 0.0 <= fill_confidence <= 1.0):
        _fail(folder, f"fill_confidence expected a number in [0, 1], found {fill_confidence!r}")
    if folder.exists() and not folder.is_dir():
        _fail(folder, "exists and is not a folder")
    if np.isinf(seq.points).any():
        _fail(folder, "cannot write infinite coordinates (use NaN for missing)")
    if _is_write_back(seq):
        files = _write_back_files(seq, folder, fill_confidence)
    else:
        files = _fresh_files(seq, folder, fill_confidence)
    _write_folder(folder, files)


def fill_confidences(points: np.ndarray, observed: np.ndarray, confidence: np.ndarray | None,
                     std: np.ndarray | None, fill_confidence: float | None) -> np.ndarray:
    """``(T, J)`` confidences for filled keypoints (the module notes give the mapping).

    ``points`` (T, J, 2) with fills, ``observed`` (T, J) the keypoints seen, ``confidence`` their
    confidences (None: 1), ``std`` the fill's error estimate in pixels (None: unknown)."""
    T, J = observed.shape
    if fill_confidence is not None:
        return np.full((T, J), float(fill_confidence))
    conf = np.where(observed, 1.0 if confidence is None else confidence, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)           # keypoints never observed
        ref = np.nanmedian(conf, axis=0)
    ref = np.where(np.isfinite(ref), ref, 1.0)
    if std is None or np.shape(std) != (T, J):
        share = np.full((T, J), UNKNOWN_STD_SHARE)
    else:
        xy = np.where(observed[..., None], points, np.nan)
        enough = observed.sum(axis=1) >= 2
        size = 0.0
        if enough.any():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                span = np.nanmax(xy[enough], axis=1) - np.nanmin(xy[enough], axis=1)
            size = float(np.median(np.hypot(span[:, 0], span[:, 1])))
        s = SCALE_SHARE * size if size > 0 else 10.0
        sd = np.asarray(std, dtype=np.float64)
        share = np.where(np.isfinite(sd), np.exp(-0.5 * (np.nan_to_num(sd) / s) ** 2),
                         UNKNOWN_STD_SHARE)
    return np.round(np.clip(ref[None, :] * share, 0.0, 1.0), 6)


def _is_write_back(seq: MarkerSequence) -> bool:
    return (seq.meta.get("format") == "openpose" and seq.source is not None
            and len(seq.meta.get("files", ())) == seq.n_frames)


def _write_back_files(seq: MarkerSequence, folder: Path,
                      fill_confidence: float | None) -> dict[str, bytes]:
    key, meta = seq.meta["key"], seq.meta
    if not seq.source.is_dir():
        _fail(folder, f"source folder {seq.source} is gone")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                   # the reader's warnings were given once
        source = read(seq.source, min_confidence=meta["min_confidence"], key=key)
    if source.meta["files"] != meta["files"] or source.n_frames != seq.n_frames:
        _fail(folder, f"source folder {seq.source} changed since it was read")
    if source.labels != seq.labels or source.points.shape != seq.points.shape:
        _fail(folder, f"a write-back needs the {source.n_markers} keypoints of {seq.source} in "
                      f"their order, found {seq.n_markers} ({', '.join(seq.labels[:4])} ...)")
    filled = filled_samples(seq, ~source.mask, folder)
    skipped = unwritten_edits(seq, source.points, filled)
    if skipped:
        warnings.warn(f"{folder}: {skipped} sample(s) differ from the source but were not filled "
                      "there; they are not written", UserWarning, stacklevel=3)
    width = seq.points.shape[2] + 1
    observed = ~source.mask & ~source.meta.get("filled", np.zeros_like(filled))
    conf = fill_confidences(seq.points, observed, source.meta["confidence"],
                            seq.meta.get("std"), fill_confidence)
    had = source.meta.get("filled", np.zeros_like(filled))
    out = {}
    for t, name in enumerate(meta["files"]):
        raw = (seq.source / name).read_bytes()
        if not filled[t].any() and not had[t].any():
            out[name] = raw
            continue
        obj = json.loads(raw)
        person = source.meta["person"][t]
        if person < 0:
            obj["people"].append({"person_id": [-1], key: [0.0] * (width * seq.n_markers)})
            person = len(obj["people"]) - 1
        values = obj["people"][person][key]
        for j in np.flatnonzero(filled[t]):
            values[width * j:width * j + width - 1] = [float(v) for v in seq.points[t, j]]
            values[width * j + width - 1] = float(conf[t, j])
        obj["people"][person].pop(FILLED_FIELD, None)
        if filled[t].any():
            obj["people"][person][FILLED_FIELD] = [int(j) for j in np.flatnonzero(filled[t])]
        out[name] = json.dumps(obj, separators=(",", ":")).encode("utf-8")
    return out


def _fresh_files(seq: MarkerSequence, folder: Path,
                 fill_confidence: float | None) -> dict[str, bytes]:
    if seq.points.shape[2] != 2:
        _fail(folder, f"OpenPose keypoints are 2-D; found {seq.points.shape[2]} coordinates")
    present = np.isfinite(seq.points).all(axis=2)
    filled = np.asarray(seq.meta.get("filled", np.zeros_like(present)), dtype=bool)
    if filled.shape != present.shape:
        filled = np.zeros_like(present)
    filled &= present
    observed = present & ~filled
    given = seq.meta.get("confidence")
    given = (np.asarray(given, dtype=np.float64) if given is not None
             and np.shape(given) == present.shape else None)
    own = np.where(observed & np.isfinite(given) & (given > 0), given, 1.0) \
        if given is not None else np.ones(present.shape)
    made = fill_confidences(seq.points, observed, own, seq.meta.get("std"), fill_confidence)
    conf = np.where(observed, own, np.where(filled, made, 0.0))
    xy = np.where(present[..., None], seq.points, 0.0)
    values = np.concatenate([xy, conf[..., None]], axis=2).reshape(seq.n_frames, -1)
    name = folder.name or "frames"
    out = {}
    for t, row in enumerate(values):
        person = {"person_id": [-1], "pose_keypoints_2d": row.tolist()}
        if filled[t].any():
            person[FILLED_FIELD] = [int(j) for j in np.flatnonzero(filled[t])]
        out[f"{name}_{t:012d}_keypoints.json"] = json.dumps(
            {"version": 1.3, "people": [person]}, separators=(",", ":")).encode("utf-8")
    return out


def _write_folder(folder: Path, files: dict[str, bytes]) -> None:
    """Existing folder: each file replaced atomically. New folder: built under a temporary name
    beside it, then renamed, so a failure leaves nothing behind."""
    if folder.is_dir():
        for name, data in files.items():
            atomic_write(folder / name, lambda handle, data=data: handle.write(data))
        return
    parent = folder.parent if str(folder.parent) else Path(".")
    if not parent.is_dir():
        _fail(folder, f"cannot write, folder {parent} does not exist")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=parent))
    except OSError as err:
        _fail(folder, f"cannot write ({err.strerror or err})")
    try:
        for name, data in files.items():
            (tmp / name).write_bytes(data)
        os.chmod(tmp, 0o777 & ~_umask())
        os.replace(tmp, folder)
    except OSError as err:
        shutil.rmtree(tmp, ignore_errors=True)
        _fail(folder, f"cannot write ({err.strerror or err})")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


__all__ = ["BODY_25", "COCO", "MPI", "read", "write"]

"""OpenPose output folders: read -> fill -> write -> read keeps every observed keypoint bit for bit
and every other JSON field; bad JSON is a one-line error naming the file; several people."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import torchfill
from torchfill.cli import main
from torchfill.io import FileFormatError, openpose

T, J = 90, 25
OTHER_FIELDS = {"face_keypoints_2d": [], "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": [],
                "pose_keypoints_3d": [], "face_keypoints_3d": [], "hand_left_keypoints_3d": [],
                "hand_right_keypoints_3d": []}


def track(seed: int = 0, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Smooth keypoints (T, J, 2) in pixels, 3 decimals as OpenPose prints them, and confidences."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / 30.0
    base = rng.uniform(200, 800, (1, J, 2)) + offset
    xy = np.round(base + 40 * np.sin(2 * np.pi * 0.7 * t + rng.uniform(0, 6, (1, J, 2))), 3)
    conf = np.round(rng.uniform(0.35, 0.95, (T, J)), 6)
    return xy, conf


def frame_text(people: list[tuple[np.ndarray, np.ndarray]]) -> str:
    """One frame as OpenPose writes it (compact, undetected keypoints as integer 0,0,0)."""
    def fmt(x, y, c):
        return "0,0,0" if c == 0 else f"{x:.3f},{y:.3f},{c:.6f}"
    body = []
    for xy, conf in people:
        values = ",".join(fmt(*xy[j], conf[j]) for j in range(len(conf)))
        rest = ",".join(f'"{k}":[]' for k in OTHER_FIELDS)
        body.append(f'{{"person_id":[-1],"pose_keypoints_2d":[{values}],{rest}}}')
    return '{"version":1.3,"people":[' + ",".join(body) + "]}\n"


@pytest.fixture
def folder(tmp_path) -> tuple[Path, np.ndarray, np.ndarray]:
    """A BODY_25 folder: gaps (confidence 0), a frame with nobody, a second person in some frames
    listed first, and low-confidence keypoints."""
    xy, conf = track(0)
    conf[20:45, 4] = 0.0                                   # right wrist lost for 25 frames
    conf[50:70, 10] = 0.0                                  # right knee
    conf[:3, 0] = 0.0                                      # nose at the start
    conf[60, 7] = 0.05                                     # a low-confidence left wrist
    other_xy, other_conf = track(1, offset=1500.0)        # a bystander far to the right
    out = tmp_path / "clip_json"
    out.mkdir()
    for t in range(T):
        people = [] if t == 33 else [(xy[t], conf[t])]
        if 10 <= t < 30 and t != 33:
            people.insert(0, (other_xy[t], other_conf[t]))
        (out / f"clip_{t:012d}_keypoints.json").write_text(frame_text(people))
    return out, xy, conf


def test_read_layout_missing_and_tracking(folder):
    path, xy, conf = folder
    with pytest.warns(UserWarning, match="up to 2 people"):
        seq = torchfill.read(path)
    assert seq.points.shape == (T, J, 2) and seq.labels == list(openpose.BODY_25)
    assert seq.units == "px" and seq.meta["layout"] == "BODY_25"
    observed = conf > 0
    observed[33] = False
    assert np.array_equal(~seq.mask, observed)
    assert np.array_equal(seq.points[observed], xy[observed])        # the tracked person, exact
    assert seq.meta["person"][33] == -1 and seq.meta["person"][15] == 1


def test_min_confidence_makes_low_keypoints_missing(folder):
    path, _, conf = folder
    with pytest.warns(UserWarning):
        seq = torchfill.read(path, min_confidence=0.1)
    assert seq.mask[60, 7] and seq.meta["confidence"][60, 7] == 0.05


def test_round_trip_keeps_observed_and_every_other_field(folder, tmp_path):
    path, xy, conf = folder
    with pytest.warns(UserWarning):
        seq = torchfill.read(path)
    filled = torchfill.fill(seq)
    out = tmp_path / "filled_json"
    with pytest.warns(UserWarning):
        torchfill.write(filled, out)
        back = torchfill.read(out)
    assert sorted(p.name for p in out.iterdir()) == seq.meta["files"]
    observed = ~seq.mask
    assert np.array_equal(back.points[observed], seq.points[observed])        # bit for bit
    assert np.array_equal(back.meta["confidence"][observed], seq.meta["confidence"][observed])
    changed = 0
    for t, name in enumerate(seq.meta["files"]):
        before, after = (path / name).read_bytes(), (out / name).read_bytes()
        if not filled.meta["filled"][t].any():
            assert before == after                                             # byte for byte
            continue
        changed += 1
        a, b = json.loads(before), json.loads(after)
        p = seq.meta["person"][t]
        marks = np.flatnonzero(filled.meta["filled"][t]).tolist()
        if p < 0:                                        # nobody there: one person added
            assert len(b["people"]) == len(a["people"]) + 1
            assert b["people"][-1]["torchfill_filled"] == marks
            continue
        kp_a, kp_b = a["people"][p].pop("pose_keypoints_2d"), b["people"][p].pop("pose_keypoints_2d")
        assert b["people"][p].pop("torchfill_filled") == marks
        assert a == b                                   # every other field and person unchanged
        for j in range(J):
            same = kp_a[3 * j:3 * j + 3] == kp_b[3 * j:3 * j + 3]
            assert same != bool(filled.meta["filled"][t, j])   # observed: x, y, c bit for bit
            if filled.meta["filled"][t, j]:
                assert kp_b[3 * j:3 * j + 2] == filled.points[t, j].tolist()
                # no std estimate: half the keypoint's median observed confidence
                ref = np.median(seq.meta["confidence"][observed[:, j], j])
                assert kp_b[3 * j + 2] == pytest.approx(0.5 * ref, abs=1e-6)
    assert changed == int(filled.meta["filled"].any(axis=1).sum()) > 0
    with pytest.warns(UserWarning):
        seen = torchfill.read(out)                             # the fills, read back as data
    assert np.array_equal(seen.points, filled.points, equal_nan=True)
    assert np.array_equal(seen.meta["filled"], filled.meta["filled"])


def test_fill_confidence_from_std_or_constant(folder, tmp_path):
    """Filled keypoints: c = c_ref exp(-(std/s)^2/2), or the constant asked for; observed ones
    keep theirs."""
    path, xy, conf = folder
    with pytest.warns(UserWarning):
        seq = torchfill.read(path)
    filled, std = torchfill.fill(seq, "linear", return_std=True)
    mark = filled.meta["filled"]
    for option, name in ((None, "std"), (0.42, "const")):
        out = tmp_path / name
        with pytest.warns(UserWarning):
            torchfill.write(filled, out, fill_confidence=option)
            back = torchfill.read(out)
        c = back.meta["confidence"]
        observed = ~seq.mask
        assert np.array_equal(c[observed], seq.meta["confidence"][observed])
        if option is not None:
            assert (c[mark] == option).all()
            continue
        assert np.isfinite(std[mark]).all()
        ok = observed
        span = [np.ptp(seq.points[t][ok[t]], axis=0) for t in range(T) if ok[t].sum() >= 2]
        s = 0.05 * np.median([np.hypot(*d) for d in span])
        ref = np.array([np.median(seq.meta["confidence"][ok[:, j], j]) for j in range(J)])
        t, j = np.nonzero(mark)
        np.testing.assert_allclose(c[t, j], ref[j] * np.exp(-0.5 * (std[t, j] / s) ** 2),
                                   atol=1e-6)
        # a larger std, a lower confidence (up to the file's 1e-6 rounding of c, over ref)
        order = np.argsort(std[t, j] / 1.0)
        assert (np.diff((c[t, j] / ref[j])[order]) <= 1e-6 / ref.min()).all()
    gap = slice(20, 45)                        # the filled wrist stays near the true track
    err = np.abs(filled.points[gap, 4] - xy[gap, 4]).max()
    assert err < 80.0, err


def test_cli_fill_info_and_min_confidence(folder, tmp_path, capsys):
    path, _, _ = folder
    out = tmp_path / "out_json"
    assert main(["fill", str(path), "-o", str(out), "-m", "linear", "-q"]) == 0
    assert len(list(out.glob("*_keypoints.json"))) == T
    capsys.readouterr()

    def missing(*options) -> dict[str, int]:             # the 'missing' column of info, per label
        assert main(["info", str(path), *options]) == 0
        return {line.split()[0]: int(line.split()[1]) for line in capsys.readouterr().out
                .splitlines() if line.split() and line.split()[0] in openpose.BODY_25}
    plain, strict = missing(), missing("--min-confidence", "0.1")
    assert plain["RWrist"] == strict["RWrist"] == 25             # frames 20-44 (33: nobody)
    assert (plain["LWrist"], strict["LWrist"]) == (1, 2)         # the 0.05 keypoint joins


@pytest.mark.parametrize("content, needle", [
    ('{"version":1.3,"people":[{"pose_keypoints_2d":[1,2', "not valid JSON"),
    ("[1, 2, 3]", "no 'people' list"),
    ('{"people":[{"pose_keypoints_2d":[1,2,0.5,4]}]}', "not a multiple of 3"),
    ('{"people":[{"pose_keypoints_2d":[1,"a",0.5]}]}', "not a finite number"),
    ('{"people":[{"pose_keypoints_2d":[1,2,0.5,3,4,0.5]}]}', "2 keypoints, the frames before have 25"),
    (b"\x80{}", "not UTF-8"),
])
def test_bad_json_is_one_line_naming_the_file_and_nothing_written(folder, tmp_path, capsys,
                                                                   content, needle):
    path, _, _ = folder
    bad = path / f"clip_{40:012d}_keypoints.json"
    bad.write_bytes(content if isinstance(content, bytes) else content.encode())
    out = tmp_path / "never"
    assert main(["fill", str(path), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"torchfill: error: {bad}: ") and needle in err[0]
    assert not out.exists() and not list(tmp_path.glob(".never*"))


def test_empty_folder_and_no_person_are_errors(tmp_path):
    with pytest.raises(FileFormatError, match="no OpenPose"):
        torchfill.read(tmp_path)
    (tmp_path / "a_000000000000_keypoints.json").write_text('{"version":1.3,"people":[]}')
    with pytest.raises(FileFormatError, match="no person"):
        torchfill.read(tmp_path)


def test_coco_layout_and_fresh_folder_from_an_array(tmp_path):
    xy, _ = track(2)
    xy = xy[:, :18]
    xy[10:30, 3] = np.nan
    out = torchfill.write(xy, tmp_path / "coco")
    seq = torchfill.read(out)
    assert seq.labels == list(openpose.COCO) and seq.meta["layout"] == "COCO"
    assert np.array_equal(seq.points, xy, equal_nan=True)


def test_3d_points_are_refused_for_a_fresh_folder(tmp_path):
    with pytest.raises(FileFormatError, match="2-D"):
        torchfill.write(np.zeros((5, 3, 3)), tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_cli_evaluate_on_a_folder(tmp_path, capsys):
    xy, _ = track(3)
    folder = torchfill.write(xy, tmp_path / "walk")
    code = main(["evaluate", str(folder), "-m", "linear,pchip", "--markers", "4",
                 "--gap-length", "20", "--max-gaps", "2", "--json", "-q"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["units"] == "px" and [r["method"] for r in result["results"]] == ["linear", "pchip"]
    assert all(r["rmse_missing"] > 0 for r in result["results"])


def test_write_back_of_a_subset_of_keypoints_is_refused(folder, tmp_path):
    path, _, _ = folder
    with pytest.warns(UserWarning):
        part = torchfill.read(path).select([0, 1, 2])
    with pytest.raises(FileFormatError, match="needs the 25 keypoints"):
        torchfill.write(part, tmp_path / "part")
    assert not (tmp_path / "part").exists()

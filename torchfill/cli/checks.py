"""Input and output paths checked now, before any file is read: one line naming the path."""
from __future__ import annotations

from pathlib import Path


def _check_input(path: Path, batch_hint: bool = False) -> None:
    """One line now if ``path`` cannot be read as a recording: missing, of an unknown type, or a
    folder of recordings (not an OpenPose folder) without ``--out-dir``."""
    from torchfill.io import FileFormatError, _pick

    if not path.exists():
        raise FileFormatError(f"{path}: no such file")
    if path.is_dir():
        from torchfill.batch import SUFFIXES
        from torchfill.io.openpose import PATTERN

        if not any(path.glob(PATTERN)):
            found = [p for p in path.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES]
            if found and batch_hint:
                raise FileFormatError(f"{path}: a folder of {len(found)} recording(s), not an "
                                      f"OpenPose folder; fill them all with --out-dir DIR")
            raise FileFormatError(f"{path}: a folder with no recordings and no OpenPose "
                                  f"{PATTERN} files")
        return
    _pick(path, "read")


def _check_format(out: Path, openpose: bool) -> None:
    """The output's type from its suffix, now (a folder without suffix: OpenPose output)."""
    from torchfill.io import FileFormatError, _pick

    if not out.suffix and not openpose:
        raise FileFormatError(f"{out}: no file type; give a suffix (.c3d, .trc, .npy, .npz, "
                              ".csv)")
    _pick(out, "write")


#: The hint after a ``--report`` name of another format.
REPORT_ALSO = " (the per-gap verdicts as JSON: --report-json FILE.json)"


def _check_suffix(path: Path, suffix: str, option: str, also: str = "") -> None:
    """One line now if ``path`` does not end in ``suffix`` (or ``.htm`` for ``.html``): the file
    would hold another format than its name says (``also``: what to use instead)."""
    if path.suffix.lower() != suffix and (suffix, path.suffix.lower()) != (".html", ".htm"):
        raise ValueError(f"{path}: {option} writes {suffix}, found "
                         f"{path.suffix or 'no suffix'}{also}")

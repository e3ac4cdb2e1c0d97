"""``torchfill info IN`` and ``torchfill methods``."""
from __future__ import annotations

import sys

from .options import _pose_options
from .qc import _frame0
from .terminal import _shown


def _cmd_info(args) -> int:
    import torchfill
    from torchfill.metrics import gap_runs

    seq = torchfill.read(args.input, markers_only=not args.all_points, **_pose_options(args))
    if args.segments is not None:          # the segments a fill would use, as an editable YAML
        from torchfill.segments import resolve
        source = None if args.segments == "auto" else args.segments
        segs = resolve(source, seq.labels, seq.points, ~seq.mask)
        sys.stdout.write(segs.to_yaml())
        return 0
    T = seq.n_frames
    never = seq.mask.all(axis=0)
    runs = [(j, a, b) for j, a, b in gap_runs(seq.mask) if not never[j]]   # gaps of seen markers
    inner = [b - a for _, a, b in runs if a > 0 and b < T]
    seen = seq.mask[:, ~never]
    labels = [_shown(label) for label in seq.labels]     # a newline in a label stays visible too
    print(seq)
    f0 = _frame0(seq)
    print(f"frames {T} (numbered {f0}-{f0 + T - 1} as in the file), markers {seq.n_markers}, "
          f"rate {seq.rate:g} Hz, units {_shown(seq.units)}, "
          f"{len(runs)} gaps, longest {max((b - a for _, a, b in runs), default=0)} frames")
    print(f"  {len(inner)} interior gap(s) (longest {max(inner, default=0)} frames), "
          f"{len(runs) - len(inner)} at the trial ends; "
          f"{100.0 * seen.mean() if seen.size else 0.0:.1f}% missing in observed markers; "
          f"{int(seq.mask.all(axis=1).sum())} frame(s) with no marker seen")
    if never.any():
        print(f"  {int(never.sum())} marker(s) never observed: "
              f"{', '.join(labels[j] for j in range(seq.n_markers) if never[j])}")
    dups = seq.duplicates()
    if dups:
        print("  duplicate labels: " + ", ".join(f"{_shown(label)} "
                                                 f"(markers {', '.join(map(str, idx))})"
                                                 for label, idx in dups.items()))
    width = max((len(label) for label in labels), default=6)
    print(f"{'marker':<{width}}  {'missing':>8}  {'gaps':>5}  {'longest':>7}  "
          "frames (file's numbering)")
    for j, label in enumerate(labels):
        spans = [(a, b) for k, a, b in runs if k == j]
        own = [b - a for a, b in spans]
        if own or never[j] or args.all_markers:
            where = ", ".join(f"{f0 + a}-{f0 + b - 1}" for a, b in spans[:4]) + \
                (f", ... ({len(spans)} gaps)" if len(spans) > 4 else "")
            print(f"{label:<{width}}  {int(seq.mask[:, j].sum()):>8}  {len(own):>5}  "
                  f"{max(own, default=0):>7}  " + ("never observed" if never[j] else where))
    return 0


def _cmd_methods(args) -> int:
    """One row per method: name (the default marked), speed class, 2-D keypoints, training
    recordings, the summary's first sentence wrapped to the terminal; ``-v`` adds the
    hyperparameters (that imports torch)."""
    import re
    import shutil
    import textwrap

    from torchfill._catalog import catalog, default

    best = default()
    head = f"{'method':<15}{'speed':<8}{'2-D':<5}{'training':<10}"
    tty = getattr(sys.stdout, "isatty", lambda: False)()
    width = max((shutil.get_terminal_size().columns if tty else 100) - len(head), 30)
    print(head + "summary")
    declared = _declared() if args.verbose else {}
    for e in catalog():
        name = e.name + (" *" if e.name == best else "")
        text = re.sub(r"``(.*?)``", r"\1", e.summary)          # reST code spans: plain text
        lines = textwrap.wrap(text, width, break_on_hyphens=False) or [""]
        print(f"{name:<15}{e.speed:<8}{'yes' if e.planar else 'no':<5}"
              f"{'optional' if e.training else '-':<10}{lines[0]}")
        for line in lines[1:]:
            print(" " * len(head) + line)
        for key, spec in declared.get(e.name, {}).items():
            print(f"    {key} = {spec.default!r}  {spec.doc}")
    print("\n".join(textwrap.wrap(
        "* the default (fill without -m). speed on 3000 frames x 41 markers: fast about a second "
        "or less, medium a few seconds, slow tens of seconds (docs/speed.md); 2-D: takes (T, J, "
        "2) keypoints; training: learns from other recordings if given (--training)",
        len(head) + width, subsequent_indent="  ")))
    return 0


def _declared() -> dict:
    from torchfill.solvers import base

    return {name: base._REGISTRY[name].declared_params() for name in base.available()}
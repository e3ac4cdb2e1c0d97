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
    if not args.verbose:  # names and summaries read from the sources: no torch import
        from torchfill._catalog import entries

        for name, doc in entries():
            print(f"{name:<14} {doc}")
        return 0
    from torchfill.solvers import base

    for name in base.available():
        cls = base._REGISTRY[name]
        doc = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
        print(f"{name:<14} {doc}")
        if args.verbose:
            for key, spec in cls.declared_params().items():
                print(f"    {key} = {spec.default!r}  {spec.doc}")
    return 0

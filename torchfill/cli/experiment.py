"""``torchfill experiment CONFIG``: the Lightning runner."""
from __future__ import annotations


def _cmd_experiment(args) -> int:
    try:
        from torchfill.lightning.runner import run_experiment
    except ImportError as err:            # the optional [experiments] extra is not installed
        if "torchfill[experiments]" not in str(err):
            raise
        raise ValueError(str(err)) from None

    out = run_experiment(args.config, resume=args.resume, workers=args.workers,
                         limit=args.limit, output=args.output, report_only=args.report_only,
                         ray_address=args.ray)
    print(f"results in {out}")
    return 0

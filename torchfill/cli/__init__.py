"""Command line: ``torchfill fill | qc | evaluate | info | methods | experiment``
(also ``python -m torchfill``).

Every failure on bad input prints one line, ``torchfill: error: <file>: <problem>``, and exits
with status 2; nothing is written unless the whole fill succeeded.
"""
from __future__ import annotations

import os
import sys
import warnings

from .options import _parse_params  # noqa: F401  (tests and the docs generator use these names)
from .parser import _parser
from .terminal import (EXIT_ERROR, _Escaping, _install_signal_handlers, _one_line, _set_threads,
                       _silence_stdout)


def main(argv: list[str] | None = None) -> int:
    _install_signal_handlers()
    saved = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _Escaping(sys.stdout), _Escaping(sys.stderr)
    try:
        return _main(argv)
    finally:
        sys.stdout, sys.stderr = saved


def _main(argv: list[str] | None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return EXIT_ERROR
    try:
        _set_threads(getattr(args, "threads", None))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            status = args.run(args)
        for w in caught if getattr(args, "quiet", 0) < 2 else ():      # -qq: errors only
            if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning)):
                print(f"torchfill: warning: {_one_line(w.message)}", file=sys.stderr)
        return status
    except KeyboardInterrupt:
        print("torchfill: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:                # `torchfill info F | head`: the reader left; be quiet
        _silence_stdout()
        return 141
    except (ValueError, OSError, KeyError) as err:
        print(f"torchfill: error: {_one_line(err)}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as err:  # a bug, not bad input: still one line unless debugging
        if os.environ.get("TORCHFILL_DEBUG"):
            raise
        print(f"torchfill: internal error: {type(err).__name__}: {_one_line(err)} "
              "(set TORCHFILL_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

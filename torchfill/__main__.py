import os
import sys

try:
    from .cli import main
except KeyboardInterrupt:                  # Ctrl-C while starting up
    sys.exit(130)

status = main()
if status == 130:       # interrupted: the run has cleaned up; skip the interpreter's slow teardown
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(130)
sys.exit(status)

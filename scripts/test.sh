#!/usr/bin/env bash
# Set up .venv if needed (scripts/setup.sh), then run the test suite. Extra arguments go to pytest.
# Tests that need the real recordings in ../shared/data skip cleanly when it is absent.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
cd "$root"
exec "$root/.venv/bin/python" -m pytest -q -p no:cacheprovider "$@"

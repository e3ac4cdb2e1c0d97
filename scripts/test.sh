#!/usr/bin/env bash
# Set up .venv if needed (scripts/setup.sh), then run the test suite. Extra arguments go to pytest.
# Tests that need the real recordings in ../shared/data skip cleanly when it is absent.
# The run is quiet already (-q); a -q or -qq given here is not added to it, because pytest drops
# its pass/fail summary line below -q and that line is what this script is for.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
cd "$root"
args=()
for arg in "$@"; do
    [[ "$arg" =~ ^-q+$ || "$arg" == "--quiet" ]] || args+=("$arg")
done
exec "$root/.venv/bin/python" -m pytest -q -p no:cacheprovider "${args[@]+"${args[@]}"}"

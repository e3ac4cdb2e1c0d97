#!/usr/bin/env bash
# Create .venv at the repository root if missing and install torchfill into it (editable, with the
# dev, plot, experiments, interop and ray extras: the interop and Ray tests run rather than skip;
# ray adds about 35 s to a fresh install). torch is
# pinned to 2.13.0 first: on this project's machines that is a CPU build on local disk, and an
# unpinned torch would pull a multi-GB CUDA build instead.
# Re-running is cheap: the install is skipped while pyproject.toml and the extras are unchanged.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
python="${PYTHON:-python3}"
log="$(mktemp)"
trap 'rm -f "$log"' EXIT

if [ ! -x "$venv/bin/python" ]; then
    echo "setup: creating $venv" >&2
    "$python" -m venv "$venv"
fi
stamp="$venv/.torchfill-installed"
extras="dev,plot,experiments,interop,ray"
want="$( { cat "$root/pyproject.toml"; echo "$extras"; } | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ] || ! "$venv/bin/python" -c "import torchfill" 2>/dev/null; then
    echo "setup: installing torch==2.13.0 and torchfill into .venv (first run takes a minute)" >&2
    pip=("$venv/bin/python" -m pip install --disable-pip-version-check --no-input -q)
    if ! { "${pip[@]}" "torch==2.13.0" && "${pip[@]}" -e "$root[$extras]"; } >"$log" 2>&1; then
        grep -v "^WARNING: Location" "$log" >&2 || true
        echo "setup: pip install failed (see above)" >&2
        exit 1
    fi
    echo "$want" >"$stamp"
fi

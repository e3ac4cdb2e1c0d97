#!/usr/bin/env bash
# Set up .venv if needed, then show torchfill on a recording:
#   scripts/demo.sh            the embedded synthetic walking sample (no network, no data needed)
#   scripts/demo.sh FILE       your own .c3d/.trc/.npy/.npz/.csv: its gaps, the fill, and a
#                              score on simulated gaps in its complete markers
# It simulates gaps, fills them with the best method and with interpolation, prints the errors
# against the truth, and writes a filled copy.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
tf=("$root/.venv/bin/python" -m torchfill)
out="${TORCHFILL_DEMO_OUT:-$root/demo_output}"
mkdir -p "$out"

if [ $# -ge 1 ]; then
    file="$1"
    "${tf[@]}" info "$file"
    echo
    name="$(basename "$file")"
    "${tf[@]}" fill "$file" -o "$out/${name%.*}_filled.${name##*.}" || true
    echo
    echo "== scoring on simulated gaps in the complete markers of $name"
    "${tf[@]}" evaluate "$file" --markers 10 --gap-length 60 --max-gaps 3 --seed 0
else
    sample="$("$root/.venv/bin/python" -c 'import torchfill.data as d; print(d.sample_path())')"
    echo "== the embedded sample: $sample"
    echo "== 10 markers lose up to 3 gaps of 60 frames each; fill and score against the truth"
    "${tf[@]}" evaluate "$sample" --markers 10 --gap-length 60 --max-gaps 3 --seed 0
    echo
    echo "== writing a gappy copy and filling it: $out"
    "$root/.venv/bin/python" - "$sample" "$out/sample_gappy.c3d" <<'PY'
import sys, numpy as np, torchfill
from torchfill import gaps
seq = torchfill.read(sys.argv[1])
mask = gaps.multi_gap(seq.n_frames, seq.n_markers, n_markers=10, gap_length=60, max_gaps=3, seed=1)
gappy = seq.with_points(np.where(mask[..., None], np.nan, seq.points))
gappy.source = None  # a fresh file, not a write-back onto the sample
torchfill.write(gappy, sys.argv[2])
PY
    "${tf[@]}" fill "$out/sample_gappy.c3d" -o "$out/sample_filled.c3d"
fi

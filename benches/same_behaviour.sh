#!/usr/bin/env bash
# Same behaviour, two builds: runs each scene of a refactor's check (issue 58) with the old and
# the new binary back to back, on the CPU backend and on the GPU backend (lavapipe where there is
# no hardware adapter), and prints per run whether the final energies, Newton and Uzawa
# iterations, device submits and bytes moved are the same to the bit, with both wall times
# (the median of REPEAT runs each).
#
# Usage: benches/same_behaviour.sh OLD_BIN NEW_BIN [REPEAT]     (REPEAT defaults to 3)
set -euo pipefail
old=$1 new=$2 repeat=${3:-3}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cd "$(dirname "$0")/.."
# scene | --set overrides (kept short enough for a 2-core machine)
cases=(
  "sliding_block|"
  "bar_impact|"
  "hertz_cylinder|"
  "stack_3d|"
  "love_laursen|"
  "grains_many|packing.count=200 output.scene_every=0"
  "grains_many|packing.count=10000 time.end=0.05 output.scene_every=0"
  "grains_3d|output.scene_every=0"
  "free_vibration_2d|material.rubber.K=1.0e7 time.end=0.5"
)
fields='energy.total energy.kinetic newton_iterations uzawa_iterations device_submits bytes_moved status'
printf '%-40s %-4s %-5s %10s %10s  %s\n' scene backend same old_s new_s differences
for case in "${cases[@]}"; do
  scene=${case%%|*} sets=${case#*|}
  args=(run "scenes/$scene.toml" --quiet --json)
  for s in $sets; do args+=(--set "$s"); done
  for backend in cpu gpu; do
    declare -A wall=()
    for k in $(seq "$repeat"); do
      for which in old new; do
        bin=${!which}
        "$bin" "${args[@]}" --backend "$backend" --out "$out/$which.mcap" > "$out/$which.$k.json" 2>/dev/null || true
        wall[$which]+="$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['wall_s'])" "$out/$which.$k.json") "
      done
    done
    diff=$(python3 - "$out/old.1.json" "$out/new.1.json" $fields <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
def get(d, key):
    for k in key.split('.'):
        d = d[k]
    return d
print(' '.join(f"{k}: {get(a, k)!r} -> {get(b, k)!r}" for k in sys.argv[3:] if get(a, k) != get(b, k)))
PY
)
    median() { tr ' ' '\n' | grep . | sort -g | awk '{v[NR]=$1} END {print v[int((NR+1)/2)]}'; }
    printf '%-40s %-4s %-5s %10.3f %10.3f  %s\n' "$scene ${sets// /,}" "$backend" "$([ -z "$diff" ] && echo yes || echo NO)" "$(echo "${wall[old]}" | median)" "$(echo "${wall[new]}" | median)" "$diff"
    unset wall
  done
done

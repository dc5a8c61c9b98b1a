#!/usr/bin/env bash
# Packings at scale (doc/benchmarks.md, "Packings at scale"): the cost per step, the set-up,
# the peak memory and the log's bytes per grain of grains_many (2D) and grains_3d (3D) from
# small to large N, one run each, grains falling under gravity for the first steps (few touch).
# Prints one JSON object per run.
#
#   benches/packings.sh [BINARY] [2d|3d]...
set -euo pipefail
bin=${1:-target/release/bifirst}
shift || true
sections=${*:-2d 3d}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

run() { # label scene N gravity steps-end [extra sets...]
  local label=$1 scene=$2 n=$3 gravity=$4 end=$5
  shift 5
  for every in 1 1000000; do
    /usr/bin/time -f "%M" -o "$tmp/mem" "$bin" run "$scene" --backend cpu --quiet --json --set output.scene_every=0 \
      --set packing.count="$n" --set "gravity=$gravity" --set time.end="$end" --set output.every=$every "$@" --out "$tmp/run_$every.mcap" >"$tmp/run_$every.json"
    cp "$tmp/mem" "$tmp/mem_$every"
  done
  python3 - "$label" "$n" "$tmp" <<'PY'
import json, os, sys
label, n, tmp = sys.argv[1], int(sys.argv[2]), sys.argv[3]
d = json.load(open(f"{tmp}/run_1.json"))
steps, phases = d["steps"], d["wall_by_phase"]
every_step, ends_only = os.path.getsize(f"{tmp}/run_1.mcap"), os.path.getsize(f"{tmp}/run_1000000.mcap")
# Logging every step against only the start and the last: the per-step channels' share.
per_grain_step = (every_step - ends_only) / ((steps - 1) * n)
print(json.dumps({"label": label, "N": n, "steps": steps, "wall_s": round(d["wall_s"], 3), "steps_s": round(phases["total"], 3),
                  "per_step_s": round(phases["total"] / steps, 4), "setup_and_log_s": round(d["wall_s"] - phases["total"], 3),
                  "contact_s": round(phases["contact"], 3), "elements_s": round(phases["elements"], 3),
                  "peak_mb": int(open(f"{tmp}/mem_1").read().split()[-1]) // 1024, "log_bytes": every_step,
                  "log_bytes_per_grain_step": round(per_grain_step, 1)}))
PY
}

for section in $sections; do
  case $section in
    2d) for n in 1000 3000 10000 30000 100000; do run "2d_$n" scenes/grains_many.toml "$n" "[0.0,-9.81]" 0.05; done ;;
    3d) for n in 100 300 1000 3000 10000; do run "3d_$n" scenes/grains_3d.toml "$n" "[0.0,-9.81,0.0]" 0.05; done ;;
  esac
done

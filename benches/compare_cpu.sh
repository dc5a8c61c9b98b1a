#!/usr/bin/env bash
# Whole-run comparison of two bifirst binaries on this machine, back to back (doc/benchmarks.md,
# "CPU speed"). Prints one JSON object per run: label, threads, the `--json` summary's wall time,
# solver totals, phase times, final energy and peak memory.
#
#   benches/compare_cpu.sh BEFORE_BINARY AFTER_BINARY [grains|packing|slope|block|orderings|contact|kernels|stress]...
#
# With no section, runs them all (about 8 minutes on 2 cores).
set -euo pipefail
before=$1 after=$2
shift 2
sections=${*:-grains slope block orderings contact kernels}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

run() { # label binary threads(- for default) run-arguments...
  local label=$1 bin=$2 threads=$3
  shift 3
  local t=()
  [ "$threads" != "-" ] && t=(--threads "$threads")
  /usr/bin/time -f "%M" -o "$tmp/mem" "$bin" "${t[@]}" run "$@" --backend cpu --set output.scene_every=0 --out "$tmp/run.mcap" --quiet --json >"$tmp/run.json" || true
  python3 - "$label" "$threads" "$tmp" <<'PY'
import json, sys
label, threads, tmp = sys.argv[1:]
d = json.load(open(f"{tmp}/run.json"))
mem = int(open(f"{tmp}/mem").read().split()[-1])
print(json.dumps({"label": label, "threads": threads, "wall": d["wall_s"], "steps": d["steps"], "newton": d["newton_iterations"],
                  "uzawa": d["uzawa_iterations"], "status": d["status"], "max_overlap_ratio": d["max_overlap_ratio"], "bodies_iterated": d.get("bodies_iterated"), "factorizations": d.get("factorizations"), "cutbacks": d["cutbacks"],
                  "phases": d["wall_by_phase"], "energy": d["energy"]["total"], "balance": d["energy"]["energy_balance_error"],
                  "max_penetration": d["max_penetration"], "peak_memory_kb": mem}))
PY
}

for section in $sections; do
  case $section in
    stress) # issue 28's table: grains_many N = 200 at its defaults, at 4x dt and 10x wall speed; bar_impact at 100x speed and 50x dt
      g=(scenes/grains_many.toml --set packing.count=200)
      for _ in 1 2 3; do run g200_before "$before" - "${g[@]}"; run g200_after "$after" - "${g[@]}"; done
      run g200_dt4_before "$before" - "${g[@]}" --set time.dt=0.02; run g200_dt4_after "$after" - "${g[@]}" --set time.dt=0.02
      run g200_wall10_after "$after" - "${g[@]}" --set packing.wall_velocity=20.0 --set time.end=0.3
      for bin in before after; do b=$before; [ $bin = after ] && b=$after
        run bar_speed100_$bin "$b" - scenes/bar_impact.toml --set 'body.bar.initial_velocity=[-50.0, 0.0]'
        run bar_dt50_$bin "$b" - scenes/bar_impact.toml --set time.dt=2.5e-3
      done
      ;;
    grains)
      g=(scenes/grains_many.toml --set packing.count=400 --set time.end=0.1)
      for _ in 1 2 3 4 5; do run g400_before "$before" - "${g[@]}"; run g400_after "$after" - "${g[@]}"; run g400_after "$after" 1 "${g[@]}"; done
      for _ in 1 2; do
        run g1000_before "$before" - scenes/grains_many.toml --set packing.count=1000
        run g1000_after "$after" - scenes/grains_many.toml --set packing.count=1000
        run g1000_after "$after" 1 scenes/grains_many.toml --set packing.count=1000
      done ;;
    packing)
      # 10 000 grains, the first ten steps: the wall reaches the first column, most grains at rest.
      p=(scenes/grains_many.toml --set packing.count=10000 --set time.end=0.05)
      for _ in 1 2 3 4 5; do run p10000_before "$before" - "${p[@]}"; run p10000_after "$after" - "${p[@]}"; done ;;
    slope)
      for n in 100 200 400 800 1600; do run "slope_$n" "$after" - scenes/grains_many.toml --set packing.count=$n; done ;;
    block)
      for d in 30,15,15 40,20,20; do
        b=(scenes/free_flight_3d.toml --set "body.block.mesh.divisions=[$d]" --set time.end=0.006)
        run "block_${d}_before" "$before" - "${b[@]}"; run "block_${d}_after" "$after" - "${b[@]}"; run "block_${d}_after" "$after" 1 "${b[@]}"
      done ;;
    orderings)
      for d in 30,15,15 40,20,20; do for o in amd nested_dissection; do for t in 1 2; do
        run "ordering_${d}_$o" "$after" $t scenes/free_flight_3d.toml --set "body.block.mesh.divisions=[$d]" --set time.end=0.004 \
          --set "solver.ordering=\"$o\"" --set solver.reuse_factorization=false
      done; done; done ;;
    contact)
      for s in sliding_block stack_3d hertz_cylinder grains_box bar_impact; do
        for _ in 1 2 3; do run "${s}_before" "$before" - "scenes/$s.toml"; run "${s}_after" "$after" - "scenes/$s.toml"; done
      done ;;
    kernels)
      "$before" bench --backend cpu --kernel element_force_tangent --json | sed 's/^{/{"binary":"before",/'
      "$after" --threads 1 bench --backend cpu --kernel element_force_tangent --json | sed 's/^{/{"binary":"after",/' ;;
    *) echo "unknown section $section" >&2; exit 2 ;;
  esac
done

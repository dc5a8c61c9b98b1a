#!/usr/bin/env bash
# The GPU measurements in one command, for a machine with a GPU, CPU and GPU backends of one
# build back to back, repeated, medians:
#   runs    issue 14's table (doc/benchmarks.md, "GPU pipeline"): four scenes; the grains again
#           with the contact sweeps on the device, and the grains and stack_3d with every
#           Newton round on the device (`--rounds gpu`), then with the sweeps too;
#   scale   issue 31's table (doc/benchmarks.md, "The GPU at scale"): grains_many N = 1 000,
#           10 000 and 100 000 (2D) and grains_3d N = 1 000 and 10 000, the grains falling
#           under gravity in their box (every grain moves, so every one is evaluated: the
#           packings-at-scale convention of benches/packings.sh), stack_3d, and the 54 243-dof
#           Hex8 block of free_flight_3d;
#   bench   the kernels' throughput and roofline (`bench --elements 1000000`);
#   kernels the device's time by kernel (`--kernel-times`) of the largest falling packings of
#           "scale" (2D and 3D), once each, plain `gpu` and the whole step on the device: where
#           a device pass spends its time;
#   sweeps  the contact sweeps' device/CPU ratio by size (uzawa_sweep: one large problem colour by
#           colour; uzawa_solve: a packing's small problems, each solved whole), from which `--uzawa auto`'s
#           thresholds (backend::AUTO_UZAWA_*) are read.
#
#   benches/gpu_table.sh [BINARY] [REPETITIONS] [OUTDIR]
#
# Prints the date, the machine and Markdown tables; OUTDIR (default: a temporary folder) keeps
# every run's `--json` summary and bench's JSON rows. QUICK=1 runs small sizes, to try the
# script on lavapipe; BENCH_ELEMENTS (default 1000000) sizes the kernel benchmark, whose every
# kernel is stopped after BENCH_LIMIT seconds (default 80), and every run after RUN_LIMIT seconds
# (default 600; a stopped run is reported and left out of the table). SECTIONS (default "runs bench
# sweeps") picks the parts, so that a device call's 10 minutes can hold them: "runs bench
# sweeps" took about 8 minutes next to an H100, most of it the kernel benchmark; "scale" takes
# about 4 minutes of CPU runs on 2 cores per repetition, less on 16 (call it on its own).
set -uo pipefail
bin=$(realpath "${1:-target/release/bifirst}")
reps=${2:-3}
out=${3:-$(mktemp -d)}
mkdir -p "$out"
cd "$(dirname "$0")/.."

if [ "${QUICK:-0}" = 1 ]; then
  grains=(--set packing.count=100 --set time.end=0.05)
  stack=(--set time.end=0.1)
  love=(--set contact.friction=0.5 --set time.end=0.05)
  flight=(--set 'body.block.mesh.divisions=[8,4,4]' --set time.end=0.004)
  elements=${BENCH_ELEMENTS:-4096} bench_time=0.2 sweep_sizes="64 256 1024"
  scale_2d=("100 0.05" "300 0.02") scale_3d=("27 0.02") stack_end=0.1 block=(8 4 4) block_end=0.004
else
  grains=(--set packing.count=1000 --set time.end=0.2)
  stack=()
  love=(--set contact.friction=0.5)
  flight=(--set 'body.block.mesh.divisions=[40,20,20]' --set time.end=0.02)
  elements=${BENCH_ELEMENTS:-1000000} bench_time=0 sweep_sizes="64 256 1024 4096 16384 65536"
  # "N end" pairs: 40, 20 and 10 steps of dt = 0.005 (2D); 20 and 10 (3D).
  scale_2d=("1000 0.2" "10000 0.1" "100000 0.05") scale_3d=("1000 0.1" "10000 0.05") stack_end=5.0 block=(40 20 20) block_end=0.02
fi
limit=${BENCH_LIMIT:-80}
run_limit=${RUN_LIMIT:-600}
sections=" ${SECTIONS:-runs bench sweeps} "

run() { # label backend scene [arguments...]: one run, its summary appended to runs.jsonl
  local label=$1 backend=$2 scene=$3
  shift 3
  if timeout "$run_limit" "$bin" run "scenes/$scene.toml" "$@" --backend "$backend" --quiet --json --out "$out/run.mcap" >"$out/run.json" 2>"$out/run.err"; then
    python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); d["label"]=sys.argv[2]; d["mode"]=sys.argv[3]; print(json.dumps(d))' \
      "$out/run.json" "$label" "$backend$UZAWA_LABEL" >>"$out/runs.jsonl"
  else
    echo "run failed: $label $backend: $(tail -n 3 "$out/run.err")" >&2
  fi
}

echo "Date: $(date -u '+%Y-%m-%d %H:%M UTC'); machine: $(nproc) cores, $(uname -m); binary: $("$bin" info 2>/dev/null | head -n 1)"
echo
"$bin" info >&2 || true
: >"$out/runs.jsonl"
runs_reps=$reps
[[ $sections == *" runs "* ]] || runs_reps=0
for r in $(seq "$runs_reps"); do
  echo "repetition $r of $reps" >&2
  for backend in cpu gpu; do
    UZAWA_LABEL=""
    run "grains_many" "$backend" grains_many "${grains[@]}" --set output.scene_every=10
    run "stack_3d" "$backend" stack_3d "${stack[@]}"
    run "love_laursen, mu = 0.5" "$backend" love_laursen "${love[@]}"
    run "free_flight_3d" "$backend" free_flight_3d "${flight[@]}"
  done
  UZAWA_LABEL=" --uzawa gpu"
  run "grains_many" gpu grains_many "${grains[@]}" --set output.scene_every=10 --uzawa gpu
  # Every Newton round on the device: what backend::round_on_device saves (its threshold).
  UZAWA_LABEL=" --rounds gpu"
  run "grains_many" gpu grains_many "${grains[@]}" --set output.scene_every=10 --rounds gpu
  run "stack_3d" gpu stack_3d "${stack[@]}" --rounds gpu
  # The whole step on the device, groups in contact included: a submit per refactorisation
  # round, not per increment.
  UZAWA_LABEL=" --rounds gpu --uzawa gpu"
  run "grains_many" gpu grains_many "${grains[@]}" --set output.scene_every=10 --rounds gpu --uzawa gpu
  run "stack_3d" gpu stack_3d "${stack[@]}" --rounds gpu --uzawa gpu
done

if [[ $sections == *" kernels "* ]]; then
  echo "kernels: the device's time by kernel" >&2
  read -r n2 end2 <<<"${scale_2d[-1]}"
  read -r n3 end3 <<<"${scale_3d[-1]}"
  for flags in "" "--rounds gpu --uzawa gpu"; do
    UZAWA_LABEL=" --kernel-times${flags:+ $flags}"
    # shellcheck disable=SC2086 # the flags are words
    run "grains_many, N = $n2, falling, t <= $end2" gpu grains_many --set packing.count="$n2" --set time.end="$end2" \
      --set 'gravity=[0.0,-9.81]' --set output.scene_every=0 --kernel-times $flags
    # shellcheck disable=SC2086
    run "grains_3d, N = $n3, falling, t <= $end3" gpu grains_3d --set packing.count="$n3" --set time.end="$end3" \
      --set 'gravity=[0.0,-9.81,0.0]' --set output.scene_every=0 --kernel-times $flags
  done
  UZAWA_LABEL=""
fi

scale_reps=$reps
[[ $sections == *" scale "* ]] || scale_reps=0
for r in $(seq "$scale_reps"); do
  echo "scale: repetition $r of $scale_reps" >&2
  for backend in cpu gpu; do
    UZAWA_LABEL=""
    for case in "${scale_2d[@]}"; do
      read -r n end <<<"$case"
      run "grains_many, N = $n, falling, t <= $end" "$backend" grains_many --set packing.count="$n" --set time.end="$end" \
        --set 'gravity=[0.0,-9.81]' --set output.scene_every=0
    done
    for case in "${scale_3d[@]}"; do
      read -r n end <<<"$case"
      run "grains_3d, N = $n, falling, t <= $end" "$backend" grains_3d --set packing.count="$n" --set time.end="$end" \
        --set 'gravity=[0.0,-9.81,0.0]' --set output.scene_every=0
    done
    run "stack_3d, t <= $stack_end" "$backend" stack_3d --set time.end="$stack_end"
    if [[ $backend == gpu ]]; then
      # The whole step on the device: the falling grains take their Newton iterations there,
      # their contact sweeps with them (doc/ARCHITECTURE.md, "Newton iterations on the device",
      # "Groups in contact on the device"), whatever `auto`'s thresholds.
      UZAWA_LABEL=" --rounds gpu --uzawa gpu"
      read -r n end <<<"${scale_2d[-1]}"
      run "grains_many, N = $n, falling, t <= $end" gpu grains_many --set packing.count="$n" --set time.end="$end" \
        --set 'gravity=[0.0,-9.81]' --set output.scene_every=0 --rounds gpu --uzawa gpu
      read -r n end <<<"${scale_3d[-1]}"
      run "grains_3d, N = $n, falling, t <= $end" gpu grains_3d --set packing.count="$n" --set time.end="$end" \
        --set 'gravity=[0.0,-9.81,0.0]' --set output.scene_every=0 --rounds gpu --uzawa gpu
      UZAWA_LABEL=""
    fi
    run "free_flight_3d, ${block[0]}x${block[1]}x${block[2]} Hex8, t <= $block_end" "$backend" free_flight_3d \
      --set "body.block.mesh.divisions=[${block[0]},${block[1]},${block[2]}]" --set time.end="$block_end"
  done
done

: >"$out/bench.jsonl"
kernels="peak element_force_tangent assemble evaluate element_energy newton_iteration"
[[ $sections == *" bench "* ]] || kernels=""
for kernel in $kernels; do
  timeout "$limit" "$bin" bench --elements "$elements" --time "$bench_time" --kernel "$kernel" --backend gpu --json >>"$out/bench.jsonl" \
    || echo "bench --kernel $kernel stopped (exit $?) after ${limit} s; the rows it finished are kept" >&2
done
: >"$out/sweeps.jsonl"
[[ $sections == *" sweeps "* ]] || sweep_sizes=""
for e in $sweep_sizes; do
  for kernel in uzawa_sweep uzawa_solve; do
    timeout "$limit" "$bin" bench --elements "$e" --time 1 --kernel "$kernel" --backend gpu --json >>"$out/sweeps.jsonl" \
      || echo "bench --kernel $kernel --elements $e stopped (exit $?)" >&2
  done
done

python3 - "$out" <<'PY'
import json, statistics, sys
from collections import defaultdict
out = sys.argv[1]
runs = [json.loads(l) for l in open(f"{out}/runs.jsonl")]
by = defaultdict(list)
for r in runs:
    by[(r["label"], r["mode"])].append(r)
med = lambda rs, f: statistics.median(f(r) for r in rs)
adapter = next((r["adapter"] for r in runs if r.get("adapter")), "none")
print(f"Adapter: {adapter}\n")
print("| scene | CPU run | GPU run | GPU / CPU | CPU steps | GPU steps | GPU submits | GPU Newton increments on the device | energies (CPU / GPU) |")
print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
labels = list(dict.fromkeys(r["label"] for r in runs))
for label in labels:
    cpu = by.get((label, "cpu"))
    for mode in ("gpu", "gpu --uzawa gpu", "gpu --rounds gpu", "gpu --rounds gpu --uzawa gpu"):
        gpu = by.get((label, mode))
        if not cpu or not gpu:
            continue
        wc, wg = med(cpu, lambda r: r["wall_s"]), med(gpu, lambda r: r["wall_s"])
        ratio = f"{wc / wg:.2f}x faster" if wg < wc else f"{wg / wc:.2f}x slower"
        name = label + {"gpu --uzawa gpu": " (contact on the device)", "gpu --rounds gpu": " (every round on the device)",
                         "gpu --rounds gpu --uzawa gpu": " (the whole step on the device)"}.get(mode, "")
        print(f"| {name} | {wc:.2f} s | {wg:.2f} s | {ratio} | {med(cpu, lambda r: r['wall_by_phase']['total']):.2f} s "
              f"| {med(gpu, lambda r: r['wall_by_phase']['total']):.2f} s | {med(gpu, lambda r: r['device_submits']):.0f} "
              f"| {med(gpu, lambda r: r.get('device_iterations', 0)):.0f} "
              f"| {cpu[0]['energy']['total']:.10g} / {gpu[0]['energy']['total']:.10g} |")
print()
for r in runs:
    if not r.get("kernel_times"):
        continue
    kernels = r["kernel_times"]["kernels"]
    total = sum(k["seconds"] for k in kernels)
    print(f"{r['label']} ({r['mode']}): {r['wall_s']:.2f} s wall, {r['wall_by_phase']['elements']:.2f} s in device passes, "
          f"{total:.3f} s of kernels, {r['device_submits']} submits\n")
    print("| kernel | device time | share | dispatches | per dispatch |\n| --- | --- | --- | --- | --- |")
    for k in kernels:
        print(f"| {k['kernel']} | {k['seconds']:.4f} s | {100 * k['seconds'] / max(total, 1e-300):.1f} % | {k['dispatches']} "
              f"| {1e3 * k['seconds'] / max(k['dispatches'], 1):.3f} ms |")
    print()

def rows(path):
    for line in open(path):
        line = line.strip()
        if line.startswith("{"):
            yield json.loads(line)

def throughput(r):
    return f"{r['items_per_second'] / 1e6:.3g} M/s"

bench = list(rows(f"{out}/bench.jsonl"))
if bench:
    print("| kernel | element | material | items | CPU f64 | GPU f64 | GPU f32 | GPU f64 %bw / %flop | GPU f32 %bw / %flop |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    cases = defaultdict(dict)
    for r in bench:
        cases[(r["kernel"], r["element"], r["material"])][r["backend"]] = r
    pct = lambda r: "-" if r is None or r.get("peak_bandwidth_fraction") is None else f"{100 * r['peak_bandwidth_fraction']:.1f} / {100 * r['peak_flops_fraction']:.1f}"
    cell = lambda r: "-" if r is None else throughput(r)
    for (kernel, element, material), c in cases.items():
        if kernel.startswith("peak"):
            continue
        items = max(r["items"] for r in c.values())
        g64, g32 = c.get("gpu f64"), c.get("gpu f32")
        print(f"| {kernel} | {element} | {material} | {items} | {cell(c.get('cpu f64'))} | {cell(g64)} | {cell(g32)} | {pct(g64)} | {pct(g32)} |")
    print("\n| peak kernel | backend | GB/s | GFLOP/s |\n| --- | --- | --- | --- |")
    for (kernel, _, _), c in cases.items():
        if kernel.startswith("peak"):
            for backend, r in c.items():
                print(f"| {kernel} | {backend} | {r['gbytes_per_second']:.4g} | {r['gflops_per_second']:.4g} |")
    print()
sweeps = list(rows(f"{out}/sweeps.jsonl"))
if sweeps:
    print("| kernel | points | CPU twin per call | device per call | device / CPU | bytes per call |")
    print("| --- | --- | --- | --- | --- | --- |")
    by_items = defaultdict(dict)
    for r in sweeps:
        by_items[(r["kernel"], r["items"])][r["backend"].split()[0]] = r
    for (kernel, items), c in sorted(by_items.items()):
        if "cpu" in c and "gpu" in c:
            tc, tg = c["cpu"]["seconds_per_call"], c["gpu"]["seconds_per_call"]
            print(f"| {kernel} | {items} | {1e3 * tc:.3g} ms | {1e3 * tg:.3g} ms | {tg / tc:.2f} | {c['gpu']['bytes_per_call'] / 1e6:.2f} MB |")
PY
echo "raw results in $out" >&2

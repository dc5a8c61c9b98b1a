#!/usr/bin/env python3
"""Bytes a grain moves between host and device per step, submits per step and peak memory: the
CPU backend and two builds' GPU backends with every Newton round on the device, back to back.

    python3 benches/bytes_per_step.py SCENE N "SET SET ..." OLD_BINARY NEW_BINARY ["GPU FLAGS"]

SCENE is a file stem of scenes/, N the grains (to divide by), the sets as `--set` takes them;
the GPU runs take `--backend gpu` and the flags given (none by default: the issue's command;
"--rounds gpu --uzawa gpu" for the whole step on the device).
Reads `/solver.bytes_moved` and `device_submits` per step from each run's log (the `mcap`
package), the peak resident memory from `/usr/bin/time`.
"""
import json, os, statistics, subprocess, sys, tempfile
from mcap.reader import make_reader

def run(binary, scene, sets, backend, out):
    cmd = ['/usr/bin/time', '-f', '%M', binary, 'run', scene, '--quiet', '--json', '--out', out] + sum([['--set', s] for s in sets], []) + backend
    p = subprocess.run(cmd, capture_output=True, text=True, check=False)
    summary = json.loads(p.stdout)
    peak_mb = int(p.stderr.strip().splitlines()[-1]) // 1024
    steps = []
    with open(out, 'rb') as f:
        for _, _, message in make_reader(f).iter_messages(topics=['/solver']):
            j = json.loads(message.data)
            steps.append((j['bytes_moved'], j['device_submits']))
    return summary, peak_mb, steps

def main():
    scene, n, sets, old, new = sys.argv[1], int(sys.argv[2]), sys.argv[3].split(), sys.argv[4], sys.argv[5]
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'scenes', scene + '.toml')
    gpu = ['--backend', 'gpu'] + (sys.argv[6].split() if len(sys.argv) > 6 else [])
    with tempfile.TemporaryDirectory() as out:
        for name, binary, backend in [('cpu', old, ['--backend', 'cpu']), ('old gpu', old, gpu), ('new gpu', new, gpu)]:
            summary, peak, steps = run(binary, path, sets, backend, os.path.join(out, 'run.mcap'))
            later = steps[1:10]
            e = summary['energy']
            print(f"{name:8s} step 1 {steps[0][0] / n:8.0f} B/grain, steps 2-10 median {statistics.median(b for b, _ in later) / n:6.0f} B/grain, "
                  f"submits/step median {statistics.median(s for _, s in later)} max {max(s for _, s in later)}, peak {peak} MB, wall {summary['wall_s']:.1f} s, "
                  f"Newton {summary['newton_iterations']}, energy {e['total']!r}, kinetic {e['kinetic']!r}")
            print(f"{'':8s} steps 2-10 B/grain {' '.join(str(round(b / n)) for b, _ in later)}; steps over 3 submits {sum(s > 3 for _, s in steps[1:])} of {len(steps) - 1}")

if __name__ == '__main__':
    main()

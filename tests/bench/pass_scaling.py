#!/usr/bin/env python3
"""How one path-traced frame spreads over worker processes: whole tiles against passes.

Starts `tessera-server` with W local workers of one thread each (for each W given), submits one
512x512 path-traced frame cut into 16 tiles of 128 px (../shared/bench/jaroslav_path.xml:
cornellbox_jaroslav_path_diffuse's `diffuse_next_importance` camera), once as whole tiles (one
pass a tile: what the farm did before passes) and once in passes of --pass-samples, and prints
for each run:
  - the frame's wall time, from the submission to the job's `done`;
  - every worker's CPU seconds over the job (from /proc), their sum, and the largest one: the
    frame's wall time on a machine with a core for each worker (the last worker to finish
    sets it), and the share of that time the workers were busy (sum / (W x largest)).
On a machine with fewer cores than workers the wall time cannot scale; the largest worker's
CPU time still shows how evenly the frame's work was spread.

Example (the figures in docs/PERFORMANCE.md):
  cargo build --release && python3 tests/bench/pass_scaling.py --workers 2 4 8 --samples 128
"""

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
TICKS = os.sysconf("SC_CLK_TCK")


def cpu(pid):
    with open(f"/proc/{pid}/stat") as f:
        rest = f.read().rsplit(")", 1)[1].split()
    return (int(rest[11]) + int(rest[12])) / TICKS


def children(pid):
    out = []
    for p in os.listdir("/proc"):
        if p.isdigit():
            try:
                with open(f"/proc/{p}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        out.append(int(p))
            except OSError:
                pass
    return out


def get(url):
    with urllib.request.urlopen(url) as r:
        return json.loads(r.read())


def run(args, scene, workers, pass_samples):
    data = tempfile.mkdtemp(prefix="tessera-scaling-")
    server = subprocess.Popen(
        [os.path.join(args.bin_dir, "tessera-server"), "--bind", "127.0.0.1:0", "--local-workers", str(workers),
         "--local-worker-threads", "1", "--data-dir", data],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        url = server.stdout.readline().strip().removeprefix("listening on ")
        deadline = time.time() + 30
        while len(get(url + "/api/v1/workers").get("workers", [])) < workers:
            if time.time() > deadline:
                raise SystemExit("the local workers did not all register")
            time.sleep(0.1)
        pids = children(server.pid)
        before = {p: cpu(p) for p in pids}
        start = time.time()
        form = ["-F", f"scene=@{scene}", "-F", "tile_size=128", "-F", f"pass_samples={pass_samples}"]
        job = json.loads(subprocess.run(["curl", "-sf", *form, url + "/api/v1/jobs"], capture_output=True,
                                        text=True, check=True).stdout)
        while True:
            state = get(f"{url}/api/v1/jobs/{job['id']}")["state"]
            if state == "done":
                break
            if state in ("failed", "canceled"):
                raise SystemExit(f"job {state}")
            time.sleep(0.2)
        wall = time.time() - start
        used = sorted((cpu(p) - before[p] for p in pids), reverse=True)
        return wall, used
    finally:
        server.terminate()
        server.wait()
        shutil.rmtree(data, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, nargs="+", default=[2, 4, 8])
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument("--pass-samples", type=int, default=16)
    ap.add_argument("--bin-dir", default=os.path.join(ROOT, "target", "release"))
    args = ap.parse_args()
    bench = os.path.join(ROOT, "..", "shared", "bench", "jaroslav_path.xml")
    folder = tempfile.mkdtemp(prefix="tessera-scaling-scene-")
    scene = os.path.join(folder, "jaroslav_path.xml")
    with open(bench) as f, open(scene, "w") as out:
        out.write(f.read().replace("SPP", str(args.samples)))
    print(f"512x512, {args.samples} spp, 16 tiles of 128 px; passes of {args.pass_samples} samples; "
          f"{os.cpu_count()} CPUs here")
    print("| workers | split | units | wall s | worker CPU s (sum) | largest worker CPU s | busy share |")
    print("|---|---|---|---|---|---|---|")
    for w in args.workers:
        for name, ps in (("whole tiles", args.samples), ("passes", args.pass_samples)):
            wall, used = run(args, scene, w, ps)
            units = 16 * -(-args.samples // ps)
            total = sum(used)
            print(f"| {w} | {name} | {units} | {wall:.1f} | {total:.1f} | {used[0]:.1f} | "
                  f"{total / (w * used[0]):.2f} |", flush=True)
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()

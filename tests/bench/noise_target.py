#!/usr/bin/env python3
"""What a noise target saves against a fixed sample count, and what it costs in quality.

Renders one camera of a scene with `tessera-worker render`, first with every sample (the scene's
NumSamples, or --samples), then once per noise target given (`--noise-target T`, the samples as
the cap), and compares each frame with the course's official image:
  - PSNR of the tone-mapped PNGs after a 4x4 box filter (forgives per-pixel noise);
  - mean FLIP (LDR, NVIDIA's flip-evaluator package) of the tone-mapped PNGs;
beside the CPU seconds of each render process (user + system, from the kernel) and the samples
per pixel a noise target left on average. The fixed render is the anchor of the same run.
With --side-by-side the renders run at the same time, one process each, so that whatever else
the machine does weighs on all of them alike (each one's CPU seconds are its own, from wait4);
give them --threads 1 on a machine with fewer cores than renders.
Needs numpy, OpenEXR, Pillow and flip-evaluator, and a release build
(`cargo build --release -p tessera-worker`).

Example (the figures in docs/PERFORMANCE.md):
  python3 tests/bench/noise_target.py --scene ../shared/scenes/xml/cornellbox_jaroslav_path_glass.xml \
      --camera 3 --reference ../shared/scenes/reference/cornellbox_jaroslav_path_glass__glass_next_importance \
      --targets 0.3 0.2 0.1
"""

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from denoise_quality import box_psnr, mean_flip, read_png  # noqa: E402


def cpu_seconds():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def command(args, out, extra):
    cmd = [args.bin, "render", args.scene, "--camera", args.camera, "--quiet", "--out", out,
           "--tile-size", str(args.tile_size)] + extra
    if args.samples:
        cmd += ["--samples", str(args.samples)]
    if args.threads:
        cmd += ["--threads", args.threads]
    return cmd


def render(args, out, extra):
    cmd = command(args, out, extra)
    before = cpu_seconds()
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{run.stderr}")
    return cpu_seconds() - before, run.stdout


def render_side_by_side(args, jobs):
    """Every (out, extra) of `jobs` at once; their (CPU seconds, stdout) in the same order."""
    procs = {}
    for i, (out, extra) in enumerate(jobs):
        cmd = command(args, out, extra)
        log = open(os.path.join(os.path.dirname(out), f"render{i}.log"), "w+")
        procs[subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT).pid] = (i, cmd, log)
    results = [None] * len(jobs)
    while procs:
        pid, status, usage = os.wait4(-1, 0)
        if pid not in procs:
            continue
        i, cmd, log = procs.pop(pid)
        log.seek(0)
        text = log.read()
        if os.waitstatus_to_exitcode(status) != 0:
            sys.exit(f"{' '.join(cmd)} failed:\n{text}")
        results[i] = (usage.ru_utime + usage.ru_stime, text)
    return results


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--camera", required=True)
    ap.add_argument("--reference", required=True, help="the official image's path without .png")
    ap.add_argument("--targets", type=float, nargs="+", required=True)
    ap.add_argument("--samples", type=int, default=None, help="instead of the camera's NumSamples")
    ap.add_argument("--tile-size", type=int, default=32)
    ap.add_argument("--bin", default=os.path.join(os.path.dirname(__file__), "../../target/release/tessera-worker"))
    ap.add_argument("--threads", default=None)
    ap.add_argument("--keep", default=None, help="keep the renders in this folder")
    ap.add_argument("--side-by-side", action="store_true", help="run all renders at the same time")
    args = ap.parse_args()
    ref_png = args.reference + ".png"
    ref = read_png(ref_png)
    root = args.keep or tempfile.mkdtemp(prefix="tessera-noise-target-")
    os.makedirs(root, exist_ok=True)
    print("| render | samples per pixel (mean) | CPU s | CPU / fixed | box PSNR (dB) | mean FLIP |")
    print("|---|---|---|---|---|---|")
    targets = [None] + args.targets
    jobs = [(os.path.join(root, "fixed" if t is None else f"target{t}"),
             [] if t is None else ["--noise-target", str(t)]) for t in targets]
    done = render_side_by_side(args, jobs) if args.side_by_side else None
    fixed_cpu = None
    for k, (target, (out, extra)) in enumerate(zip(targets, jobs)):
        cpu, stdout = done[k] if done else render(args, out, extra)
        png = [f for f in os.listdir(out) if f.endswith(".png") and not f.endswith("_samples.png")][0]
        spp = re.search(r"([0-9.]+) samples per pixel on average", stdout)
        spp = spp.group(1) if spp else re.search(r", (\d+) spp,", stdout).group(1)
        if fixed_cpu is None:
            fixed_cpu = cpu
        name = "fixed" if target is None else f"noise target {target}"
        test = os.path.join(out, png)
        print(f"| {name} | {spp} | {cpu:.1f} | {cpu / fixed_cpu:.3f} | {box_psnr(read_png(test), ref):.2f} | {mean_flip(ref_png, test):.4f} |", flush=True)
    print(f"renders in {root}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Whether a noise target pays: its relative MSE against uniform sampling at equal mean samples,
and the mean samples it needs to reach a uniform render's error.

Renders one camera of a scene with `tessera-worker render` (linear EXR), all at --scale:
  - a reference of --reference-samples with another seed (--seed), so that its samples are
    independent of the renders measured against it (its own noise adds the same small amount to
    every render's error: the ratios below are conservative);
  - a uniform render of --samples samples (every pixel the same);
  - one render per noise target (--noise-target T, --cap samples at most, --pass-samples);
  - for each target, a uniform render of the target's mean samples per pixel, rounded.
Relative MSE: the mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01). A few fireflies
(a rare caustic path through glass) dominate it, and whether a render caught one is luck, so
it is also given trimmed: without the 0.1 % of pixels with the largest error. With --seeds K
every render but the reference is made K times, with Tessera's own seed and then seeds 1 to K-1,
and each figure is the mean over them (the expected error, which one seed's firefly luck does
not decide); the range over the seeds follows in brackets.
For each target it prints its mean samples, its relative MSE, the uniform render's at the same
samples and the ratio (below 1: the target is better), and whether it reaches the --samples
uniform render's error and with what share of its samples.
Needs numpy and OpenEXR, and a release build (`cargo build --release -p tessera-worker`).

Example (the glass Cornell box at 256x256):
  python3 tests/bench/noise_target_mse.py --scene ../shared/scenes/xml/cornellbox_jaroslav_path_glass.xml \
      --camera 3 --scale 0.5 --samples 256 --cap 1024 --targets 0.2 0.15 0.1 0.07 --reference-samples 4096
"""

import argparse
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from denoise_quality import read_exr, rel_mse  # noqa: E402

import numpy as np  # noqa: E402


def trimmed_rel_mse(x, r, keep=0.999):
    """The relative MSE of the pixels but the 0.1 % with the largest error."""
    e = np.sort(((x - r) ** 2 / (r * r + 0.01)).mean(axis=-1).ravel())
    return float(e[: max(1, int(len(e) * keep))].mean())


def render(args, out, samples, extra=()):
    cmd = [args.bin, "render", args.scene, "--camera", args.camera, "--quiet", "--out", out,
           "--tile-size", str(args.tile_size), "--samples", str(samples), "--scale", str(args.scale)]
    cmd += list(extra)
    if args.threads:
        cmd += ["--threads", args.threads]
    if not (os.path.isdir(out) and any(f.endswith(".exr") for f in os.listdir(out))):
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            sys.exit(f"{' '.join(cmd)} failed:\n{run.stderr}")
        with open(os.path.join(out, "stdout.txt"), "w") as f:
            f.write(run.stdout)
    stdout = open(os.path.join(out, "stdout.txt")).read()
    exr = [f for f in os.listdir(out) if f.endswith(".exr")][0]
    spp = re.search(r"([0-9.]+) samples per pixel on average", stdout)
    return read_exr(os.path.join(out, exr)), float(spp.group(1)) if spp else float(samples)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--camera", required=True)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--samples", type=int, required=True, help="the uniform render to match")
    ap.add_argument("--cap", type=int, required=True, help="the noise target renders' samples at most")
    ap.add_argument("--targets", type=float, nargs="+", required=True)
    ap.add_argument("--pass-samples", type=int, default=16)
    ap.add_argument("--reference-samples", type=int, default=4096)
    ap.add_argument("--seed", default="12345", help="the reference's seed")
    ap.add_argument("--tile-size", type=int, default=32)
    ap.add_argument("--bin", default=os.path.join(os.path.dirname(__file__), "../../target/release/tessera-worker"))
    ap.add_argument("--threads", default=None)
    ap.add_argument("--seeds", type=int, default=1, help="renders of each kind, with as many seeds (the mean is given)")
    ap.add_argument("--keep", default=None, help="keep the renders in this folder (and reuse them)")
    args = ap.parse_args()
    root = args.keep or tempfile.mkdtemp(prefix="tessera-noise-mse-")
    os.makedirs(root, exist_ok=True)
    ref, _ = render(args, os.path.join(root, f"reference{args.reference_samples}"), args.reference_samples,
                    ["--seed", args.seed])
    uniform_cache = {}
    seeds = [[]] + [["--seed", str(k)] for k in range(1, args.seeds)]

    def errors(img):
        return rel_mse(img, ref), trimmed_rel_mse(img, ref)

    def seeded(name, k):
        return os.path.join(root, name if k == 0 else f"{name}_seed{k}")

    def uniform(n):
        if n not in uniform_cache:
            uniform_cache[n] = [errors(render(args, seeded(f"uniform{n}", k), n, seeds[k])[0])
                                for k in range(args.seeds)]
        return uniform_cache[n]

    def mean(runs, i):
        return sum(r[i] for r in runs) / len(runs)

    def spread(runs, i):
        if len(runs) == 1:
            return ""
        return f" [{min(r[i] for r in runs):.5f}-{max(r[i] for r in runs):.5f}]"

    goal = uniform(args.samples)
    goal_mean = (mean(goal, 0), mean(goal, 1))
    print(f"{os.path.basename(args.scene)} camera {args.camera} at scale {args.scale}: reference "
          f"{args.reference_samples} spp (seed {args.seed}); uniform {args.samples} spp: relative MSE "
          f"{goal_mean[0]:.5f}{spread(goal, 0)}, trimmed {goal_mean[1]:.5f}{spread(goal, 1)}"
          f"{f' (means over {args.seeds} seeds)' if args.seeds > 1 else ''}")
    print(f"| render | samples per pixel (mean) | relative MSE (trimmed) | uniform at the same samples | ratio "
          f"(trimmed) | reaches uniform {args.samples} spp (trimmed)? |")
    print("|---|---|---|---|---|---|")
    for t in args.targets:
        runs, spps = [], []
        for k in range(args.seeds):
            img, spp = render(args, seeded(f"target{t}_cap{args.cap}_pass{args.pass_samples}", k), args.cap,
                              ["--noise-target", str(t), "--pass-samples", str(args.pass_samples)] + seeds[k])
            runs.append(errors(img))
            spps.append(spp)
        spp = sum(spps) / len(spps)
        e = (mean(runs, 0), mean(runs, 1))
        same_runs = uniform(max(1, round(spp)))
        same = (mean(same_runs, 0), mean(same_runs, 1))
        reach = ["yes" if e[i] <= goal_mean[i] else "no" for i in range(2)]
        print(f"| target {t} (cap {args.cap}) | {spp:.2f} ({spp / args.samples:.3f}x) | {e[0]:.5f}{spread(runs, 0)} "
              f"({e[1]:.5f}) | {same[0]:.5f}{spread(same_runs, 0)} ({same[1]:.5f}) | {e[0] / same[0]:.3f} "
              f"({e[1] / same[1]:.3f}) | {reach[0]} ({reach[1]}) |", flush=True)
    print(f"renders in {root}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""How much any per-pixel sample allocation could buy on a scene: an oracle's figure.

Renders one camera of a scene four times with `tessera-worker render` (linear EXR, --samples
each, seeds 0 to 3, all at --scale). Pixel by pixel, the relative variance of one sample,
    c = n * (a - b)^2 / 2 / (r^2 + 0.01)   (the mean over the channels)
is measured twice and independently: from renders 0 and 1 (r the mean of renders 2 and 3) and
from renders 2 and 3 (r the mean of 0 and 1). Uniform sampling's expected relative MSE at N
samples a pixel is mean(c) / N; giving each pixel samples in proportion to w (mean 1) makes it
mean(c / w) / N. The oracle takes w = smooth(c')^p from one measurement and is scored with the
other (scored with the same one it would be flattered by its own noise), for box smoothings of
--smooth half-widths and the powers 1/2 (the allocation that minimises the error when c is
known) and 1/3. Each line prints mean(c / w) / mean(c) both ways round: below 1 the oracle
beats uniform sampling at equal mean samples; a noise target, which measures its pixels' error
from their own few samples, does no better than the oracle in expectation.

Needs numpy and OpenEXR, and a release build (`cargo build --release -p tessera-worker`).

Example (VeachAjar_hw6's path camera at 320x180):
  python3 tests/bench/noise_oracle.py --scene ../shared/scenes/xml/VeachAjar_hw6.xml --camera 2 \\
      --scale 0.25 --samples 1017
"""

import argparse
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from denoise_quality import read_exr  # noqa: E402

import numpy as np  # noqa: E402


def render(args, out, seed):
    if not (os.path.isdir(out) and any(f.endswith(".exr") for f in os.listdir(out))):
        cmd = [args.bin, "render", args.scene, "--camera", args.camera, "--quiet", "--out", out,
               "--tile-size", str(args.tile_size), "--samples", str(args.samples),
               "--scale", str(args.scale), "--seed", str(seed)]
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            sys.exit(f"{' '.join(cmd)} failed:\n{run.stderr}")
    exr = [f for f in os.listdir(out) if f.endswith(".exr")][0]
    return read_exr(os.path.join(out, exr)).astype(np.float64)


def box(x, k):
    """The mean of each pixel's (2k+1) x (2k+1) neighbourhood (edges repeated)."""
    if k == 0:
        return x
    p = np.pad(x, k, mode="edge")
    out = np.zeros_like(x)
    for dy in range(2 * k + 1):
        for dx in range(2 * k + 1):
            out += p[dy:dy + x.shape[0], dx:dx + x.shape[1]]
    return out / (2 * k + 1) ** 2


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--camera", required=True)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--samples", type=int, required=True, help="samples a pixel of each of the four renders")
    ap.add_argument("--smooth", type=int, nargs="+", default=[0, 1, 2, 4, 8], help="box half-widths")
    ap.add_argument("--tile-size", type=int, default=32)
    ap.add_argument("--bin", default=os.path.join(os.path.dirname(__file__), "../../target/release/tessera-worker"))
    ap.add_argument("--keep", default=None, help="keep the renders in this folder (and reuse them)")
    args = ap.parse_args()
    root = args.keep or tempfile.mkdtemp(prefix="tessera-noise-oracle-")
    os.makedirs(root, exist_ok=True)
    x = [render(args, os.path.join(root, f"uniform{args.samples}_seed{s}"), s) for s in range(4)]
    n = args.samples

    def measured(a, b, r):
        return (n * (a - b) ** 2 / 2 / (r * r + 0.01)).mean(axis=-1)

    c = [measured(x[0], x[1], (x[2] + x[3]) / 2), measured(x[2], x[3], (x[0] + x[1]) / 2)]
    print(f"{os.path.basename(args.scene)} camera {args.camera}, {c[0].shape[1]}x{c[0].shape[0]}, four renders of "
          f"{n} spp; one sample's relative variance, the pixels' mean: {c[0].mean():.4g} and {c[1].mean():.4g}")
    print("| smoothing | power | oracle / uniform, measured on 0-1 scored on 2-3 | and the other way round |")
    print("|---|---|---|---|")
    for k in args.smooth:
        for power in (0.5, 1 / 3):
            ratios = []
            for est, score in ((c[0], c[1]), (c[1], c[0])):
                # A pixel measured at exactly 0 (black in both renders) still gets a sliver.
                w = np.maximum(box(est, k), 1e-12) ** power
                w = w / w.mean()
                ratios.append(np.mean(score / w) / np.mean(score))
            print(f"| {2 * k + 1}x{2 * k + 1} | {power:.2f} | {ratios[0]:.3f} | {ratios[1]:.3f} |")
    print(f"renders in {root}")


if __name__ == "__main__":
    main()

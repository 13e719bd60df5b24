#!/usr/bin/env python3
"""How close raw and denoised path-traced frames come to the course's official image.

Renders one camera of a scene with `tessera-worker render --denoise` at each sample count
given, then compares the raw and the denoised frame with the official image:
  - relative MSE on the linear EXRs: mean over pixels and channels of (x - r)^2 / (r^2 + 0.01);
  - PSNR of the tone-mapped PNGs after a 4x4 box filter (forgives per-pixel noise);
  - mean FLIP (LDR, NVIDIA's flip-evaluator package) of the tone-mapped PNGs;
and prints the render and denoise times the CLI reports, beside the time of the pyoidn wheel's
own `oidnDenoise` program doing the same three filters on a frame of the same size, as the
anchor of the same run. Needs numpy, OpenEXR, Pillow and
flip-evaluator (`python3 -m pip install numpy OpenEXR pillow flip-evaluator`), OIDN (pyoidn), and
a release build (`cargo build --release -p tessera-worker`).

Example (the figures in docs/PERFORMANCE.md):
  python3 tests/bench/denoise_quality.py --scene ../shared/scenes/xml/VeachAjar_hw6.xml --camera 2 \
      --reference ../shared/scenes/reference/VeachAjar_hw6__VeachAjar_path --spp 16 64 256
"""

import argparse
import os
import re
import subprocess
import sys
import tempfile

import numpy as np


def read_exr(path):
    import OpenEXR

    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.asarray(ch["RGB"].pixels, dtype=np.float64)
        return np.stack([np.asarray(ch[c].pixels, dtype=np.float64) for c in "RGB"], axis=-1)


def read_png(path):
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)


def rel_mse(x, r):
    return float(np.mean((x - r) ** 2 / (r * r + 0.01)))


def box_psnr(a, b):
    h, w = (a.shape[0] // 4) * 4, (a.shape[1] // 4) * 4

    def box(img):
        return img[:h, :w].reshape(h // 4, 4, w // 4, 4, 3).mean(axis=(1, 3))

    mse = float(np.mean((box(a) - box(b)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def mean_flip(ref_png, test_png):
    import flip_evaluator

    _, mean, _ = flip_evaluator.evaluate(ref_png, test_png, "LDR")
    return float(mean)


def write_pfm(path, px):
    h, w, _ = px.shape
    with open(path, "wb") as o:
        o.write(f"PF\n{w} {h}\n-1.0\n".encode())
        o.write(np.ascontiguousarray(px[::-1]).astype("<f4").tobytes())


def oidn_denoise_seconds(raw_exr, workdir):
    """The anchor: the pyoidn wheel's own oidnDenoise program doing the work Tessera's denoise
    does, at high quality: an RT filter on an albedo image, one on a normal image, then one on
    the raw frame with both as clean guides. OIDN's time does not depend on what the guides hold
    (measured: constant, random and rendered albedo take the same time), so they are flat images
    of the frame's size here. Each filter's time as oidnDenoise reports it (first run, as in
    Tessera, where each filter is made anew), summed."""
    import importlib.util

    spec = importlib.util.find_spec("pyoidn")
    if spec is None:
        return None
    prog = os.path.join(spec.submodule_search_locations[0], "oidn", "bin", "oidnDenoise")
    raw = read_exr(raw_exr)
    paths = {k: os.path.join(workdir, k + ".pfm") for k in ("raw", "albedo", "normal", "out")}
    write_pfm(paths["raw"], raw)
    write_pfm(paths["albedo"], np.full(raw.shape, 0.5))
    write_pfm(paths["normal"], np.full(raw.shape, 0.5))
    total = 0.0
    for args in (["--alb", paths["albedo"]], ["--nrm", paths["normal"]],
                 ["--hdr", paths["raw"], "--alb", paths["albedo"], "--nrm", paths["normal"], "--clean_aux"]):
        run = subprocess.run([prog, *args, "-o", paths["out"], "-q", "high", "-n", "1", "-v", "2"],
                             capture_output=True, text=True)
        times = re.findall(r"Denoising\n\s*msec=([0-9.]+)", run.stdout)
        if not times:
            return None
        total += float(times[0]) / 1000
    return total


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--camera", required=True)
    ap.add_argument("--reference", required=True, help="the official image's path without .exr/.png")
    ap.add_argument("--spp", type=int, nargs="+", required=True)
    ap.add_argument("--bin", default=os.path.join(os.path.dirname(__file__), "../../target/release/tessera-worker"))
    ap.add_argument("--threads", default=None)
    ap.add_argument("--keep", default=None, help="keep the renders in this folder")
    args = ap.parse_args()
    ref_exr, ref_png = read_exr(args.reference + ".exr"), args.reference + ".png"
    ref_png_px = read_png(ref_png)
    out_root = args.keep or tempfile.mkdtemp(prefix="tessera-denoise-")
    print(f"| spp | render s | denoise s | oidnDenoise s (same 3 filters) | relMSE raw | relMSE denoised | box PSNR raw | box PSNR denoised | FLIP raw | FLIP denoised |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for spp in args.spp:
        out = os.path.join(out_root, f"spp{spp}")
        cmd = [args.bin, "render", args.scene, "--camera", args.camera, "--samples", str(spp), "--denoise", "--quiet", "--out", out]
        if args.threads:
            cmd += ["--threads", args.threads]
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            sys.exit(f"{' '.join(cmd)} failed:\n{run.stderr}")
        render_s = float(re.search(r"spp, ([0-9.]+) s", run.stdout).group(1))
        denoise_s = float(re.search(r"denoised in ([0-9.]+) s", run.stdout).group(1))
        exrs = sorted(f for f in os.listdir(out) if f.endswith(".exr"))
        raw = [f for f in exrs if not f.endswith("_denoised.exr")][0]
        stem = raw[: -len(".exr")]
        cells = []
        for name in (stem, stem + "_denoised"):
            cells.append(
                (rel_mse(read_exr(os.path.join(out, name + ".exr")), ref_exr),
                 box_psnr(read_png(os.path.join(out, name + ".png")), ref_png_px),
                 mean_flip(ref_png, os.path.join(out, name + ".png")))
            )
        (m0, p0, f0), (m1, p1, f1) = cells
        anchor = oidn_denoise_seconds(os.path.join(out, stem + ".exr"), out)
        anchor = f"{anchor:.2f}" if anchor is not None else "n/a"
        print(f"| {spp} | {render_s:.1f} | {denoise_s:.2f} | {anchor} | {m0:.4f} | {m1:.4f} | {p0:.2f} | {p1:.2f} | {f0:.4f} | {f1:.4f} |", flush=True)
    print(f"renders in {out_root}")


if __name__ == "__main__":
    main()

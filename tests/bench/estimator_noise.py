#!/usr/bin/env python3
"""A renderer flag of Tessera's own against the estimator without it, at equal samples: time and noise.

Takes one camera of a path-traced scene (by default ../shared/bench/jaroslav_path.xml, the
course's cornellbox_jaroslav_path_diffuse `diffuse_next_importance` camera: a point light and a
light box) at --size x --size, its RendererParams as they are or as --params gives them (which
also makes a classic camera path-traced), and renders it:
  - a reference of each estimator (without and with --flag) at --ref-spp samples (both threads);
  - each estimator at --spp samples on one thread, --rounds times, in alternation (the render
    time the CLI prints; the median is reported).
Each test render is compared with the OTHER estimator's reference, so that no sample is shared
(the two draw different numbers). The error is the mean squared difference over the pixels
divided by the squared mean of the image, dropping the worst 0.1 % of pixels (a single firefly
of the reference otherwise decides it); the two references' own error is printed too, since it
is part of both figures. Equal-time efficiency is 1 / (error x seconds). The scene is rewritten
into a temporary folder, so it must not refer to files beside it. Needs numpy and OpenEXR, and a
release build.

Examples (the figures in docs/PERFORMANCE.md):
  python3 tests/bench/estimator_noise.py --flag SampleOneLight --size 128 --spp 64 --ref-spp 1024 --rounds 3
  python3 tests/bench/estimator_noise.py --flag MultipleImportanceSampling \\
      --scene ../shared/scenes/xml/cornellbox_jaroslav_glossy_area.xml \\
      --params "NextEventEstimation ImportanceSampling" --size 128 --spp 16 --ref-spp 1024 --rounds 3
"""

import argparse
import os
import re
import statistics
import subprocess
import tempfile
import xml.etree.ElementTree as ET

import numpy as np
import OpenEXR

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")


def read_exr(path):
    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.array(ch["RGB"].pixels, dtype=np.float64)
        return np.stack([np.array(ch[c].pixels, dtype=np.float64) for c in "RGB"], -1)


def set_child(parent, tag, text):
    node = parent.find(tag)
    if node is None:
        node = ET.SubElement(parent, tag)
    node.text = text


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=os.path.join(ROOT, "..", "shared", "bench", "jaroslav_path.xml"))
    ap.add_argument("--camera", default="1", help="the camera's id")
    ap.add_argument("--params", default=None, help="RendererParams instead of the camera's own")
    ap.add_argument("--flag", default="SampleOneLight", help="the RendererParams word under test")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "tessera-worker"))
    args = ap.parse_args()
    with open(args.scene) as f:
        # The bench's own scenes hold a placeholder for the sample count; --samples sets it.
        root = ET.fromstring(f.read().replace("<NumSamples>SPP</NumSamples>", "<NumSamples>1</NumSamples>"))
    cameras = [c for c in root.iter("Camera") if c.get("id") == args.camera]
    if len(cameras) != 1:
        raise SystemExit(f"{args.scene}: no single <Camera id=\"{args.camera}\">")
    cam = cameras[0]
    block = next(root.iter("Cameras"))
    for other in block.findall("Camera"):
        if other is not cam:
            block.remove(other)
    set_child(cam, "ImageResolution", f"{args.size} {args.size}")
    set_child(cam, "ImageName", "frame.exr")
    base = args.params if args.params is not None else (cam.findtext("RendererParams") or "")
    if args.params is not None:
        set_child(cam, "Renderer", "PathTracing")
    if cam.findtext("Renderer", "").strip() != "PathTracing":
        raise SystemExit(f"camera {args.camera} is not path-traced; give --params")
    work = tempfile.mkdtemp(prefix="tessera-estimator-")

    def scene(name, flag):
        set_child(cam, "RendererParams", f"{base} {args.flag}" if flag else base)
        path = os.path.join(work, name + ".xml")
        ET.ElementTree(root).write(path)
        return path

    def render(path, out, spp, threads, pin):
        cmd = [args.bin, "render", path, "--quiet", "--out", out, "--threads", str(threads), "--samples", str(spp)]
        if pin:
            cmd = ["taskset", "-c", "0"] + cmd
        run = subprocess.run(cmd, capture_output=True, text=True, check=True)
        secs = float(re.search(r"spp, ([0-9.]+) s", run.stdout).group(1))
        return read_exr(os.path.join(out, "frame.exr")), secs

    refs = {f: render(scene(f"ref{int(f)}", f), os.path.join(work, f"ref{int(f)}"), args.ref_spp, 2, False)[0]
            for f in (False, True)}
    mean = refs[False].mean()

    def error(x, ref):
        e = ((x - ref) ** 2).mean(-1) / mean ** 2
        return np.sort(e.ravel())[: int(e.size * 0.999)].mean()

    print(f"{os.path.basename(args.scene)} camera {args.camera} ({base}), {args.size}x{args.size}, "
          f"{args.spp} spp against {args.ref_spp}-spp references; the references' own error: "
          f"{error(refs[False], refs[True]):.4f}")
    print("| estimator | s (median, one thread) | error | efficiency (1 / error x s) |")
    print("|---|---|---|---|")
    rows = {}
    paths = {flag: scene(f"test{int(flag)}", flag) for flag in (False, True)}
    times, imgs = {False: [], True: []}, {}
    # Rounds alternate between the two, so that a drift in the machine's speed weighs on both.
    for _ in range(args.rounds):
        for flag in (False, True):
            imgs[flag], secs = render(paths[flag], os.path.join(work, f"test{int(flag)}"), args.spp, 1, True)
            times[flag].append(secs)
    for flag in (False, True):
        secs = statistics.median(times[flag])
        err = error(imgs[flag], refs[not flag])
        rows[flag] = (secs, err)
        name = args.flag if flag else "without it"
        print(f"| {name} | {secs:.3f} | {err:.4f} | {1 / (err * secs):.1f} |", flush=True)
    (ta, ea), (tf, ef) = rows[False], rows[True]
    print(f"{args.flag} / without: time {tf / ta:.3f}, error {ef / ea:.3f}, efficiency {(ea * ta) / (ef * tf):.3f}")


if __name__ == "__main__":
    main()

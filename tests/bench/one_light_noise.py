#!/usr/bin/env python3
"""Every-light NEE (the course's estimator) against SampleOneLight at equal samples: time and noise.

Renders ../shared/bench/jaroslav_path.xml (cornellbox_jaroslav_path_diffuse's
`diffuse_next_importance` camera, a point light and a light box) at --size x --size:
  - a reference of each estimator at --ref-spp samples (both threads);
  - each estimator at --spp samples on one thread, --rounds times (the render time the CLI
    prints; the median is reported).
Each test render is compared with the OTHER estimator's reference, so that no sample is shared
(the two draw different numbers after the first vertex). The error is the mean squared
difference over the pixels divided by the squared mean of the image, dropping the worst 0.1 %
of pixels (a single firefly of the reference otherwise decides it); the two references' own
error is printed too, since it is part of both figures. Equal-time efficiency is
1 / (error x seconds). Needs numpy and OpenEXR, and a release build.

Example (the figures in docs/PERFORMANCE.md):
  python3 tests/bench/one_light_noise.py --size 128 --spp 64 --ref-spp 1024 --rounds 3
"""

import argparse
import os
import re
import statistics
import subprocess
import tempfile

import numpy as np
import OpenEXR

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
PARAMS = "NextEventEstimation ImportanceSampling"


def read_exr(path):
    with OpenEXR.File(path) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.array(ch["RGB"].pixels, dtype=np.float64)
        return np.stack([np.array(ch[c].pixels, dtype=np.float64) for c in "RGB"], -1)


def render(args, scene, out, threads, pin):
    cmd = [args.bin, "render", scene, "--quiet", "--out", out, "--threads", str(threads)]
    if pin:
        cmd = ["taskset", "-c", "0"] + cmd
    run = subprocess.run(cmd, capture_output=True, text=True, check=True)
    secs = float(re.search(r"spp, ([0-9.]+) s", run.stdout).group(1))
    return read_exr(os.path.join(out, "diffuse_next_importance.exr")), secs


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "tessera-worker"))
    args = ap.parse_args()
    with open(os.path.join(ROOT, "..", "shared", "bench", "jaroslav_path.xml")) as f:
        base = f.read()
    if PARAMS not in base or "<ImageResolution>512 512</ImageResolution>" not in base:
        raise SystemExit("jaroslav_path.xml is not the file this bench edits")
    base = base.replace("<ImageResolution>512 512</ImageResolution>",
                        f"<ImageResolution>{args.size} {args.size}</ImageResolution>")
    work = tempfile.mkdtemp(prefix="tessera-one-light-")

    def scene(name, spp, one):
        text = base.replace("SPP", str(spp))
        if one:
            text = text.replace(PARAMS, PARAMS + " SampleOneLight")
        path = os.path.join(work, name + ".xml")
        with open(path, "w") as f:
            f.write(text)
        return path

    refs = {one: render(args, scene(f"ref{int(one)}", args.ref_spp, one), os.path.join(work, f"ref{int(one)}"), 2,
                        False)[0] for one in (False, True)}
    mean = refs[False].mean()

    def error(x, ref):
        e = ((x - ref) ** 2).mean(-1) / mean ** 2
        return np.sort(e.ravel())[: int(e.size * 0.999)].mean()

    print(f"{args.size}x{args.size}, {args.spp} spp against {args.ref_spp}-spp references; "
          f"the references' own error: {error(refs[False], refs[True]):.4f}")
    print("| estimator | s (median, one thread) | error | efficiency (1 / error x s) |")
    print("|---|---|---|---|")
    rows = {}
    for one in (False, True):
        path = scene(f"test{int(one)}", args.spp, one)
        times, img = [], None
        for _ in range(args.rounds):
            img, secs = render(args, path, os.path.join(work, f"test{int(one)}"), 1, True)
            times.append(secs)
        secs = statistics.median(times)
        err = error(img, refs[not one])
        rows[one] = (secs, err)
        name = "SampleOneLight" if one else "every light"
        print(f"| {name} | {secs:.3f} | {err:.4f} | {1 / (err * secs):.1f} |", flush=True)
    (ta, ea), (to, eo) = rows[False], rows[True]
    print(f"SampleOneLight / every light: time {to / ta:.3f}, error {eo / ea:.3f}, efficiency {(ea * ta) / (eo * to):.3f}")


if __name__ == "__main__":
    main()

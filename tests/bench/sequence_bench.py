#!/usr/bin/env python3
"""An animation three ways, side by side in one run: the CLI rendering every scene file in one
process (its caches shared), the CLI as one process per scene file, and the farm (a fresh
`tessera-server` with one local worker) given the whole sequence as one job by the client.

    cargo build --release
    python3 tests/bench/sequence_bench.py --bin target/release \
        --dir ../shared/scenes/sequences/camera_around_david --glob 'davids_camera_*.json'

Prints one line per mode (wall seconds; CPU milliseconds a frame of the CLI's one process, and of
the farm's server and its worker apart), the farm's bytes uploaded and kept, whether every farm
frame has the CLI's bytes, and, when ffmpeg is on PATH and the folder has `reference.mp4`, the
PSNR of the farm's video against it after a 4x4 box (both decoded to RGB and averaged over 4x4
blocks by ffmpeg's `area` scaling) over every frame. `--frames N` takes the first N files only.
"""

import argparse
import glob
import json
import os
import re
import resource
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request


def dir_bytes(path):
    total = 0
    for root, _, files in os.walk(path):
        for f in files:
            try:
                total += os.lstat(os.path.join(root, f)).st_size
            except OSError:
                pass
    return total


def cpu_seconds(pid):
    """User + system CPU seconds of process `pid` so far (every thread; from /proc)."""
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def child_pids(pid):
    """The processes `pid` started (its local worker), from /proc."""
    out = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            out += [int(c) for c in open(f"/proc/{pid}/task/{task}/children").read().split()]
        except OSError:
            pass
    return out


def children_cpu():
    """CPU seconds of this script's finished child processes."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def timed(cmd, **kw):
    start = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, **kw)
    return time.monotonic() - start, proc


def split(stdout):
    """Median seconds per frame of each step, from `--timings-json` lines (frames after the first)."""
    rows = [json.loads(l) for l in stdout.splitlines() if l.startswith("{")]
    rows = rows[1:] or rows
    keys = ["parse_seconds", "mesh_seconds", "top_level_seconds", "render_seconds", "write_seconds"]
    med = lambda xs: sorted(xs)[len(xs) // 2] if xs else float("nan")
    return "  ".join(f"{k.split('_')[0]} {med([r[k] for r in rows]) * 1000:.1f} ms" for k in keys)


def video_psnr(ours, reference):
    """Mean PSNR (dB, RGB) over the frames both videos have, after a 4x4 box."""
    graph = (
        "[0:v]format=rgb24,scale=iw/4:ih/4:flags=area[a];"
        "[1:v]format=rgb24,scale=iw/4:ih/4:flags=area[b];[a][b]psnr"
    )
    proc = subprocess.run(
        ["ffmpeg", "-hide_banner", "-nostats", "-i", ours, "-i", reference, "-lavfi", graph, "-f", "null", "-"],
        capture_output=True,
        text=True,
    )
    m = re.search(r"PSNR .*average:([0-9.inf]+)", proc.stderr)
    return m.group(1) if m else "unknown (" + proc.stderr.strip().splitlines()[-1] + ")"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", required=True, help="folder of the release binaries")
    ap.add_argument("--dir", required=True, help="the sequence's folder")
    ap.add_argument("--glob", required=True, help="its scene files, relative to --dir (zero-padded names)")
    ap.add_argument("--frames", type=int, default=0, help="only the first N scene files")
    ap.add_argument("--skip-separate", action="store_true", help="leave out the one-process-a-frame run")
    args = ap.parse_args()

    scenes = sorted(glob.glob(os.path.join(args.dir, args.glob)))
    if args.frames:
        scenes = scenes[: args.frames]
    if not scenes:
        sys.exit(f"no file of {args.dir} matches {args.glob}")
    worker = os.path.join(args.bin, "tessera-worker")
    server = os.path.join(args.bin, "tessera-server")
    client = os.path.join(args.bin, "tessera")
    work = tempfile.mkdtemp(prefix="sequence-bench-")
    n = len(scenes)
    try:
        # 1. One process, every scene file.
        cpu_before = children_cpu()
        t_one, proc = timed(
            [worker, "render", *scenes, "--out", os.path.join(work, "cli"), "--quiet", "--timings-json"]
        )
        if proc.returncode != 0:
            sys.exit("tessera-worker render failed:\n" + proc.stderr)
        cpu_one = children_cpu() - cpu_before
        print(
            f"frames {n}: CLI, one process: {t_one:.2f} s ({t_one / n * 1000:.0f} ms a frame; "
            f"CPU {cpu_one / n * 1000:.0f} ms a frame)",
            flush=True,
        )
        print(f"  per frame (median of frames 2-{n}): {split(proc.stdout)}")

        # 2. One process a scene file.
        if not args.skip_separate:
            start = time.monotonic()
            lines = []
            for s in scenes:
                proc = subprocess.run(
                    [worker, "render", s, "--out", os.path.join(work, "separate"), "--quiet", "--timings-json"],
                    capture_output=True,
                    text=True,
                )
                if proc.returncode != 0:
                    sys.exit(f"tessera-worker render {s} failed:\n" + proc.stderr)
                lines.append(proc.stdout)
            t_sep = time.monotonic() - start
            print(f"frames {n}: CLI, a process a frame: {t_sep:.2f} s ({t_sep / n * 1000:.0f} ms a frame)", flush=True)
            print(f"  per frame (median of frames 2-{n}): {split(''.join(lines))}")

        # 3. The farm: a fresh server with one local worker, the sequence as one job.
        port = free_port()
        data = os.path.join(work, "data")
        log = open(os.path.join(work, "server.log"), "w")
        srv = subprocess.Popen(
            [server, "--bind", f"127.0.0.1:{port}", "--data-dir", data, "--local-workers", "1"],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        url = f"http://127.0.0.1:{port}"
        try:
            for _ in range(200):
                try:
                    urllib.request.urlopen(url + "/healthz", timeout=1).read()
                    break
                except OSError:
                    time.sleep(0.1)
            env = dict(os.environ, TESSERA_SERVER=url)
            out = os.path.join(work, "farm")
            # CPU of the server and of its local worker, from /proc (ffmpeg's is the server's
            # children's, not counted here).
            workers = []
            for _ in range(100):
                workers = child_pids(srv.pid)
                if workers:
                    break
                time.sleep(0.1)
            cpu_at = lambda: [cpu_seconds(p) for p in [srv.pid, *workers]]
            cpu_start = cpu_at()
            t_farm, proc = timed([client, "submit", *scenes, "--wait", "--out", out, "--verbose"], env=env)
            cpu_farm = [b - a for a, b in zip(cpu_start, cpu_at())]
            if proc.returncode != 0:
                sys.exit("tessera submit failed:\n" + proc.stdout + proc.stderr)
            uploaded = re.findall(r"uploaded \d+ of \d+ files[^\n]*", proc.stderr + proc.stdout)
            print(f"frames {n}: farm, one job: {t_farm:.2f} s ({t_farm / n * 1000:.0f} ms a frame)", flush=True)
            if not args.skip_separate:
                print(f"  farm / CLI one process: {t_farm / t_one:.2f}; farm / CLI a process a frame: {t_farm / t_sep:.2f}")
            else:
                print(f"  farm / CLI one process: {t_farm / t_one:.2f}")
            print(
                f"  CPU a frame: server {cpu_farm[0] / n * 1000:.0f} ms, its worker "
                f"{sum(cpu_farm[1:]) / n * 1000:.0f} ms (the CLI's one process: {cpu_one / n * 1000:.0f} ms)"
            )
            for line in uploaded[:3]:
                print(f"  client: {line.strip()}")
            built = [l for l in open(os.path.join(work, "server.log")).read().splitlines() if " built in " in l]
            cached = sum(1 for l in built if "world tree from the cache" in l or "(0 mesh(es) from the cache" not in l)
            print(f"  farm worker: {len(built)} scene builds, {cached} of them with meshes from its cache")
            files = dir_bytes(os.path.join(data, "files"))
            total = dir_bytes(data)
            print(
                f"  server data dir: {total / 1e6:.1f} MB ({files / 1e6:.1f} MB of it the job's files, "
                f"{(total - files) / n / 1e3:.0f} kB a frame besides)"
            )
            jobs = json.load(urllib.request.urlopen(url + "/api/v1/jobs"))["jobs"]
            print(f"  jobs on the farm: {len(jobs)}")
        finally:
            srv.terminate()
            srv.wait(timeout=30)
            log.close()

        # The farm's frames against the CLI's, byte for byte.
        cli_files = sorted(f for f in os.listdir(os.path.join(work, "cli")))
        differ = [
            f
            for f in cli_files
            if not os.path.exists(os.path.join(out, f))
            or open(os.path.join(out, f), "rb").read() != open(os.path.join(work, "cli", f), "rb").read()
        ]
        print(f"  farm frames with the CLI's bytes: {len(cli_files) - len(differ)} of {len(cli_files)}")

        videos = [f for f in os.listdir(out) if f.endswith(".mp4")]
        reference = os.path.join(args.dir, "reference.mp4")
        if videos and os.path.exists(reference) and shutil.which("ffmpeg"):
            psnr = video_psnr(os.path.join(out, videos[0]), reference)
            print(f"  video {videos[0]} against reference.mp4: PSNR after a 4x4 box {psnr} dB (mean over frames)")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

"""Whole-process render time of official scenes: Tessera against the student tracer anchor.

Usage: peer_scenes.py [--rounds N] [--threads N] [--peer-dir DIR] [--worker PATH] SCENE.xml [SCENE.xml ...]

For issue #18 item 3 ("five times the student tracer on every scene"). Each round renders every
scene once with `tessera-worker render` (target/release, or --worker, e.g. the PGO build
deploy/pgo-build.sh makes in target/pgo/release; every core unless --threads) and once
with the student C++ tracer of ../shared/bench/peer (`DIR/run_peer.sh`, where DIR is
--peer-dir or `$PEER_DIR`, the directory its build.sh built it into; it always uses every
core), alternately, and times each whole process
(parse, build, render, image files). Prints one line per scene and round, then one summary line
per scene: the median wall seconds of each side and the ratio student / Tessera (higher is
better for Tessera; the target is 5). Bare scene names are looked up in ../shared/scenes/xml
(or $TESSERA_SCENES/xml).

Both sides render the scene as its file says (its cameras and sample counts). The images are
written to a temporary directory and thrown away; conformance is the job of the tests, not of
this bench.
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def scenes_dir() -> Path:
    env = os.environ.get("TESSERA_SCENES")
    return Path(env) if env else ROOT.parent / "shared" / "scenes"


def resolve(scene: str) -> Path:
    p = Path(scene)
    if p.is_file():
        return p
    q = scenes_dir() / "xml" / (scene if scene.endswith(".xml") else scene + ".xml")
    if q.is_file():
        return q
    sys.exit(f"peer_scenes: no scene {scene!r} (looked for {p} and {q})")


def timed(cmd: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    secs = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"peer_scenes: {' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return secs


def machine() -> str:
    """What `tessera_testkit::cpu_description` prints for the Rust benches: ratios from different CPUs differ."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "unknown CPU"
    model = next((l.split(":", 1)[1].strip() for l in info.splitlines() if l.startswith("model name")), "unknown CPU")
    cpus = sum(1 for l in info.splitlines() if l.startswith("processor"))
    flags = next((l.split(":", 1)[1].split() for l in info.splitlines() if l.startswith("flags")), [])
    vector = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    return f"{model}, {cpus} logical CPUs, widest vectors {vector}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None, help="Tessera's render threads (default: every core)")
    ap.add_argument("--peer-dir", help="the student tracer's build directory (default: $PEER_DIR)")
    ap.add_argument("--worker", help="the tessera-worker binary (default: target/release/tessera-worker)")
    ap.add_argument("scenes", nargs="+")
    args = ap.parse_args()
    print(f"machine: {machine()}", flush=True)

    worker = Path(args.worker) if args.worker else ROOT / "target" / "release" / "tessera-worker"
    if not worker.is_file():
        sys.exit(f"peer_scenes: {worker} is missing: run `cargo build --release` (or deploy/pgo-build.sh) first")
    peer_dir = args.peer_dir or os.environ.get("PEER_DIR")
    if not peer_dir:
        sys.exit(
            "peer_scenes: where is the student tracer? Pass --peer-dir DIR or set PEER_DIR to the "
            "directory ../shared/bench/peer/build.sh built it into (see ../shared/bench/README.md)"
        )
    peer = Path(peer_dir) / "run_peer.sh"
    if not peer.is_file():
        sys.exit(
            f"peer_scenes: {peer} is missing: build the student tracer there with "
            "../shared/bench/peer/build.sh (see ../shared/bench/README.md)"
        )

    scenes = [resolve(s) for s in args.scenes]
    times: dict[Path, tuple[list[float], list[float]]] = {s: ([], []) for s in scenes}
    with tempfile.TemporaryDirectory(prefix="peer_scenes.") as tmp:
        for r in range(args.rounds):
            for s in scenes:
                ours_cmd = [str(worker), "render", str(s), "--out", f"{tmp}/tessera"]
                if args.threads:
                    ours_cmd += ["--threads", str(args.threads)]
                ours = timed(ours_cmd)
                theirs = timed(["bash", str(peer), str(s), f"{tmp}/peer"])
                times[s][0].append(ours)
                times[s][1].append(theirs)
                print(f"round {r + 1} {s.stem}: tessera {ours:.2f} s, student {theirs:.2f} s, ratio {theirs / ours:.2f}")
                sys.stdout.flush()
    print()
    print(f"{'scene':40} {'tessera s':>10} {'student s':>10} {'ratio':>6}   (medians of {args.rounds} rounds)")
    for s in scenes:
        ours, theirs = (statistics.median(v) for v in times[s])
        print(f"{s.stem:40} {ours:10.2f} {theirs:10.2f} {theirs / ours:6.2f}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""The Embree 4 side of `cargo bench -p tessera-common --bench rays` (the anchor).

    embree_rays.py MESH.ply RAYDIR

Driven over stdin/stdout by the Rust bench, one command per line, one JSON line per answer, so
Tessera and Embree run alternately in the same session on the same mesh and the same rays:

    build             -> {"build_s": S}   a fresh scene: TriangleMesh + commit (BVH build)
    trace KIND QUERY  -> {"s": S, "n": N, "hits": H}   RAYDIR/KIND.rays, QUERY INTERSECT|OCCLUDED
    distances KIND    -> {"written": PATH}   RAYDIR/KIND.embree_t: f32 tfar per ray (inf = miss)
    quit

Rays are little-endian f32 records (ox oy oz dx dy dz tmax); tnear is 0 (embreex fixes it).
embreex's `EmbreeScene.run` calls rtcIntersect1 / rtcOccluded1 once per ray in a compiled loop
(one Python call per batch, single rays inside): embreex exposes no packet or stream API, so this
is Embree's single-ray figure. Run under `taskset -c 0` so Embree's build uses one core too.
"""
import json
import sys
import time

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh


def read_ply(path):
    """Binary little-endian PLY as written by tessera::ply::write_ply_binary_le (float x y z
    first, then other float properties; faces `uchar int` triangles)."""
    data = open(path, 'rb').read()
    end = data.index(b'end_header\n') + len(b'end_header\n')
    header = data[:end].decode('ascii').splitlines()
    assert header[1].split()[1] == 'binary_little_endian'
    nv = nf = 0
    props = 0
    cur = None
    for line in header:
        w = line.split()
        if w[:2] == ['element', 'vertex']:
            nv, cur = int(w[2]), 'v'
        elif w[:2] == ['element', 'face']:
            nf, cur = int(w[2]), 'f'
        elif w and w[0] == 'property' and cur == 'v':
            assert w[1] == 'float'
            props += 1
    v = np.frombuffer(data, dtype='<f4', count=nv * props, offset=end).reshape(nv, props)[:, :3]
    faces = np.frombuffer(data, dtype=np.dtype([('n', 'u1'), ('i', '<i4', 3)]), count=nf,
                          offset=end + nv * props * 4)
    assert (faces['n'] == 3).all()
    return np.ascontiguousarray(v, dtype=np.float32), np.ascontiguousarray(faces['i'], dtype=np.int32)


def main():
    mesh, raydir = sys.argv[1], sys.argv[2]
    v, f = read_ply(mesh)
    tri_verts = np.ascontiguousarray(v[f])
    scene = None
    rays = {}

    def build():
        nonlocal scene
        scene = None
        one = np.zeros((1, 3), dtype=np.float32)
        t0 = time.perf_counter()
        s = rtcs.EmbreeScene()
        TriangleMesh(s, tri_verts)
        s.run(one, one + np.float32(1.0))  # the first query commits (builds) the scene
        dt = time.perf_counter() - t0
        scene = s
        return dt

    def load(kind):
        if kind not in rays:
            r = np.fromfile(f'{raydir}/{kind}.rays', dtype='<f4').reshape(-1, 7)
            rays[kind] = (np.ascontiguousarray(r[:, 0:3]), np.ascontiguousarray(r[:, 3:6]),
                          np.ascontiguousarray(r[:, 6]))
        return rays[kind]

    for line in sys.stdin:
        w = line.split()
        if not w:
            continue
        if w[0] == 'quit':
            break
        if w[0] == 'build':
            out = {'build_s': build()}
        elif w[0] == 'trace':
            if scene is None:
                build()
            o, d, tmax = load(w[1])
            dists = tmax.copy()
            t0 = time.perf_counter()
            ids = scene.run(o, d, dists=dists, query=w[2])
            dt = time.perf_counter() - t0
            hits = int((ids != -1).sum())  # primID, or 0 (occluded) / -1 (free) for OCCLUDED
            out = {'s': dt, 'n': int(len(o)), 'hits': hits}
        elif w[0] == 'distances':
            if scene is None:
                build()
            o, d, tmax = load(w[1])
            dists = tmax.copy()
            ids = scene.run(o, d, dists=dists, query='INTERSECT')
            t = scene.run(o, d, dists=tmax.copy(), query='DISTANCE')
            t = np.where(ids == -1, np.float32(np.inf), t).astype('<f4')
            path = f'{raydir}/{w[1]}.embree_t'
            t.tofile(path)
            out = {'written': path}
        else:
            out = {'error': f'unknown command {w[0]}'}
        print(json.dumps(out), flush=True)


if __name__ == '__main__':
    main()

"""Mitsuba 3's first-hit render of the head.ply primary-ray workload (issue #54, item 3).

Usage: mitsuba_head_first_hit.py PLY WIDTH HEIGHT VARIANT

The camera of ../shared/bench/head_primary.xml (position 0.322839 0.0534825 0.504299, looking at
-0.140808 -0.162727 -0.35493, up +Y, vertical field of view 30 degrees) at WIDTH x HEIGHT, one
sample a pixel through its centre, with the `aov` integrator writing the first hit's depth
(`dd.y:depth`): a camera ray each pixel, a closest hit, no shading. Renders once to compile the
kernels, then times a second render, and prints one JSON line: seconds, Mrays/s, and the share
of pixels that hit the head (Tessera's own count of that share is printed beside it by the
bench, as a check that both trace the same rays). Mitsuba uses one thread per core.
"""
import json
import sys
import time

import drjit as dr
import mitsuba as mi

ply, width, height, variant = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
mi.set_variant(variant)
scene = mi.load_dict({
    'type': 'scene',
    'head': {'type': 'ply', 'filename': ply, 'face_normals': True},
    'sensor': {
        'type': 'perspective', 'fov': 30.0, 'fov_axis': 'y',
        'to_world': mi.ScalarTransform4f().look_at(
            origin=[0.322839, 0.0534825, 0.504299], target=[-0.140808, -0.162727, -0.35493], up=[0, 1, 0]),
        # Pixel centres, as the course's one-sample camera shoots them.
        'sampler': {'type': 'stratified', 'sample_count': 1, 'jitter': False},
        'film': {'type': 'hdrfilm', 'width': width, 'height': height, 'rfilter': {'type': 'box'},
                 'pixel_format': 'rgb'},
    },
    'integrator': {'type': 'aov', 'aovs': 'dd.y:depth'},
})
img = mi.render(scene, spp=1)  # compile the kernels
dr.eval(img)
dr.sync_thread()
start = time.perf_counter()
img = mi.render(scene, spp=1, seed=1)
dr.eval(img)
dr.sync_thread()
secs = time.perf_counter() - start
depth = img.numpy()[..., -1]
print(json.dumps({'seconds': secs, 'mrays_per_s': width * height / secs / 1e6,
                  'hit': float((depth > 0).mean())}))

"""Mitsuba 3's path tracer on its built-in Cornell box, for the homework-6 speed figures.

Usage: mitsuba_cornell_path.py VARIANT SPP [THREADS] [RES]

Renders mi.cornell_box() (walls, a ceiling area light, two boxes) at RES x RES with the `path`
integrator (max_depth 5: up to 4 bounces, next-event estimation and BSDF sampling with MIS,
Russian roulette off) and prints one JSON line: wall seconds of the render (after a warm-up
render that compiles kernels) and Msamples/s. The scene is comparable in size and lighting to
cornellbox_jaroslav_path_diffuse, not identical.
"""
import json
import sys
import time

import drjit as dr
import mitsuba as mi

variant, spp = sys.argv[1], int(sys.argv[2])
threads = int(sys.argv[3]) if len(sys.argv) > 3 else 1
res = int(sys.argv[4]) if len(sys.argv) > 4 else 512
mi.set_variant(variant)
dr.set_thread_count(threads)
scene_dict = mi.cornell_box()
scene_dict["sensor"]["film"]["width"] = res
scene_dict["sensor"]["film"]["height"] = res
scene_dict["integrator"] = {"type": "path", "max_depth": 5, "rr_depth": 1000}
scene = mi.load_dict(scene_dict)
img = mi.render(scene, spp=1)
dr.eval(img)
start = time.perf_counter()
img = mi.render(scene, spp=spp, seed=1)
dr.eval(img)
dr.sync_thread()
secs = time.perf_counter() - start
print(json.dumps({"variant": variant, "spp": spp, "threads": threads, "seconds": secs,
                  "msamples_per_s": res * res * spp / secs / 1e6}))

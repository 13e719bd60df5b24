#!/usr/bin/env python3
"""Writes scenes/orbit/orbit_00.xml ... orbit_23.xml: the tori scene (scenes/tori.xml) with its
camera orbiting the torus once in 24 frames at 240x150, one scene file a frame, all naming the
same PLY (scenes/ply/torus.ply): a small animation for the farm's sequences
(`tessera submit scenes/orbit/orbit_*.xml --wait --out orbit/` leaves the frames and
orbit/video.mp4). Standard library only."""

import math
import os
import re

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.dirname(HERE)
FRAMES = 24


def main():
    base = open(os.path.join(SCENES, "tori.xml")).read()
    # The header comment says what the original shows; this file says what it is.
    body = base[base.index("<Scene>"):]
    body = body.replace('plyFile="ply/torus.ply"', 'plyFile="../ply/torus.ply"')
    body = body.replace("<ImageResolution>640 400</ImageResolution>", "<ImageResolution>240 150</ImageResolution>")
    out = os.path.join(SCENES, "orbit")
    os.makedirs(out, exist_ok=True)
    for k in range(FRAMES):
        a = 2 * math.pi * k / FRAMES
        x, z = 7.5 * math.sin(a), 7.5 * math.cos(a)
        frame = re.sub(r"<Position>0 3.2 7.5</Position>", f"<Position>{x:.4f} 3.2 {z:.4f}</Position>", body, count=1)
        frame = frame.replace("<ImageName>tori.png</ImageName>", f"<ImageName>orbit_{k:02d}.png</ImageName>")
        header = (
            f"<!-- Tessera demo animation, frame {k + 1} of {FRAMES}: scenes/tori.xml seen from a camera orbiting\n"
            f"     the torus. Written by scenes/tools/gen_orbit.py. -->\n"
        )
        with open(os.path.join(out, f"orbit_{k:02d}.xml"), "w") as f:
            f.write(header + frame)


if __name__ == "__main__":
    main()

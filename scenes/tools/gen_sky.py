#!/usr/bin/env python3
"""Writes scenes/textures/sky.hdr, the environment map of scenes/environment.xml.

A 256x128 latitude-longitude panorama (row 0 = straight up, the middle column looks along -Z,
the convention of scene-format.md section 5.6): a blue sky brightening towards the horizon, a
warm grey ground below it, and a small sun (radius 2.5 degrees, 40 degrees above the horizon,
30 degrees to the right of -Z) about 4000 times brighter than the sky, so the light has a
strong direction and importance sampling has something to find.

Radiance RGBE, flat (uncompressed) scanlines. Python 3 standard library only; deterministic.
Run from the repository root: python3 scenes/tools/gen_sky.py
"""
import math
import pathlib

W, H = 256, 128
SUN_ELEVATION = math.radians(40.0)
SUN_AZIMUTH = math.radians(30.0)  # from -Z towards +X
SUN_RADIUS = math.radians(2.5)
SUN = (4000.0, 3600.0, 3000.0)


def direction(u, v):
    theta, phi = v * math.pi, (u - 0.5) * 2.0 * math.pi
    return (math.sin(theta) * math.sin(phi), math.cos(theta), -math.sin(theta) * math.cos(phi))


def radiance(d):
    sun = (
        math.cos(SUN_ELEVATION) * math.sin(SUN_AZIMUTH),
        math.sin(SUN_ELEVATION),
        -math.cos(SUN_ELEVATION) * math.cos(SUN_AZIMUTH),
    )
    cos_sun = sum(a * b for a, b in zip(d, sun))
    if cos_sun > math.cos(SUN_RADIUS):
        return SUN
    y = d[1]
    if y >= 0.0:
        t = 1.0 - y  # 0 at the zenith, 1 at the horizon
        base = (0.25 + 0.75 * t ** 3, 0.45 + 0.5 * t ** 3, 1.0)
        glow = 0.6 * max(cos_sun, 0.0) ** 16  # haze around the sun
        return tuple(c + glow for c in base)
    return (0.30, 0.26, 0.22)


def rgbe(c):
    m = max(c)
    if m < 1e-32:
        return bytes(4)
    e = math.frexp(m)[1]
    scale = 256.0 / 2.0 ** e
    return bytes([min(255, int(x * scale)) for x in c] + [e + 128])


def main():
    out = pathlib.Path(__file__).resolve().parent.parent / "textures" / "sky.hdr"
    body = bytearray()
    for y in range(H):
        for x in range(W):
            body += rgbe(radiance(direction((x + 0.5) / W, (y + 0.5) / H)))
    header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (H, W)
    out.write_bytes(header + bytes(body))
    print(f"wrote {out} ({W}x{H})")


if __name__ == "__main__":
    main()

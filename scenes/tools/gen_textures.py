#!/usr/bin/env python3
"""Writes the texture assets of scenes/textures.xml into scenes/textures/:

* tiles.png   64x64 8-bit RGB: a 4x4 grid of glazed tiles in eight colours with light grout,
              each tile with a soft highlight towards its top-left corner and a diagonal stripe,
              so orientation (u to the right, v down) is visible in the render.
* bumps.png   64x64 8-bit RGB normal map: a 4x4 grid of rounded domes (one per 16x16 cell)
              on a flat base, stored as RGB = (n + 1) / 2 * 255 in tangent space (x along u,
              y along v, z out of the surface): blue-dominant.

Python 3 standard library only (zlib + struct write the PNGs). The output is deterministic.
Run from the repository root: python3 scenes/tools/gen_textures.py
"""
import math
import pathlib
import struct
import zlib

SIZE = 64
CELLS = 4  # tiles / domes per side
CELL = SIZE // CELLS


def png_rgb8(width, height, rows):
    """A PNG (8-bit RGB, filter 0 on every row) from `rows`: height lists of width (r, g, b)."""

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    raw = bytearray()
    for row in rows:
        raw.append(0)
        for r, g, b in row:
            raw += bytes((r, g, b))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(bytes(raw), 9))
        + chunk(b"IEND", b"")
    )


def clamp8(x):
    return max(0, min(255, int(round(x))))


# Tile colours (sRGB-ish 0..255), chosen to stay readable under diffuse lighting.
PALETTE = [
    (214, 96, 64),   # terracotta
    (64, 132, 196),  # cobalt
    (232, 186, 72),  # ochre
    (74, 160, 110),  # jade
    (150, 88, 170),  # violet
    (60, 170, 178),  # teal
    (224, 128, 150), # rose
    (112, 128, 64),  # olive
]
GROUT = (226, 220, 204)


def tiles():
    rows = []
    for y in range(SIZE):
        row = []
        for x in range(SIZE):
            cx, cy = x // CELL, y // CELL
            lx, ly = x % CELL, y % CELL
            if lx == 0 or ly == 0:
                row.append(GROUT)
                continue
            base = PALETTE[(cx + 3 * cy) % len(PALETTE)]
            # Soft highlight from the top-left corner of each tile, darker towards bottom-right.
            t = (lx + ly) / (2.0 * (CELL - 1))
            shade = 1.12 - 0.3 * t
            # A lighter diagonal stripe across each tile (top-left to bottom-right).
            if abs(lx - ly) <= 1:
                shade += 0.18
            row.append(tuple(clamp8(c * shade) for c in base))
        rows.append(row)
    return rows


def bumps():
    rows = []
    radius = CELL * 0.42
    for y in range(SIZE):
        row = []
        for x in range(SIZE):
            # Offset from the centre of this cell, in texels (texel centres at +0.5).
            dx = (x % CELL) + 0.5 - CELL / 2
            dy = (y % CELL) + 0.5 - CELL / 2
            rho = math.hypot(dx, dy) / radius
            if rho < 1.0:
                # A dome h = H (1 - rho^2)^2: smooth at its rim, normal = normalize(-dh/dx, -dh/dy, 1).
                height = 5.0
                k = -4.0 * height * (1.0 - rho * rho) / (radius * radius)
                gx, gy = k * dx, k * dy
                n = (-gx, -gy, 1.0)
            else:
                n = (0.0, 0.0, 1.0)
            length = math.sqrt(sum(c * c for c in n))
            row.append(tuple(clamp8((c / length + 1.0) / 2.0 * 255.0) for c in n))
        rows.append(row)
    return rows


def main():
    out = pathlib.Path(__file__).resolve().parent.parent / "textures"
    out.mkdir(parents=True, exist_ok=True)
    for name, rows in (("tiles.png", tiles()), ("bumps.png", bumps())):
        data = png_rgb8(SIZE, SIZE, rows)
        (out / name).write_bytes(data)
        print(f"wrote {out / name} ({len(data)} bytes)")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""A depth camera's view of a box on a table, made without palpate's code: rays cast from a
pinhole camera (OpenCV axes: x right, y down, z forward; pixel (u, v) centred at integer
coordinates; depth = the point's z in the camera, not its range) against the box's six
planes and a table plane, analytically (slab test), with a sensor's faults: noise whose
standard deviation grows with depth (sigma = a + b z^2), pixels dropped where the surface is
seen at a grazing angle, and mixed ("flying") pixels at depth edges, averaged between the two
sides. The 16-bit PNG is written by hand (zlib + CRC from the standard library), so palpate's
PNG reader is checked against a writer it did not share.

    python3 tests/generators/render_depth.py -o tests/data/depth-box

writes depth.png (unit 0.1 mm) and camera.json (intrinsics, pose as camera-to-box rotation
columns and camera centre, the box, the table, the noise model, the unit).
"""
import argparse
import json
import os
import struct
import zlib

import numpy as np


def png16(path, img):
    """A 16-bit greyscale PNG, rows filtered with filter type 0 (none)."""
    h, w = img.shape
    raw = b"".join(b"\x00" + img[r].astype(">u2").tobytes() for r in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 9)))
        f.write(chunk(b"IEND", b""))


def look_at(eye, target, up):
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)  # columns: camera axes in the box frame


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("-o", "--out", required=True)
    ap.add_argument("--seed", type=int, default=4)
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)

    width, height = 160, 120
    fx, fy, cx, cy = 300.0, 305.0, 80.3, 59.1
    box_lo, box_hi = np.array([0.0, 0.0, 0.0]), np.array([0.10, 0.04, 0.02])
    table_z = -0.01  # a table 1 cm under the box (it stands on a post)
    eye, target = np.array([0.22, 0.17, 0.26]), np.array([0.05, 0.02, 0.01])
    rot = look_at(eye, target, np.array([0.0, 0.0, 1.0]))
    sigma_a, sigma_b = 2e-4, 1e-3  # m, 1/m: 0.33 mm at 0.4 m
    unit = 1e-4

    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    d_cam = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)  # z = 1
    d = d_cam @ rot.T  # ray direction in the box frame, scaled so its camera z is 1

    # Slab test against the box: t is the camera depth directly (d has unit camera z).
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (box_lo - eye) / d
        t2 = (box_hi - eye) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit_box = (tmax >= tmin) & (tmin > 0)
    # The face the ray enters by: its normal, for the grazing-angle dropout.
    axis = np.argmax(np.minimum(t1, t2), axis=-1)
    normal = np.zeros_like(d)
    for k in range(3):
        sel = axis == k
        normal[sel, k] = -np.sign(d[sel, k])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = (table_z - eye[2]) / d[..., 2]
    hit_table = t_table > 0
    depth = np.where(hit_box, tmin, np.where(hit_table, t_table, 0.0))
    obj = hit_box.copy()

    # Grazing angle: the sensor loses the return where the surface turns away from the ray.
    ray = d / np.linalg.norm(d, axis=-1, keepdims=True)
    cos = np.abs(np.sum(ray * normal, axis=-1))
    depth[obj & (cos < 0.15)] = 0.0

    # Flying pixels: where the depth jumps by more than 5 mm to a neighbour, the sensor returns a
    # mix of both sides.
    flying = np.zeros_like(obj)
    mixed = depth.copy()
    for dv, du in [(0, 1), (1, 0), (0, -1), (-1, 0)]:
        nb = np.roll(np.roll(depth, dv, axis=0), du, axis=1)
        jump = (np.abs(nb - depth) > 5e-3) & (nb > 0) & (depth > 0) & ~flying
        w = rng.uniform(0.2, 0.8, size=depth.shape)
        mixed = np.where(jump & (rng.uniform(size=depth.shape) < 0.5), w * depth + (1 - w) * nb, mixed)
        flying |= jump
    depth = mixed

    sigma = sigma_a + sigma_b * depth**2
    noisy = np.where(depth > 0, depth + sigma * rng.standard_normal(depth.shape), 0.0)
    img = np.round(noisy / unit).astype(np.int64)
    assert img.max() < 65536
    os.makedirs(a.out, exist_ok=True)
    png16(os.path.join(a.out, "depth.png"), img.astype(np.uint16))
    meta = {
        "generator": "tests/generators/render_depth.py",
        "seed": a.seed,
        "width": width,
        "height": height,
        "fx": fx, "fy": fy, "cx": cx, "cy": cy,
        "rotation_columns": rot.T.tolist(),
        "camera_centre": eye.tolist(),
        "unit_m": unit,
        "box_lo": box_lo.tolist(),
        "box_hi": box_hi.tolist(),
        "table_z": table_z,
        "sigma_a_m": sigma_a,
        "sigma_b_per_m": sigma_b,
        "box_pixels": int(np.sum(obj & (depth > 0))),
        "flying_pixels": int(np.sum(flying)),
    }
    with open(os.path.join(a.out, "camera.json"), "w") as f:
        json.dump(meta, f, indent=1)
    print(json.dumps({k: meta[k] for k in ("box_pixels", "flying_pixels")}))


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Nearest-neighbour spacing of one material's particles in `physketch run --export particles`
frames (binary PLY: x y z vx vy vz as float, body material stroke as int), in particle spacings h.

    python3 scripts/particle_spacing.py H MATERIAL FRAME.ply [FRAME.ply ...]

prints, per frame, the particle count, the median and tenth-percentile distance to the nearest
other particle of that material, and the highest one's height, in units of H (the voxel size:
workspace edge / 151). Standard library only (a hash of cells of 2 H, brute force within 27)."""
import collections
import math
import struct
import sys


def load(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    count = int(next(l for l in header.split("\n") if l.startswith("element vertex")).split()[2])
    record = struct.Struct("<6f3i")
    return [record.unpack_from(data, end + k * record.size) for k in range(count)]


def spacing(path, h, material):
    points = [p for p in load(path) if p[7] == material]
    cell = 2.0 * h
    grid = collections.defaultdict(list)
    key = lambda p: (int(p[0] // cell), int(p[1] // cell), int(p[2] // cell))
    for i, p in enumerate(points):
        grid[key(p)].append(i)
    nearest = []
    for i, p in enumerate(points):
        cx, cy, cz = key(p)
        best = math.inf
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for j in grid.get((cx + dx, cy + dy, cz + dz), ()):
                        if j != i:
                            q = points[j]
                            best = min(best, (p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 + (p[2] - q[2]) ** 2)
        nearest.append(math.sqrt(best) / h if best < math.inf else math.inf)
    nearest.sort()
    top = max(p[1] for p in points) / h
    return len(points), nearest[len(nearest) // 2], nearest[len(nearest) // 10], top


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    h, material = float(sys.argv[1]), int(sys.argv[2])
    for path in sys.argv[3:]:
        n, median, tenth, top = spacing(path, h, material)
        print(f"{path}: {n} particles, nearest neighbour median {median:.3f} h, tenth percentile {tenth:.3f} h, "
              f"top {top:.2f} h")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Cross-checks `octolod metro` against MeshLab's Hausdorff filter (pymeshlab).

Usage (from the repository root; installs pymeshlab into a venv on first use):

    tools/metro-crosscheck.sh [--samples N] [--pairs quick|full]

For a few generated pairs (an original mesh and a simplified level of it),
both tools sample the same number of points per direction, with vertex, edge
and face sampling on, in both directions. Acceptance (issue 4): mean and RMS
agree within 2 %, max within 5 %. Exits non-zero if any pair disagrees.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import pymeshlab

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release")


def run(*args):
    return subprocess.run(args, check=True, capture_output=True, text=True).stdout


def meshlab(a, b, samples):
    """One-directional distances a -> b with vertex+edge+face sampling."""
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(a)
    ms.load_new_mesh(b)
    r = ms.get_hausdorff_distance(
        sampledmesh=0, targetmesh=1, samplevert=True, sampleedge=True, sampleface=True,
        samplenum=samples, maxdist=pymeshlab.PercentageValue(100.0))
    return {"max": r["max"], "mean": r["mean"], "rms": r["RMS"], "samples": r["n_samples"]}


def octolod(a, b, samples):
    out = json.loads(run(os.path.join(BIN, "octolod"), "metro", a, b, "--samples", str(samples), "--json", "--quiet"))
    return out


def pick(d, *keys):
    for k in keys:
        if k in d:
            return d[k]
    raise KeyError(f"none of {keys} in {sorted(d)}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--pairs", choices=["quick", "full"], default="quick")
    args = ap.parse_args()
    pairs = [("sphere", 200_000, ["--normals"]), ("terrain", 200_000, [])]
    if args.pairs == "full":
        pairs += [("instances", 300_000, []), ("open", 200_000, [])]
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        print(f"{'pair':<22} {'dir':<5} {'metric':<5} {'octolod':>12} {'meshlab':>12} {'diff %':>8} {'limit %':>8}")
        for shape, tris, extra in pairs:
            src = os.path.join(tmp, f"{shape}.ply")
            run(os.path.join(BIN, "octolod-gen"), "--shape", shape, "--tris", str(tris), "-o", src, "--quiet", *extra)
            for target in (tris // 10, tris // 50):
                dst = os.path.join(tmp, f"{shape}-{target}.ply")
                run(os.path.join(BIN, "octolod"), "simplify", src, "-o", dst, "--target-tris", str(target),
                    "--leaf-tris", "4000", "--quiet")
                o = octolod(src, dst, args.samples)
                for direction, (a, b) in (("A->B", (src, dst)), ("B->A", (dst, src))):
                    mine = pick(o, "a_to_b" if direction == "A->B" else "b_to_a", direction)
                    ref = meshlab(a, b, args.samples)
                    for metric, limit in (("mean", 2.0), ("rms", 2.0), ("max", 5.0)):
                        x, y = float(mine[metric]), float(ref[metric])
                        diff = 100.0 * abs(x - y) / max(abs(y), 1e-300)
                        bad = diff > limit
                        ok &= not bad
                        print(f"{shape + '/' + str(target):<22} {direction:<5} {metric:<5} {x:>12.5e} {y:>12.5e} "
                              f"{diff:>8.2f} {limit:>8.1f}{'  FAIL' if bad else ''}")
    print("agreement: " + ("OK" if ok else "FAILED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

"""Per-vertex AO of the Stanford bunny, and AO at a few of its vertices from arrays.

    python examples/python/bake_bunny.py [MESH] [--samples N] [--device auto|gpu|cpu|NAME]

Loads scenes/bunny.obj (or MESH), bakes AO at every vertex about its area-weighted
normal and prints the values' statistics, then renders a small view of the same scene
(the BVH built for the bake is reused).
"""

import argparse
import pathlib
import time

import numpy as np

import aorender

REPO = pathlib.Path(__file__).resolve().parents[2]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default=REPO / "scenes" / "bunny.obj", type=pathlib.Path)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()

    scene = aorender.Scene.load(args.mesh)
    start = time.perf_counter()
    ao, err = scene.bake(args.samples, device=args.device)
    seconds = time.perf_counter() - start
    print(f"{scene.name}: {scene.triangles} triangles, {len(ao)} vertices × {args.samples} samples "
          f"in {seconds:.2f} s (BVH build included)")
    q = np.percentile(ao, [0, 5, 25, 50, 75, 95, 100])
    print(f"AO mean {ao.mean():.4f}; min/5/25/50/75/95%/max " + " ".join(f"{v:.3f}" for v in q))
    print(f"standard error: mean {err.mean():.4f}, max {err.max():.4f}")
    print(f"fully open vertices (AO = 1): {np.count_nonzero(ao == 1.0)}")

    darkest = np.argsort(ao)[:5]
    print(f"darkest vertices: {darkest.tolist()} with AO {np.round(ao[darkest], 3).tolist()}")
    _, stats = scene.render(64, 64, 16, device=args.device)
    print(f"a 64×64 view at 16 spp: image mean {stats['image_mean']:.4f} on {stats['adapter']}")


if __name__ == "__main__":
    main()

"""A per-vertex bake split into shards of its samples on Ray tasks, merged exactly.

    python examples/python/ray_bake.py [MESH] [--samples N] [--shards K] [--out DIR] [--device cpu|gpu|auto]

Each Ray task bakes one range of the sample indices (`sample_range=(start, end)`) and
saves that shard's exact sums (`checkpoint=PATH`); the driver adds them up
(`merge=[PATH, ...]`) and writes the baked mesh. The sums are added exactly, so the
merged file holds the same bytes as the bake done in one piece: the script bakes that
too and compares them. On a cluster, put --out on storage every node reads.
"""

import argparse
import filecmp
import pathlib
import tempfile

import ray

import aorender

REPO = pathlib.Path(__file__).resolve().parents[2]


@ray.remote
def bake_shard(mesh, samples, start, end, checkpoint, device):
    """One shard: samples start..end of every vertex, its sums saved to `checkpoint`."""
    aorender.Scene.load(mesh).bake(samples, sample_range=(start, end), checkpoint=checkpoint, device=device)
    return checkpoint


def sample_ranges(samples, shards):
    """`shards` contiguous, non-empty ranges covering 0..samples."""
    shards = max(1, min(shards, samples))
    cuts = [samples * k // shards for k in range(shards + 1)]
    return list(zip(cuts[:-1], cuts[1:]))


def sharded_bake(mesh, output, samples, shards, work, device="cpu"):
    """Bakes `mesh` into `output` from `shards` Ray tasks; returns the shards' files."""
    mesh, work = pathlib.Path(mesh), pathlib.Path(work)
    tasks = [
        bake_shard.remote(str(mesh), samples, start, end, str(work / f"shard-{k}.ckpt"), device)
        for k, (start, end) in enumerate(sample_ranges(samples, shards))
    ]
    checkpoints = ray.get(tasks)
    aorender.Scene.load(mesh).bake(samples, merge=checkpoints, output=output, device=device)
    return checkpoints


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default=REPO / "scenes" / "bunny.obj", type=pathlib.Path)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--shards", type=int, default=4)
    parser.add_argument("--out", type=pathlib.Path, default=None)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()

    ray.init(num_cpus=max(2, args.shards), include_dashboard=False)
    work = args.out or pathlib.Path(tempfile.mkdtemp(prefix="aorender-ray-"))
    work.mkdir(parents=True, exist_ok=True)
    name = args.mesh.name.removesuffix(".gz")
    merged, whole = work / f"merged-{name}", work / f"whole-{name}"
    shards = sharded_bake(args.mesh, merged, args.samples, args.shards, work, args.device)
    aorender.Scene.load(args.mesh).bake(args.samples, output=whole, device=args.device)
    same = filecmp.cmp(merged, whole, shallow=False)
    print(f"{len(shards)} shards merged into {merged}; the bake in one piece: {whole}")
    print(f"byte for byte the same: {same}")
    raise SystemExit(0 if same else 1)


if __name__ == "__main__":
    main()

"""Ambient occlusion on the GPU (wgpu) or a CPU reference, from numpy arrays.

    ao, err = aorender.ambient_occlusion(V, F, P, N, samples=256)

    scene = aorender.Scene.from_arrays(V, F)      # or aorender.Scene.load("bunny.obj")
    ao, err = scene.ambient_occlusion(P, N)       # the BVH is built once per device
    image, stats = scene.render(512, 512, 64)
    ao_v, err_v = scene.bake(256)                 # per-vertex AO of the scene's meshes

AO is 1 where the hemisphere is fully open: the cosine-weighted visibility
1/π ∫ V cos θ dω. See `ambient_occlusion` for how this differs from libigl's.
"""

from ._aorender import Scene, __version__, ambient_occlusion

__all__ = ["Scene", "ambient_occlusion", "__version__"]

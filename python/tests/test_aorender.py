"""The Python module against closed forms, against the `aorender` command for the same
seed, and on bad input. Monte Carlo checks allow 4 standard errors; seeds are fixed."""

import json
import math
import os
import pathlib
import signal
import subprocess
import threading

import numpy as np
import pytest

import aorender


def plane(half=50.0):
    """A square in y = 0 facing up, ±half wide."""
    V = np.array([[-half, 0, -half], [half, 0, -half], [half, 0, half], [-half, 0, half]], float)
    F = np.array([[0, 2, 1], [0, 3, 2]])
    return V, F


def cube():
    """The closed cube [-1, 1]³, faces wound outward."""
    V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    F = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return V, F


SPHERE_SCENE = """
[camera]
type = "perspective"
eye = [0.0, 3.0, 6.0]
look_at = [0.0, 0.5, 0.0]
up = [0.0, 1.0, 0.0]
fov = 50.0

[[object]]
type = "sphere"
center = [0.0, 2.0, 0.0]
radius = 1.0

[[object]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
"""


@pytest.fixture(scope="module")
def sphere_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "sphere.toml"
    path.write_text(SPHERE_SCENE)
    return path


# Closed forms.


@pytest.mark.parametrize("device", ["cpu", "auto"])
def test_open_plane_is_exactly_one(device):
    V, F = plane()
    P = np.array([[0, 0, 0], [3.5, 0, -7.25], [-20, 0, 11]])
    N = np.tile([0.0, 2.0, 0.0], (3, 1))
    ao, err = aorender.ambient_occlusion(V, F, P, N, 256, device=device)
    assert ao.dtype == np.float64 and ao.shape == (3,)
    np.testing.assert_array_equal(ao, 1.0)
    np.testing.assert_array_equal(err, 0.0)


@pytest.mark.parametrize("device", ["cpu", "auto"])
def test_centre_of_a_closed_cube_is_exactly_zero(device):
    V, F = cube()
    N = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1], [1, 1, 1]], float)
    P = np.zeros_like(N)
    for hemisphere in ("cosine", "uniform"):
        ao, err = aorender.ambient_occlusion(V, F, P, N, 128, hemisphere=hemisphere, device=device)
        np.testing.assert_array_equal(ao, 0.0)
        np.testing.assert_array_equal(err, 0.0)


@pytest.mark.parametrize("hemisphere", ["cosine", "uniform"])
@pytest.mark.parametrize("device", ["cpu", "auto"])
def test_floor_under_a_sphere_matches_the_closed_form(sphere_scene, hemisphere, device):
    scene = aorender.Scene.load(sphere_scene)
    P = np.array([[0, 0, 0], [0.5, 0, 0.25], [1.0, 0, -1.0], [-2.0, 0, 0.5]])
    N = np.tile([0.0, 1.0, 0.0], (len(P), 1))
    ao, err = scene.ambient_occlusion(P, N, 8192, hemisphere=hemisphere, sampler="independent", seed=7, device=device)
    centre, r = np.array([0.0, 2.0, 0.0]), 1.0
    to_centre = centre - P
    d = np.linalg.norm(to_centre, axis=1)
    cos_beta = to_centre[:, 1] / d
    expected = 1 - cos_beta * (r / d) ** 2
    assert np.all(err > 0)
    assert np.all(np.abs(ao - expected) <= 4 * err), (ao, expected, err)


@pytest.mark.parametrize("device", ["cpu", "auto"])
def test_points_sampled_on_a_tilted_square_are_exactly_one(device):
    """Points computed on an open tilted square of small triangles away from the origin,
    in float64 and rounded to float32, sit just above or just under it; found on it,
    every one is fully open. Taken as exactly on a surface (surface_tolerance=0), those
    under it read 0 and are counted."""
    normal = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    t1 = np.cross(normal, [0.0, 0.0, 1.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    centre, n = np.full(3, 5.0), 40
    a, b = np.meshgrid(np.linspace(-0.5, 0.5, n + 1), np.linspace(-0.5, 0.5, n + 1), indexing="ij")
    V = centre + a.reshape(-1, 1) * t1 + b.reshape(-1, 1) * t2
    k = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).reshape(-1)
    F = np.vstack([np.stack([k, k + n + 1, k + n + 2], 1), np.stack([k, k + n + 2, k + 1], 1)])
    rng = np.random.default_rng(3)
    P = centre + rng.uniform(-0.45, 0.45, (200, 1)) * t1 + rng.uniform(-0.45, 0.45, (200, 1)) * t2
    off = P[:2] + 0.5 * normal
    N = np.tile(normal, (202, 1))
    with pytest.warns(UserWarning, match=r"2 of 202 points \(the first is P\[200\]\) lie on no surface"):
        ao, err = aorender.ambient_occlusion(V, F, np.vstack([P, off]), N, 64, device=device)
    np.testing.assert_array_equal(ao, 1.0)
    np.testing.assert_array_equal(err, 0.0)
    with pytest.warns(UserWarning, match="lie on no surface"):
        exact, _ = aorender.ambient_occlusion(V, F, P, N[:200], 64, surface_tolerance=0.0, device=device)
    assert np.any(exact < 0.5), "no sampled point lies under the square: the control is void"


def test_convex_mesh_bakes_to_exactly_one():
    scene = aorender.Scene.from_arrays(*cube())
    ao, err = scene.bake(64, device="cpu")
    assert ao.shape == (8,)
    np.testing.assert_array_equal(ao, 1.0)
    np.testing.assert_array_equal(err, 0.0)
    faces, _ = scene.bake(64, at="faces", device="cpu")
    np.testing.assert_array_equal(faces, np.ones(12))


def test_bake_gives_unused_vertices_one():
    V, F = plane()
    V = np.vstack([V, [[0, 5, 0]]])  # a vertex no face uses
    ao, err = aorender.Scene.from_arrays(V, F).bake(16, device="cpu")
    np.testing.assert_array_equal(ao, 1.0)
    np.testing.assert_array_equal(err, 0.0)


# The same numbers as the command.


def read_csv(text):
    rows = [line.split(",") for line in text.strip().splitlines()[1:]]
    return np.array([float(r[6]) for r in rows]), np.array([float(r[7]) for r in rows])


def probe_points():
    """Points on the bunny and on the aobench floor, exact in f32 and in decimal."""
    P = np.array([[0.0, 0.0, 0.0], [-0.25, 0.0625, 0.0], [0.03125, 0.125, 0.0], [0.0, 0.0625, 0.046875]])
    N = np.array([[0, 1, 0], [1, 0, 0], [0, 0.5, 0.5], [0, 0, 1]], float)
    return P, N


@pytest.mark.parametrize(
    "scene, sampler, hemisphere, seed",
    [("bunny.obj", "sobol", "cosine", 0), ("aobench.toml", "independent", "uniform", 12345)],
)
def test_probe_values_equal_the_command(cli, repo, tmp_path, scene, sampler, hemisphere, seed):
    P, N = probe_points()
    if scene == "aobench.toml":
        P = np.array([[0.0, -0.5, -2.0], [-1.0, -0.5, -3.0], [0.5, -0.5, -2.5]])
        N = np.tile([0.0, 1.0, 0.0], (3, 1))
    points = tmp_path / "points.txt"
    points.write_text("".join(" ".join(repr(float(x)) for x in (*p, *n)) + "\n" for p, n in zip(P, N)))
    cmd = [str(cli), "probe", str(repo / "scenes" / scene), "--points", str(points), "--samples", "1000",
           "--sampler", sampler, "--hemisphere", hemisphere, "--seed", str(seed), "--device", "cpu"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    want_ao, want_err = read_csv(done.stdout)
    ao, err = aorender.Scene.load(repo / "scenes" / scene).ambient_occlusion(
        P, N, 1000, sampler=sampler, hemisphere=hemisphere, seed=seed, device="cpu")
    np.testing.assert_array_equal(ao, want_ao)
    np.testing.assert_array_equal(err, want_err)
    assert np.all((ao >= 0) & (ao <= 1)) and len(set(ao)) > 1


def test_probe_values_equal_the_command_on_the_gpu(cli, repo, tmp_path, has_gpu):
    P = np.array([[0.0, -0.5, -2.0], [-1.0, -0.5, -3.0]])
    N = np.tile([0.0, 1.0, 0.0], (2, 1))
    points = tmp_path / "points.txt"
    points.write_text("0 -0.5 -2 0 1 0\n-1 -0.5 -3 0 1 0\n")
    cmd = [str(cli), "probe", str(repo / "scenes" / "aobench.toml"), "--points", str(points),
           "--samples", "512", "--sampler", "sobol", "--hemisphere", "cosine", "--seed", "3", "--device", "gpu"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    want_ao, want_err = read_csv(done.stdout)
    ao, err = aorender.Scene.load(repo / "scenes" / "aobench.toml").ambient_occlusion(
        P, N, 512, sampler="sobol", seed=3, device="gpu")
    np.testing.assert_array_equal(ao, want_ao)
    np.testing.assert_array_equal(err, want_err)


def read_pfm(path):
    data = path.read_bytes()
    header, rest = data.split(b"\n", 3)[:3], data.split(b"\n", 3)[3]
    assert header[0] == b"Pf" and float(header[2]) < 0
    w, h = map(int, header[1].split())
    return np.frombuffer(rest, dtype="<f4").reshape(h, w)[::-1]


def test_render_equals_the_command(cli, repo, tmp_path):
    out, stats_path = tmp_path / "ao.pfm", tmp_path / "stats.json"
    cmd = [str(cli), "render", str(repo / "scenes" / "aobench.toml"), "--width", "48", "--height", "32",
           "--spp", "16", "--sampler", "sobol", "--hemisphere", "cosine", "--seed", "5", "--device", "cpu",
           "-o", str(out), "--stats", str(stats_path)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    want = json.loads(stats_path.read_text())
    scene = aorender.Scene.load(repo / "scenes" / "aobench.toml")
    image, stats = scene.render(48, 32, 16, sampler="sobol", seed=5, device="cpu")
    assert image.shape == (32, 48) and image.dtype == np.float32
    np.testing.assert_array_equal(image, read_pfm(out))
    assert stats["image_mean"] == want["image_mean"]
    assert stats["samples_per_pixel"] == 16 and stats["width"] == 48 and stats["height"] == 32
    assert abs(float(image.mean(dtype=np.float64)) - stats["image_mean"]) < 1e-6
    # The command's fields, its phases included; the call itself opens, loads and writes nothing.
    assert set(stats) == set(want)
    for key in ("upload_seconds", "pipeline_seconds", "pass_seconds", "readback_seconds", "host_stats_seconds",
                "checkpoint_seconds"):
        assert math.isfinite(stats[key]) and stats[key] >= 0, key
    assert stats["pass_seconds"] > 0 and stats["readback_bytes"] == 0 and stats["checks"] == 0
    assert stats["write_seconds"] == 0 and stats["process_seconds"] is None and want["process_seconds"] > 0
    assert stats["host_peak_bytes_per_triangle"] is None and stats["host_peak_bytes_per_point"] is None


def test_render_camera_dict_overrides_keys():
    scene = aorender.Scene.from_arrays(*cube())
    image, _ = scene.render(16, 16, 4, camera={"eye": [0, 0, 10], "look_at": [0, 0, 0]}, device="cpu")
    assert image[8, 8] > 0  # the cube's face, in the middle
    assert image[0, 0] == 0  # background at the corner
    with pytest.raises(ValueError, match="unknown camera key 'position'"):
        scene.render(16, 16, 1, camera={"position": [0, 0, 1]}, device="cpu")


# Inputs: any dtype and order accepted, bad ones refused before any work.


def test_any_dtype_and_memory_order_give_the_same_values():
    V, F = cube()
    P = np.array([[0.0, 1.0, 0.0], [0.25, 1.0, 0.5]]) * [1, 1.5, 1]
    N = np.array([[0, 1, 0], [0, 1, 0]])
    ref = aorender.ambient_occlusion(V, F, P, N, 64, device="cpu")
    for args in [
        (V.astype(np.float32), F.astype(np.int32), P, N),
        (np.asfortranarray(V), np.asfortranarray(F.astype(np.uint16)), P.tolist(), N.astype(np.int8)),
        (V[::-1][::-1], F.T.copy().T, np.asfortranarray(P), N.astype(float)),
    ]:
        got = aorender.ambient_occlusion(*args, 64, device="cpu")
        np.testing.assert_array_equal(got[0], ref[0])


def test_session_is_reused_and_seeds_matter():
    scene = aorender.Scene.from_arrays(*plane())
    P = np.array([[0.0, 0.5, 0.0]])
    N = np.array([[1.0, -1.0, 0.0]])  # tilted towards the plane below
    a = scene.ambient_occlusion(P, N, 256, seed=1, sampler="independent", device="cpu")
    b = scene.ambient_occlusion(P, N, 256, seed=1, sampler="independent", device="cpu")
    c = scene.ambient_occlusion(P, N, 256, seed=2, sampler="independent", device="cpu")
    assert a[0][0] == b[0][0] and a[0][0] != c[0][0]
    assert 0 < a[0][0] < 1


BAD = [
    (dict(V=np.zeros((4, 2))), ValueError, r"V must be an \(n, 3\) array, got shape \(4, 2\)"),
    (dict(V=np.zeros(12)), ValueError, r"V must be an \(n, 3\) array, got shape \(12\)"),
    (dict(V=np.zeros((0, 3))), ValueError, "V is empty"),
    (dict(F=np.array([[0, 1, 4]])), ValueError, r"F\[0\] = \[0, 1, 4\]: index 4 is out of range for 4 vertices"),
    (dict(F=np.array([[0, -1, 2]])), ValueError, "index -1 is out of range"),
    (dict(F=np.array([[0.0, 1.0, 2.0]])), ValueError, "F must be an integer array"),
    (dict(V=np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 1], [0, 0, 1]])), ValueError, r"V\[2\] has a non-finite"),
    (dict(V=np.array([[0, 0, 0], [1e39, 0, 0], [0, 0, 1], [0, 0, 1]])), ValueError, "does not fit in 32-bit floats"),
    (dict(P=np.array([[0, 0, np.inf]])), ValueError, r"P\[0\] has a non-finite"),
    (dict(N=np.array([[0, 0, 0]])), ValueError, r"N\[0\] is not a usable normal"),
    (dict(N=np.array([[0, 1, 0], [0, 1, 0]])), ValueError, "P and N must have as many rows: P has 1, N has 2"),
    (dict(V=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])), ValueError, "no triangles of non-zero area"),
    (dict(samples=0), ValueError, "samples must be at least 1"),
    (dict(hemisphere="cos"), ValueError, "unknown hemisphere 'cos': expected one of 'uniform', 'cosine'"),
    (dict(sampler="halton"), ValueError, "unknown sampler 'halton'"),
    (dict(max_distance=-1.0), ValueError, "max_distance must be zero or positive"),
    (dict(surface_tolerance=-1.0), ValueError, "surface_tolerance must be a finite distance of at least 0, got -1"),
    (dict(surface_tolerance=float("nan")), ValueError, "surface_tolerance must be a finite distance of at least 0"),
    (dict(surface_tolerance=float("inf")), ValueError, "surface_tolerance must be a finite distance of at least 0"),
    (dict(device=""), ValueError, "device must be"),
    (dict(device="no-such-adapter-xyz"), RuntimeError, "no-such-adapter-xyz"),
    (dict(V=np.array([["a", "b", "c"]] * 4)), ValueError, "V must hold real numbers"),
]


@pytest.mark.parametrize("change, error, message", BAD, ids=[m for _, _, m in BAD])
def test_bad_input_raises_a_clear_error(change, error, message):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    args = dict(V=V, F=np.array([[0, 1, 2], [0, 2, 3]]), P=np.array([[0.2, 0.2, 0.5]]), N=np.array([[0, 0, 1.0]]))
    kwargs = dict(samples=8, device="cpu")
    for k, v in change.items():
        (args if k in args else kwargs)[k] = v
    with pytest.raises(error, match=message):
        aorender.ambient_occlusion(args["V"], args["F"], args["P"], args["N"], **kwargs)


def test_unreadable_files_raise_os_error(tmp_path):
    with pytest.raises(OSError, match="missing.obj"):
        aorender.Scene.load(tmp_path / "missing.obj")
    bad = tmp_path / "bad.toml"
    bad.write_text("[[object]]\ntype = 'cone'\n")
    with pytest.raises(OSError, match="bad.toml"):
        aorender.Scene.load(bad)


def test_read_budget_refuses_a_mesh_larger_than_it(repo):
    bunny = repo / "scenes" / "bunny.obj"
    with pytest.raises(OSError, match=r"bunny.obj: the mesh needs more than 1 MiB, the read budget \(as set"):
        aorender.Scene.load(bunny, read_budget=1 << 20)
    with pytest.raises(ValueError, match="read_budget"):
        aorender.Scene.load(bunny, read_budget=0)
    assert aorender.Scene.load(bunny, read_budget=1 << 30).triangles > 60000


def test_gltf_buffers_outside_the_folder_need_allow_external_uris(tmp_path):
    # A triangle whose buffer lies in the folder above the glTF file's.
    (tmp_path / "outside.bin").write_bytes(np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes())
    inner = tmp_path / "inner"
    inner.mkdir()
    doc = {
        "asset": {"version": "2.0"},
        "nodes": [{"mesh": 0}],
        "buffers": [{"uri": "../outside.bin", "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }
    (inner / "tri.gltf").write_text(json.dumps(doc))
    with pytest.raises(OSError, match=r'tri.gltf: buffer 0: the URI "../outside.bin" leads outside'):
        aorender.Scene.load(inner / "tri.gltf")
    scene = aorender.Scene.load(inner / "tri.gltf", allow_external_uris=True)
    assert scene.triangles == 1
    # Its bake reads the file again as it was allowed.
    ao, _ = scene.bake(4, device="cpu")
    assert len(ao) == 3


def test_bake_writes_the_file_like_the_command(repo, tmp_path):
    scene = aorender.Scene.load(repo / "scenes" / "bunny.obj")
    out = tmp_path / "bunny-ao.obj"
    ao, err = scene.bake(4, device="cpu", output=out)
    assert out.is_file() and len(ao) == len(err) > 30000
    assert 0 < ao.mean() < 1
    # Another format is written from the same trace.
    ao_ply, _ = scene.bake(4, device="cpu", output=tmp_path / "bunny.ply")
    assert (tmp_path / "bunny.ply").is_file() and (ao_ply == ao).all()
    with pytest.raises(ValueError, match="cannot bake into '.stl' files"):
        scene.bake(4, device="cpu", output=tmp_path / "bunny.stl")
    with pytest.raises(ValueError, match="no file to write back to"):
        aorender.Scene.from_arrays(*cube()).bake(4, device="cpu", output=out)


def test_bake_never_writes_over_a_file_it_reads_or_another_output(tmp_path):
    quad = "v 0 0 0\nv 1 0 0\nv 1 0 -1\nv 0 0 -1\nf 1 2 3\nf 1 3 4\n"
    for sub in ["a", "b"]:
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "x.obj").write_text(quad)
    scene = tmp_path / "two.toml"
    scene.write_text(
        '[camera]\ntype = "perspective"\neye = [0.0, 4.0, 8.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 45.0\n'
        '[[object]]\ntype = "mesh"\nfile = "a/x.obj"\n[[object]]\ntype = "mesh"\nfile = "b/x.obj"\n'
    )
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    loaded = aorender.Scene.load(scene)
    with pytest.raises(ValueError, match="the bake of object 2 \\(output\\) and the bake of object 1 \\(output\\) name the same file"):
        loaded.bake(4, device="cpu", output=tmp_path / "out")
    # A mesh of the scene, reached through a symbolic link to its directory.
    (tmp_path / "link").symlink_to(tmp_path / "a")
    single = tmp_path / "one.toml"
    single.write_text(scene.read_text().split("[[object]]")[0] + '[[object]]\ntype = "mesh"\nfile = "a/x.obj"\n')
    with pytest.raises(ValueError, match="would replace the input"):
        aorender.Scene.load(single).bake(4, device="cpu", output=tmp_path / "link")
    assert (tmp_path / "a" / "x.obj").read_text() == quad
    assert not (tmp_path / "out").exists()
    after = (p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert sorted(p for p in after if p.parts[0] not in ("link", "one.toml")) == before


def test_ctrl_c_stops_a_render_with_keyboard_interrupt(repo):
    scene = aorender.Scene.load(repo / "scenes" / "bunny.obj")
    scene.render(8, 8, 1, device="cpu")  # the BVH built before the clock starts
    timer = threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            scene.render(512, 512, 1 << 16, device="cpu")  # minutes if not stopped
    finally:
        timer.cancel()
    # The scene is still usable.
    image, stats = scene.render(8, 8, 1, device="cpu")
    assert stats["samples_per_pixel"] == 1


def test_cosine_weighted_ao_is_not_libigls_unweighted_visibility():
    """At the centre of the floor of an open cylinder of radius 1 and height 1 the wall
    blocks every direction below 45° elevation. The cosine-weighted AO this module
    returns (with either hemisphere) is sin²45° = 0.5; the unweighted visibility that
    1 − igl.embree.ambient_occlusion estimates is the solid-angle fraction above 45°,
    1 − cos 45° ≈ 0.293: the two conventions differ by far more than the noise."""
    k = 256
    t = np.linspace(0, 2 * math.pi, k, endpoint=False)
    ring0 = np.stack([np.cos(t), np.zeros(k), np.sin(t)], 1)
    ring1 = ring0 + [0, 1, 0]
    V = np.vstack([ring0, ring1])
    F = np.array([t for i in range(k) for t in ((i, (i + 1) % k, k + i), ((i + 1) % k, k + (i + 1) % k, k + i))])
    P, N = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]])
    for hemisphere in ("cosine", "uniform"):
        ao, err = aorender.ambient_occlusion(V, F, P, N, 1 << 14, hemisphere=hemisphere, sampler="independent",
                                             device="cpu")
        # 1e-3 for the 256-sided polygon standing in for the cylinder.
        assert abs(ao[0] - 0.5) <= 4 * err[0] + 1e-3, (hemisphere, ao, err)
        assert abs(ao[0] - (1 - math.cos(math.pi / 4))) > 20 * err[0]


def test_overcast_sky_at_the_floor_of_an_open_cylinder():
    """The floor's centre of an open cylinder of radius 1 and height 1 sees the sky within
    45° of the zenith: under the overcast sky E/E_h = 6/7 [sin²45°/2 + 2 (1 − cos³45°)/3]
    (docs/sampling.md), 0.584, against 0.5 under the uniform sky."""
    k = 256
    t = np.linspace(0, 2 * math.pi, k, endpoint=False)
    ring0 = np.stack([np.cos(t), np.zeros(k), np.sin(t)], 1)
    V = np.vstack([ring0, ring0 + [0, 1, 0]])
    F = np.array([t for i in range(k) for t in ((i, (i + 1) % k, k + i), ((i + 1) % k, k + (i + 1) % k, k + i))])
    P, N = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]])
    a = math.pi / 4
    expected = 6 / 7 * (math.sin(a) ** 2 / 2 + 2 * (1 - math.cos(a) ** 3) / 3)
    for sky in ("overcast", {"model": "overcast", "sampling": "control-variate", "up": (0, 2, 0)}):
        ao, err = aorender.ambient_occlusion(V, F, P, N, 1 << 14, sky=sky, device="cpu")
        # 1e-3 for the 256-sided polygon standing in for the cylinder.
        assert abs(ao[0] - expected) <= 4 * err[0] + 1e-3, (sky, ao, err)
        # Not the uniform sky's 0.5: 0.084 apart, about 18 standard errors at 2^14 samples.
        assert abs(ao[0] - 0.5) > 4 * err[0], (sky, ao, err)
    for bad, message in (("x", "unknown sky"), ({"model": "overcast", "up": (0, 0, 0)}, "up vector"),
                         ({"model": "overcast", "ground_albedo": 2.0}, "ground albedo"), ({"colour": 1}, "unknown sky key")):
        with pytest.raises(ValueError, match=message):
            aorender.ambient_occlusion(V, F, P, N, 16, sky=bad, device="cpu")


def test_bake_defaults_are_the_commands(cli, repo, tmp_path):
    """Scene.bake and `aorender bake` with their defaults (sampler, hemisphere, seed) trace the same samples."""
    out = tmp_path / "b.ply"
    cmd = [str(cli), "bake", str(repo / "scenes" / "dragon_vrip_res4.ply.gz"), "-o", str(out), "--samples", "8",
           "--device", "cpu"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    stats = json.loads(done.stdout)
    assert (stats["sampler"], stats["hemisphere"], stats["seed"]) == ("independent", "cosine", 0)
    ao, _ = aorender.Scene.load(repo / "scenes" / "dragon_vrip_res4.ply.gz").bake(8, device="cpu")
    assert len(ao) == stats["points"]
    traced_sum = ao.sum() - stats["points_without_normal"] * stats["unusable_value"]
    assert abs(traced_sum / stats["points_traced"] - stats["mean_ao"]) < 1e-6


def test_bake_mean_equals_the_command(cli, repo, tmp_path):
    stats_path = tmp_path / "stats.json"
    cmd = [str(cli), "bake", str(repo / "scenes" / "bunny.obj"), "-o", str(tmp_path / "b.obj"), "--samples", "16",
           "--sampler", "sobol", "--hemisphere", "cosine", "--seed", "9", "--device", "cpu", "--stats", str(stats_path)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    want = json.loads(stats_path.read_text())
    ao, _ = aorender.Scene.load(repo / "scenes" / "bunny.obj").bake(16, sampler="sobol", seed=9, device="cpu")
    assert len(ao) == want["points"]
    # The command's mean is over the traced points, in f64; the arrays hold f32 values and
    # 1 for each point without a normal.
    traced_sum = ao.sum() - want["points_without_normal"] * want["unusable_value"]
    assert abs(traced_sum / want["points_traced"] - want["mean_ao"]) < 1e-6


def test_replicates_give_sobol_a_valid_standard_error(sphere_scene):
    # Points on a floor under a sphere (AO 1 - cos beta (r/d)^2): in replicates, Sobol's
    # standard error is the spread of 64 replicates' means, below the spread of single
    # samples (which overestimates it), and the values agree with the closed form within
    # 5 of it (Student's t with 63 degrees of freedom: 1 in 100,000 per point). Under the
    # sphere's centre the occluded cone is a square of dyadic cells in the concentric map,
    # which every 16-point net integrates exactly: no spread, and the exact value.
    scene = aorender.Scene.load(sphere_scene)
    x = np.linspace(0.0, 2.5, 40)
    P = np.stack([x, np.zeros_like(x), 0.3 * x], axis=1)
    N = np.tile([0.0, 1.0, 0.0], (len(x), 1))
    _, se_one = scene.ambient_occlusion(P, N, 1024, sampler="sobol", seed=3, device="cpu")
    ao, se = scene.ambient_occlusion(P, N, 1024, sampler="sobol", replicate=16, seed=3, device="cpu")
    to_centre = np.array([0.0, 2.0, 0.0]) - P
    d = np.linalg.norm(to_centre, axis=1)
    expected = 1 - (to_centre[:, 1] / d) * (1.0 / d) ** 2
    assert np.all(se[1:] < se_one[1:]) and se[0] == 0.0, (se, se_one)
    assert np.all(np.abs(ao - expected) <= 5 * se + 1e-12), (ao, expected, se)
    with pytest.raises(ValueError, match="power of two"):
        scene.ambient_occlusion(P, N, 256, replicate=3, device="cpu")


def test_bake_writes_every_option_of_the_command(cli, repo, tmp_path):
    """Bent normals and standard errors into PLY, from Python and from the command: the
    same bytes."""
    mesh = repo / "scenes" / "dragon_vrip_res4.ply.gz"
    ours, theirs = tmp_path / "py.ply", tmp_path / "cli.ply"
    ao, err, bent = aorender.Scene.load(mesh).bake(
        8, device="cpu", output=ours, std_error=True, bent_normals=True, colors=True
    )
    subprocess.run(
        [str(cli), "bake", str(mesh), "-o", str(theirs), "--samples", "8", "--device", "cpu",
         "--std-error", "--bent-normals", "--colors"],
        check=True, capture_output=True,
    )
    assert ours.read_bytes() == theirs.read_bytes()
    assert bent.shape == (len(ao), 3) and len(err) == len(ao)
    used = err > 0
    assert np.allclose(np.linalg.norm(bent[used], axis=1), 1, atol=1e-5)


def test_texture_bake_writes_the_commands_files(cli, repo, tmp_path):
    mesh = repo / "scenes" / "bunny.obj"
    ours, theirs = tmp_path / "py" / "bunny.obj", tmp_path / "cli" / "bunny.obj"
    report = aorender.Scene.load(mesh).bake(4, device="cpu", output=ours, texture=128, bent_normals=True)
    subprocess.run(
        [str(cli), "bake", str(mesh), "-o", str(theirs), "--samples", "4", "--device", "cpu",
         "--texture", "128", "--bent-normals"],
        check=True, capture_output=True,
    )
    for name in ["bunny.obj", "bunny_ao.png", "bunny_bent_normals.png"]:
        assert (ours.parent / name).read_bytes() == (theirs.parent / name).read_bytes(), name
    assert report["width"] == 128 and report["maps"][0]["covered_texels"] > 0
    with pytest.raises(ValueError, match="sample_range"):
        aorender.Scene.load(mesh).bake(4, device="cpu", sample_range=(2, 9))


@pytest.fixture(scope="module")
def ray_module():
    """Ray, started locally with two CPUs; outside CI a missing Ray skips the test loudly."""
    if os.environ.get("CI"):
        import ray
    else:
        ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def test_ray_shards_merge_into_the_bake_in_one_piece(ray_module, repo, tmp_path):
    """The documented Ray example: a bake's sample ranges on Ray tasks, merged, give the
    bytes of the bake traced in one piece."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("ray_bake", repo / "examples" / "python" / "ray_bake.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    mesh = repo / "scenes" / "bunny.obj"
    merged, whole = tmp_path / "merged.obj", tmp_path / "whole.obj"
    shards = example.sharded_bake(mesh, merged, 12, 3, tmp_path, device="cpu")
    assert len(shards) == 3 and all(pathlib.Path(s).is_file() for s in shards)
    ao, _ = aorender.Scene.load(mesh).bake(12, output=whole, device="cpu")
    assert merged.read_bytes() == whole.read_bytes()
    # A shard alone is not the bake: the comparison can fail.
    part = tmp_path / "part.obj"
    aorender.Scene.load(mesh).bake(12, device="cpu", output=part, sample_range=(0, 4))
    assert part.read_bytes() != whole.read_bytes()
    with pytest.raises(ValueError, match="not all 0..12"):
        aorender.Scene.load(mesh).bake(12, device="cpu", merge=shards[:2], output=tmp_path / "short.obj")


def test_render_shards_merge_into_the_render_in_one_piece(repo, tmp_path):
    scene = aorender.Scene.load(repo / "scenes" / "bunny.obj")
    whole, _ = scene.render(24, 16, 8, device="cpu")
    shards = []
    for k, r in enumerate([(0, 3), (3, 8)]):
        path = tmp_path / f"render-{k}.ckpt"
        part, _ = scene.render(24, 16, 8, device="cpu", sample_range=r, checkpoint=path)
        assert not np.array_equal(part, whole)
        shards.append(path)
    merged, stats = scene.render(24, 16, 8, device="cpu", merge=shards)
    assert np.array_equal(merged, whole) and merged.dtype == whole.dtype
    assert stats["samples_per_pixel"] == 8 and stats["shards"] == 2
    with pytest.raises(ValueError, match="not all 0..8"):
        scene.render(24, 16, 8, device="cpu", merge=shards[1:])
    with pytest.raises(ValueError, match="another render"):
        scene.render(24, 16, 8, device="cpu", seed=3, merge=shards)

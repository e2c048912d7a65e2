"""Object SDFs (contact/sdf.py): every analytic geom against numpy references, the functions
compiled without the mesh branch against the full ones, a mesh box against the analytic box, and a
compound object as the union of its geoms."""

import numpy as np
import pytest
import trimesh
import warp as wp

from physhand_mj.contact import Objects
from physhand_mj.contact.sdf import geom_sdf, geom_sdf_analytic, geom_sdf_grad, geom_sdf_grad_analytic
from physhand_mj.types import GeomType


DEVICES = ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])
PHI_TOL = 2e-6  # m: float32 evaluation of distances of a few centimetres
GRAD_TOL = 2e-3  # unit-vector components vs numpy central differences


@wp.kernel
def _eval(gtype: int, size: wp.vec3, mesh: wp.vec2ul, p: wp.array(dtype=wp.vec3),
          phi: wp.array(dtype=float), grad: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    d, g = geom_sdf_grad(gtype, p[i], size, mesh)
    phi[i] = d
    grad[i] = g


def evaluate(gtype, size, points, mesh=0, device="cpu"):
    n = len(points)
    phi = wp.zeros(n, dtype=float, device=device)
    grad = wp.zeros(n, dtype=wp.vec3, device=device)
    wp.launch(_eval, n, inputs=[int(gtype), wp.vec3(*size), wp.vec2ul(int(mesh), 0),
                                wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device=device)],
              outputs=[phi, grad], device=device)
    return phi.numpy().astype(float), grad.numpy().astype(float)


def _seg_dist(w, a, b):
    ab = b - a
    t = np.clip(((w - a) @ ab) / (ab @ ab), 0, 1)
    return np.linalg.norm(w - (a + t[:, None] * ab), axis=1)


def ref_box(p, b):
    q = np.abs(p) - b
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def ref_cylinder(p, r, h):
    d = np.stack([np.hypot(p[:, 0], p[:, 1]) - r, np.abs(p[:, 2]) - h], 1)
    return np.minimum(d.max(axis=1), 0) + np.linalg.norm(np.maximum(d, 0), axis=1)


def ref_cone(p, r, h):
    """Distance to the profile segments (apex-rim, rim-base centre) in the (rho, z) half-plane."""
    w = np.stack([np.hypot(p[:, 0], p[:, 1]), p[:, 2]], 1)
    d = np.minimum(_seg_dist(w, np.array([0.0, 0.0]), np.array([r, -h])),
                   _seg_dist(w, np.array([r, -h]), np.array([0.0, -h])))
    inside = (w[:, 1] <= 0) & (w[:, 1] >= -h) & (w[:, 0] <= r * (-w[:, 1]) / h)
    return np.where(inside, -d, d)


REFS = {
    GeomType.PLANE: ((0, 0, 0), lambda p, s: p[:, 2]),
    GeomType.SPHERE: ((0.03, 0, 0), lambda p, s: np.linalg.norm(p, axis=1) - s[0]),
    GeomType.CAPSULE: ((0.02, 0.04, 0), lambda p, s: np.linalg.norm(
        p - np.stack([0 * p[:, 0], 0 * p[:, 0], np.clip(p[:, 2], -s[1], s[1])], 1), axis=1) - s[0]),
    GeomType.BOX: ((0.03, 0.02, 0.01), lambda p, s: ref_box(p, np.array(s))),
    GeomType.CYLINDER: ((0.03, 0.02, 0), lambda p, s: ref_cylinder(p, s[0], s[1])),
    GeomType.CONE: ((0.06, 0.1, 0), lambda p, s: ref_cone(p, s[0], s[1])),
}


def _points(rng, n=400, scale=0.08):
    p = rng.uniform(-scale, scale, size=(n, 3))
    near = rng.uniform(-1, 1, size=(n // 4, 3)) * 0.002 + np.array([0.03, 0.02, 0.01])  # near a box corner
    return np.concatenate([p, near])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("gtype", list(REFS))
def test_sdf_values_and_gradients_match_numpy(gtype, device):
    size, ref = REFS[gtype]
    rng = np.random.default_rng(int(gtype))
    p = _points(rng)
    if gtype == GeomType.CONE:
        p[:, 2] -= 0.04  # centre the samples on the cone's body
    phi, grad = evaluate(gtype, size, p, device=device)
    want = ref(p, size)
    assert np.abs(phi - want).max() < PHI_TOL, f"{gtype.name}: phi off by {np.abs(phi - want).max():.2e} m"
    assert (phi < 0).any() and (phi > 0).any(), "samples must cover inside and outside"
    # gradient vs central differences of the reference, away from the kinks of the distance field
    h = 1e-6
    fd = np.stack([(ref(p + h * e, size) - ref(p - h * e, size)) / (2 * h) for e in np.eye(3)], 1)
    smooth = np.abs(np.linalg.norm(fd, axis=1) - 1) < 1e-3
    for e in np.eye(3):  # a kink lies between p - h e and p + h e if the one-sided slopes differ
        left = (ref(p, size) - ref(p - h * e, size)) / h
        right = (ref(p + h * e, size) - ref(p, size)) / h
        smooth &= np.abs(left - right) < 1e-3
    assert smooth.sum() > 0.8 * len(p)
    err = np.abs(grad[smooth] - fd[smooth]).max()
    assert err < GRAD_TOL, f"{gtype.name}: gradient off by {err:.2e}"


@wp.kernel
def _eval_both(gtype: int, size: wp.vec3, mesh: wp.vec2ul, p: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=float)):
    i = wp.tid()
    d, g = geom_sdf_grad(gtype, p[i], size, mesh)
    da, ga = geom_sdf_grad_analytic(gtype, p[i], size, mesh)
    out[i, 0] = d - da
    out[i, 1] = wp.length(g - ga)
    out[i, 2] = geom_sdf(gtype, p[i], size, mesh) - geom_sdf_analytic(gtype, p[i], size, mesh)
    out[i, 3] = geom_sdf_analytic(gtype, p[i], size, mesh)
    out[i, 4] = da


def test_the_sdfs_without_the_mesh_branch_equal_the_full_ones():
    """sdf.geom_sdf_funcs(False), compiled into the CUDA decision points' kernel for scenes without
    a mesh geom: every analytic geom's phi and gradient bit for bit as the full functions give them,
    and a mesh geom reads FAR (where the full functions find it)."""
    from physhand_mj.contact.sdf import FAR

    rng = np.random.default_rng(3)
    # (on the CPU: the mesh geom's id is a CPU mesh's, which a CUDA kernel must not read)
    p = wp.array(_points(rng).astype(np.float32), dtype=wp.vec3, device="cpu")
    cases = [(t, REFS[t][0], 0) for t in REFS] + [(GeomType.ELLIPSOID, (0.03, 0.02, 0.01), 0)]
    box = trimesh.creation.box((0.02, 0.02, 0.02))
    objs = Objects("cpu", 1)
    objs.add(GeomType.MESH, None, vertices=box.vertices, faces=box.faces, name="block")
    cases.append((GeomType.MESH, objs._host["size"][0], objs._host["mesh"][0]))
    for gtype, size, mesh in cases:
        out = wp.zeros((p.shape[0], 5), dtype=float, device="cpu")
        wp.launch(_eval_both, p.shape[0], inputs=[int(gtype), wp.vec3(*size), wp.vec2ul(*[int(m) for m in np.resize(mesh, 2)]), p],
                  outputs=[out], device="cpu")
        o = out.numpy()
        if gtype == GeomType.MESH:
            assert np.all(o[:, 3] == FAR) and np.all(o[:, 4] == FAR)
            assert np.abs(o[:, 2]).min() > 1.0  # the full function measured the box (|phi| < 0.2 m)
        else:
            assert np.all(o[:, :3] == 0), gtype.name


def test_ellipsoid_sign_surface_and_sphere_case():
    radii = np.array([0.04, 0.025, 0.015])
    rng = np.random.default_rng(7)
    p = rng.uniform(-0.06, 0.06, size=(500, 3))
    phi, grad = evaluate(GeomType.ELLIPSOID, radii, p)
    inside = ((p / radii) ** 2).sum(axis=1) < 1
    assert np.array_equal(phi < 0, inside), "the sign must be exact"
    u = rng.normal(size=(200, 3))
    surface = u / np.linalg.norm(u / radii, axis=1, keepdims=True)  # points with (p/r)^2 sum = 1
    phi_s, grad_s = evaluate(GeomType.ELLIPSOID, radii, surface)
    assert np.abs(phi_s).max() < 1e-6, "the zero set must be the ellipsoid"
    normal = surface / radii ** 2
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    assert np.abs(grad_s - normal).max() < 1e-2, "gradient on the surface = the ellipsoid normal"
    phi_b, _ = evaluate(GeomType.ELLIPSOID, [0.03, 0.03, 0.03], p)
    assert np.abs(phi_b - (np.linalg.norm(p, axis=1) - 0.03)).max() < PHI_TOL, "exact for a sphere"


def test_mesh_sdf_matches_the_analytic_box():
    half = np.array([0.03, 0.02, 0.01])
    box = trimesh.creation.box(extents=2 * half)
    objs = Objects("cpu", 1)
    objs.add(GeomType.MESH, None, vertices=box.vertices, faces=box.faces, name="box_mesh", mesh_range=1.0)
    rng = np.random.default_rng(3)
    p = rng.uniform(-0.05, 0.05, size=(400, 3))
    phi, grad = evaluate(GeomType.MESH, objs._host["size"][0], p, mesh=int(objs._host["mesh"][0][0]))
    want = ref_box(p, half)
    assert np.abs(phi - want).max() < PHI_TOL
    outside = want > 1e-3
    box_phi, box_grad = evaluate(GeomType.BOX, half, p)
    assert np.abs(grad[outside] - box_grad[outside]).max() < 1e-4


def test_compound_object_is_the_union_of_its_geoms():
    from physhand_mj.contact.query import scene_phi, scene_phi_grad
    from physhand_mj.contact.sdf import GeomSet

    @wp.kernel
    def union(p: wp.array(dtype=wp.vec3), geoms: GeomSet, phi: wp.array(dtype=float), phi2: wp.array(dtype=float),
              grad: wp.array(dtype=wp.vec3)):
        i = wp.tid()
        phi[i] = scene_phi(p[i], geoms, geoms.count[0], -1)
        d, g, arg = scene_phi_grad(p[i], geoms, geoms.count[0], -1)
        phi2[i] = d
        grad[i] = g

    objs = Objects("cpu", 2)
    objs.add(GeomType.SPHERE, [0.02], pos=(-0.015, 0, 0), name="a", obj="dumbbell")
    objs.add(GeomType.BOX, [0.01, 0.01, 0.01], pos=(0.02, 0, 0), quat=(0.9238795, 0, 0, 0.3826834), name="b",
             obj="dumbbell")
    rng = np.random.default_rng(5)
    p = rng.uniform(-0.05, 0.05, size=(300, 3))
    n = len(p)
    phi, phi2, grad = (wp.zeros(n, dtype=float, device="cpu"), wp.zeros(n, dtype=float, device="cpu"),
                       wp.zeros(n, dtype=wp.vec3, device="cpu"))
    wp.launch(union, n, inputs=[wp.array(p.astype(np.float32), dtype=wp.vec3, device="cpu"), objs.geoms],
              outputs=[phi, phi2, grad], device="cpu")
    rot = np.array([[np.cos(np.pi / 4), -np.sin(np.pi / 4), 0], [np.sin(np.pi / 4), np.cos(np.pi / 4), 0], [0, 0, 1]])
    want = np.minimum(np.linalg.norm(p - [-0.015, 0, 0], axis=1) - 0.02,
                      ref_box((p - [0.02, 0, 0]) @ rot, np.array([0.01, 0.01, 0.01])))
    assert np.abs(phi.numpy() - want).max() < PHI_TOL
    assert np.abs(phi2.numpy() - want).max() < PHI_TOL
    assert np.allclose(np.linalg.norm(grad.numpy(), axis=1), 1, atol=1e-4)
    assert objs.object_names == ["dumbbell"]

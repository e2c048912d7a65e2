"""Signed distance functions of object geoms, as ``wp.func`` (paper section 3.3).

Every function takes a point in the geom's local frame and returns ``phi`` (m, negative inside);
``geom_sdf_grad`` adds the gradient (unit length where phi is differentiable). Exactness:

- plane, sphere, capsule, box, cylinder, cone: exact Euclidean distance, analytic gradients (box and
  cylinder pick one face's normal inside, where the distance has a kink; the cone's is the unit
  vector to its closest surface point);
- ellipsoid: Quilez's bound phi = k0 (k0 - 1) / k1 (k0 = |p / r|, k1 = |p / r^2|): exact sign and
  zero set, exact for a sphere, otherwise off by a factor between min(r)/max(r) and 1 away from
  the surface; gradient by central differences;
- mesh: an exact BVH closest-point query signed by the closest feature's pseudo normal, or by the
  generalised winding number for open meshes, with a distance grid for points far outside
  (:mod:`physhand_mj.contact.sdf_mesh`, whose docstring tells the details).
"""

import warp as wp

from physhand_mj.contact.sdf_mesh import FAR, GRID_BAND, grid_lower, grid_node, sdf_mesh_grad
from physhand_mj.types import GeomType

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

PLANE = wp.constant(int(GeomType.PLANE))
SPHERE = wp.constant(int(GeomType.SPHERE))
CAPSULE = wp.constant(int(GeomType.CAPSULE))
ELLIPSOID = wp.constant(int(GeomType.ELLIPSOID))
CYLINDER = wp.constant(int(GeomType.CYLINDER))
BOX = wp.constant(int(GeomType.BOX))
MESH = wp.constant(int(GeomType.MESH))
CONE = wp.constant(int(GeomType.CONE))
FD_STEP = wp.constant(1.0e-5)  # central-difference step for numerical gradients (m)


@wp.func
def sdf_sphere(p: wp.vec3, r: float):
    return wp.length(p) - r


@wp.func
def sdf_capsule(p: wp.vec3, r: float, half: float):
    return wp.length(p - wp.vec3(0.0, 0.0, wp.clamp(p[2], -half, half))) - r


@wp.func
def sdf_box(p: wp.vec3, b: wp.vec3):
    q = wp.vec3(wp.abs(p[0]) - b[0], wp.abs(p[1]) - b[1], wp.abs(p[2]) - b[2])
    outside = wp.vec3(wp.max(q[0], 0.0), wp.max(q[1], 0.0), wp.max(q[2], 0.0))
    return wp.length(outside) + wp.min(wp.max(q[0], wp.max(q[1], q[2])), 0.0)


@wp.func
def sdf_cylinder(p: wp.vec3, r: float, half: float):
    dx = wp.sqrt(p[0] * p[0] + p[1] * p[1]) - r
    dz = wp.abs(p[2]) - half
    ox = wp.max(dx, 0.0)
    oz = wp.max(dz, 0.0)
    return wp.min(wp.max(dx, dz), 0.0) + wp.sqrt(ox * ox + oz * oz)


@wp.func
def sdf_ellipsoid(p: wp.vec3, r: wp.vec3):
    k0 = wp.length(wp.cw_div(p, r))
    k1 = wp.length(wp.cw_div(p, wp.cw_mul(r, r)))
    if k1 < 1.0e-12:
        return -wp.min(r[0], wp.min(r[1], r[2]))
    return k0 * (k0 - 1.0) / k1


@wp.func
def sdf_cone_grad(p: wp.vec3, radius: float, height: float):
    """(phi, gradient) of the exact cone (Quilez), tip at the origin, axis +z, base disc of ``radius``
    at z = -height: in the (rho, z) half-plane the distance to the profile's two segments, signed;
    the gradient is sign(phi) times the unit vector from the closest surface point."""
    qx = radius
    qy = -height
    rho = wp.sqrt(p[0] * p[0] + p[1] * p[1])
    wy = p[2]
    t = wp.clamp((rho * qx + wy * qy) / (qx * qx + qy * qy), 0.0, 1.0)
    ax = rho - qx * t
    ay = wy - qy * t
    bx = rho - qx * wp.clamp(rho / qx, 0.0, 1.0)
    by = wy - qy
    da = ax * ax + ay * ay
    db = bx * bx + by * by
    vx = ax
    vy = ay
    d = da
    if db < da:
        vx = bx
        vy = by
        d = db
    sgn = wp.sign(wp.max(-(rho * qy - wy * qx), -(wy - qy)))
    n = wp.sqrt(d)
    radial = wp.vec3(1.0, 0.0, 0.0)
    if rho > 1.0e-12:
        radial = wp.vec3(p[0] / rho, p[1] / rho, 0.0)
    if n < 1.0e-12:  # on the surface: the side's outward normal
        g2 = wp.normalize(wp.vec2(height, radius))
        return 0.0, radial * g2[0] + wp.vec3(0.0, 0.0, g2[1])
    return n * sgn, (radial * vx + wp.vec3(0.0, 0.0, vy)) * (sgn / n)



@wp.func
def _axis_sign(x: float):
    if x < 0.0:
        return -1.0
    return 1.0


def geom_sdf_funcs(with_mesh: bool):
    """(:func:`geom_sdf`, :func:`geom_sdf_grad`) compiled with the MESH branch (``with_mesh``) or
    without it: a kernel for scenes of analytic geoms only (a mesh geom then reads FAR, as NONE does)
    leaves out the BVH walk's registers and stack (the CUDA decision points' kernel: 255 registers
    and a 640 B spill frame with it, 114 and none without; query_tiled.py). The same code otherwise,
    so the same answers for every other geom type."""

    @wp.func
    def geom_sdf(gtype: int, p: wp.vec3, size: wp.vec3, mesh: wp.vec2ul):
        """phi (m) of geom ``gtype`` of ``size`` at local point ``p``; FAR for NONE / no mesh hit."""
        if gtype == PLANE:
            return p[2]
        if gtype == SPHERE:
            return sdf_sphere(p, size[0])
        if gtype == CAPSULE:
            return sdf_capsule(p, size[0], size[1])
        if gtype == BOX:
            return sdf_box(p, size)
        if gtype == CYLINDER:
            return sdf_cylinder(p, size[0], size[1])
        if gtype == ELLIPSOID:
            return sdf_ellipsoid(p, size)
        if gtype == CONE:
            d, g = sdf_cone_grad(p, size[0], size[1])
            return d
        if wp.static(with_mesh):
            if gtype == MESH:
                if mesh[1] != wp.uint64(0):  # the grid's lower bound where it proves p far outside (module docstring)
                    dc, s = grid_node(mesh[1], p)
                    lb = grid_lower(dc, s)
                    if lb > GRID_BAND:
                        return lb
                d, g = sdf_mesh_grad(p, size, mesh)
                return d
        return FAR

    @wp.func
    def _fd_gradient(gtype: int, p: wp.vec3, size: wp.vec3, mesh: wp.vec2ul):
        h = FD_STEP
        gx = geom_sdf(gtype, p + wp.vec3(h, 0.0, 0.0), size, mesh) - geom_sdf(gtype, p - wp.vec3(h, 0.0, 0.0), size, mesh)
        gy = geom_sdf(gtype, p + wp.vec3(0.0, h, 0.0), size, mesh) - geom_sdf(gtype, p - wp.vec3(0.0, h, 0.0), size, mesh)
        gz = geom_sdf(gtype, p + wp.vec3(0.0, 0.0, h), size, mesh) - geom_sdf(gtype, p - wp.vec3(0.0, 0.0, h), size, mesh)
        g = wp.vec3(gx, gy, gz)
        n = wp.length(g)
        if n < 1.0e-12:
            return wp.vec3(0.0, 0.0, 1.0)
        return g / n

    @wp.func
    def geom_sdf_grad(gtype: int, p: wp.vec3, size: wp.vec3, mesh: wp.vec2ul):
        """(phi, unit gradient) at local point ``p``; the gradient is in the geom's local frame."""
        up = wp.vec3(0.0, 0.0, 1.0)
        if gtype == PLANE:
            return p[2], up
        if gtype == SPHERE:
            n = wp.length(p)
            if n < 1.0e-12:
                return -size[0], up
            return n - size[0], p / n
        if gtype == CAPSULE:
            q = p - wp.vec3(0.0, 0.0, wp.clamp(p[2], -size[1], size[1]))
            n = wp.length(q)
            if n < 1.0e-12:
                return -size[0], wp.vec3(1.0, 0.0, 0.0)
            return n - size[0], q / n
        if gtype == BOX:
            q = wp.vec3(wp.abs(p[0]) - size[0], wp.abs(p[1]) - size[1], wp.abs(p[2]) - size[2])
            s = wp.vec3(_axis_sign(p[0]), _axis_sign(p[1]), _axis_sign(p[2]))
            if q[0] > 0.0 or q[1] > 0.0 or q[2] > 0.0:
                o = wp.vec3(wp.max(q[0], 0.0), wp.max(q[1], 0.0), wp.max(q[2], 0.0))
                n = wp.length(o)
                return n, wp.cw_mul(o / n, s)
            if q[0] >= q[1] and q[0] >= q[2]:
                return q[0], wp.vec3(s[0], 0.0, 0.0)
            if q[1] >= q[2]:
                return q[1], wp.vec3(0.0, s[1], 0.0)
            return q[2], wp.vec3(0.0, 0.0, s[2])
        if gtype == CYLINDER:
            rho = wp.sqrt(p[0] * p[0] + p[1] * p[1])
            radial = wp.vec3(1.0, 0.0, 0.0)
            if rho > 1.0e-12:
                radial = wp.vec3(p[0] / rho, p[1] / rho, 0.0)
            axial = wp.vec3(0.0, 0.0, _axis_sign(p[2]))
            dx = rho - size[0]
            dz = wp.abs(p[2]) - size[1]
            if dx > 0.0 and dz > 0.0:
                n = wp.sqrt(dx * dx + dz * dz)
                return n, (radial * dx + axial * dz) / n
            if dx >= dz:
                return dx, radial
            return dz, axial
        if wp.static(with_mesh):
            if gtype == MESH:
                return sdf_mesh_grad(p, size, mesh)
        if gtype == CONE:
            return sdf_cone_grad(p, size[0], size[1])
        if gtype == ELLIPSOID:
            return geom_sdf(gtype, p, size, mesh), _fd_gradient(gtype, p, size, mesh)
        return FAR, up

    return geom_sdf, geom_sdf_grad


geom_sdf, geom_sdf_grad = geom_sdf_funcs(True)
geom_sdf_analytic, geom_sdf_grad_analytic = geom_sdf_funcs(False)  # (MESH reads FAR)


@wp.struct
class GeomSet:
    """The objects' per-geom arrays as one kernel argument (G = capacity; objects.Objects holds two,
    made once with its arrays: ``geoms``, the meshes with their distance grids, and ``geoms_exact``,
    without). A launch captures the arrays it holds, so a CUDA graph stays valid while Objects
    updates them in place.

    gtype (G,) int (GeomType), size (G,) vec3 (m), inv_pose (G,) transform (world -> geom frame),
    radius (G,) float (bounding radius, m), mesh (G,) vec2ul (wp.Mesh id, distance grid id or 0),
    obj (G,) int (object index), count (1,) int (geoms in use)."""

    gtype: wp.array(dtype=int)
    size: wp.array(dtype=wp.vec3)
    inv_pose: wp.array(dtype=wp.transform)
    radius: wp.array(dtype=float)
    mesh: wp.array(dtype=wp.vec2ul)
    obj: wp.array(dtype=int)
    count: wp.array(dtype=int)

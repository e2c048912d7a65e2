"""Newton's soft solvers (VBD and XPBD) as peers, on the GPU (measured on an H100: docs/peers.md).

    python benchmarks/peers/newton_gpu.py --device cuda [--solver vbd,xpbd] [--frames 8] [--out docs/benchmarks/peers_newton_cuda.json]

The same body (the hand's tet mesh through ``ModelBuilder.add_soft_mesh``: Lame parameters from
mujoco_flex's Young 30 kPa and the given Poisson ratio, density 1100 kg/m^3, skeleton vertices
pinned with mass 0) and the same objects on common.object_path (a kinematic body with the case's
sphere or mesh shape, its pose written every substep). Each 5 ms frame is ``substeps`` solver steps
(default 10, as physhand_mj). Timing excludes the first frame (kernel compilation); both measures
from common.Measure on the particle positions copied back after every frame (not timed).

Newton's API moves between releases; this targets newton 1.8 (``newton.ModelBuilder``,
``newton.solvers.SolverVBD`` / ``SolverXPBD``, ``newton.CollisionPipeline``). Where newton is missing, the
device is not CUDA, or a call fails, it says so in one line and exits 2: fix the call named there.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import FRAME_DT, Measure, cases, object_path, ph  # noqa: E402
from mujoco_flex import YOUNG  # noqa: E402
from run_cpu import KEYS, summary, table  # noqa: E402

from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.types import GeomType, Layer  # noqa: E402

import warp as wp  # noqa: E402  (physhand_mj's own dependency)


@wp.kernel
def _set_pose(body_q: wp.array(dtype=wp.transform), body: int, poses: wp.array(dtype=wp.transform), j: int):
    body_q[body] = poses[j]  # the kinematic object's pose at substep j (written, not integrated)


def fail(msg):
    print(msg, file=sys.stderr)
    sys.exit(2)


def build(newton, wp, asset, case, poisson, device):
    mu = YOUNG / (2 * (1 + poisson))
    lam = YOUNG * poisson / ((1 + poisson) * (1 - 2 * poisson))
    b = newton.ModelBuilder()
    b.add_soft_mesh(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
                    vertices=[wp.vec3(*p) for p in np.asarray(asset.positions, float)],
                    indices=np.asarray(asset.tets, int).ravel().tolist(), density=float(asset.density),
                    k_mu=mu, k_lambda=lam, k_damp=0.0)
    for i in np.flatnonzero(np.asarray(asset.layer) == Layer.SKELETON):
        b.particle_mass[i] = 0.0  # pinned, as physhand_mj's inverse mass 0
    _, quat, start = object_path(asset, case, 1)
    q = wp.quat(float(quat[1]), float(quat[2]), float(quat[3]), float(quat[0]))  # Warp order x y z w
    # a kinematic object (Newton's is_kinematic, no mass): its pose is written every substep and no
    # solver may push it away (a 4 g dynamic sphere was knocked off its path by Newton's XPBD in the
    # first H100 run, so the skin never met it)
    body = b.add_body(xform=wp.transform(wp.vec3(*start), q), is_kinematic=True)
    cfg = newton.ModelBuilder.ShapeConfig(density=0.0)
    if case.gtype == GeomType.SPHERE:
        b.add_shape_sphere(body, radius=float(case.size[0]), cfg=cfg)
    elif case.gtype == GeomType.MESH:
        b.add_shape_mesh(body, mesh=newton.Mesh(np.asarray(case.vertices, np.float32), np.asarray(case.faces, np.int32).ravel()),
                         cfg=cfg)
    else:
        raise ValueError(f"{case.gtype.name}: add a shape for it here")
    b.color()  # VBD needs a particle colouring
    return b.finalize(device=device), body


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--solver", default="vbd,xpbd")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--substeps", type=int, default=10)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--poisson", type=float, default=0.45)
    ap.add_argument("--start", type=float, default=0.0)
    ap.add_argument("--press-frames", type=int, default=6)
    ap.add_argument("--depth", type=float, default=0.003)
    ap.add_argument("--out", default="docs/benchmarks/peers_newton_cuda.json")
    ap.add_argument("--smoke", action="store_true", help="allow a CPU device: a check that the script runs, not a measurement")
    a = ap.parse_args()
    try:
        import newton
        import warp as wp
    except ImportError as e:
        fail(f"newton unavailable ({e}); pip install newton on a GPU machine")
    if not wp.get_device(a.device).is_cuda and not a.smoke:
        fail(f"device '{a.device}' is not a CUDA device; Newton's peers are measured on the GPU")
    asset = ph.load_asset()
    runs = []
    h = FRAME_DT / a.substeps
    for name in a.solver.split(","):
        for case in cases(a.depth, a.start, a.press_frames):
            try:
                model, body = build(newton, wp, asset, case, a.poisson, a.device)
                cls = {"vbd": newton.solvers.SolverVBD, "xpbd": newton.solvers.SolverXPBD}[name]
                # one kinematic object touches thousands of particles: a buffer that holds them all
                extra = {"rigid_body_particle_contact_buffer_size": 16384} if name == "vbd" else {}
                solver = cls(model, iterations=a.iterations, **extra)
                s0, s1, control = model.state(), model.state(), model.control()
            except Exception as e:  # an API change in newton: say which call
                fail(f"newton {name}: building the scene failed: {type(e).__name__}: {e}")
            path, quat, start = object_path(asset, case, a.frames)
            meas = Measure(asset, case)
            rows = {k: [] for k in KEYS}
            ms = []
            # Newton's own recipe (its examples): one CollisionPipeline and one Contacts buffer made once,
            # the object's pose written on the device by a kernel from a per-substep pose array, and
            # the frame (substeps x (pose, collide, step)) captured as one CUDA graph after the first
            # frame; with an even substep count the state swap ends where it began.
            pipeline = newton.CollisionPipeline(model)
            contacts = pipeline.contacts()
            poses = wp.zeros(a.substeps, dtype=wp.transform, device=a.device)
            states = [s0, s1]

            def frame():
                for j in range(a.substeps):
                    wp.launch(_set_pose, 1, inputs=[states[0].body_q, body, poses, j], device=a.device)
                    pipeline.collide(states[0], contacts)
                    solver.step(states[0], states[1], control, contacts, h)
                    states.reverse()

            graph = None
            use_graph = wp.get_device(a.device).is_cuda and a.substeps % 2 == 0
            for k in range(a.frames):
                p0 = start if k == 0 else path[k - 1]
                host = np.array([[*(p0 + (j + 1) / a.substeps * (path[k] - p0)), quat[1], quat[2], quat[3], quat[0]]
                                 for j in range(a.substeps)], np.float32)
                if k == 1 and use_graph:  # capture once the first frame compiled everything; a capture
                    # runs nothing, so the timed launch below is frame 1 itself
                    order = list(states)
                    try:
                        with wp.ScopedCapture(device=a.device) as cap:
                            frame()
                        graph = cap.graph
                    except Exception as e:  # a call that cannot be captured: time it eagerly, say so
                        states[:] = order  # the capture reversed the states without running anything
                        print(f"newton {name}: graph capture failed ({type(e).__name__}: {e}); eager frames",
                              file=sys.stderr)
                        use_graph = False
                wp.synchronize_device(a.device)
                t = time.perf_counter()
                poses.assign(wp.array(host, dtype=wp.transform, device="cpu"))
                if graph is not None:
                    wp.capture_launch(graph)
                else:
                    frame()
                wp.synchronize_device(a.device)
                ms.append((time.perf_counter() - t) * 1e3)
                for key, v in meas(states[0].particle_q.numpy(), path[k], quat).items():
                    rows[key].append(v)
            runs.append(dict(object=case.name, site=case.site, solver=f"newton {name}", graph=graph is not None,
                             **summary(rows, ms, skip=1)))
    result = dict(device=device_name(a.device), command="python benchmarks/peers/newton_gpu.py " + " ".join(sys.argv[1:]),
                  frames=a.frames, depth_mm=a.depth * 1e3, poisson=a.poisson, young_pa=YOUNG, runs=runs)
    Path(a.out).write_text(json.dumps(result, indent=1) + "\n")
    print(table(result))


if __name__ == "__main__":
    main()

"""Where a wide thin plate at the palm cuts the skin (issue 51): cross-sections of the skin, rest and
after the frames, through the band where the penetrating samples lie.

    python benchmarks/wall_sections.py [--frames 20,14] [--out docs/images/thin_wall_fold_sections.png]

Two ``bench.cases.wall_case`` plates (a 1 mm box plate face-first into the palm, CPU,
default Config): the 24 mm plate pressed 4 mm in from 2 mm outside over 10 frames and held, and the
30 mm plate 4 mm deep from the start (``test_wide_wall_deep_at_the_palm``). Each row: the skin
(black) cut by a plane across the plate through the penetrating samples' band, in the plate's frame
(+z into the hand; the plate at z = 0 in blue), at rest and after the frames, with the order-5 skin
samples inside the plate (red) and the skeleton's vertices near the plane (brown). Printed: each
case's last-frame counts by both measures and where its samples lie.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))


def section_lines(points: np.ndarray, faces: np.ndarray, x_cut: float) -> list:
    """The skin cut by the plane x = ``x_cut`` (plate frame, mm): a list of (2, 3) segments."""
    import trimesh

    return list(trimesh.intersections.mesh_plane(trimesh.Trimesh(points, faces, process=False), [1, 0, 0],
                                                 [x_cut, 0, 0]))


def run(case, frames: int) -> dict:
    import physhand_mj as ph
    from physhand_mj.bench.cases import case_frame, case_position, run_case
    from physhand_mj.rotations import quat_to_mat

    asset = ph.load_asset()
    r = run_case(case, ph.Config(device="cpu"), frames=frames, asset=asset)
    p0, n, quat = case_frame(case, asset)
    pos = case_position(case, p0, n, case.depth)
    rot = quat_to_mat(np.asarray(quat, float)[None])[0]
    to_plate = lambda p: (np.asarray(p, float) - pos) @ rot * 1e3  # (mm, plate frame)
    state, solver = r["state"], r["solver"]
    samples, _ = solver.contact.penetrating_samples(state, 5)
    inv = solver.model.inv_mass.numpy() == 0
    x = state.x.numpy().astype(float)
    return dict(case=case, frames=frames, rest=to_plate(solver.model.rest_x.numpy()), now=to_plate(x),
                bone=inv, samples=to_plate(samples) if len(samples) else np.zeros((0, 3)),
                counts=[int(r[k][-1]) for k in ("skin_count", "dense_count", "obj_count", "check_count")])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", default="20,14", help="frames of the pressed and the embedded case")
    ap.add_argument("--out", default="docs/images/thin_wall_fold_sections.png")
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import physhand_mj as ph

    faces = np.asarray(ph.load_asset().skin_faces)
    ns = int(ph.load_asset().n_skin)
    f_press, f_emb = (int(v) for v in a.frames.split(","))
    from physhand_mj.bench.cases import wall_case

    runs = [(run(wall_case(0.012, 0.001, 0.004, start=0.002), f_press), "24 mm plate pressed 4 mm in from 2 mm out, held"),
            (run(wall_case(0.015, 0.001, 0.004), f_emb), "30 mm plate 4 mm deep from the start")]
    fig, axes = plt.subplots(len(runs), 2, figsize=(13, 5.2 * len(runs)), squeeze=False)
    for row, (r, title) in zip(axes, runs):
        s = r["samples"]
        x_cut = float(np.median(s[:, 0])) if len(s) else 0.0
        print(f"{title}: last frame order-5 / order-9 samples, object / check points {r['counts']}; samples at "
              + (f"x {s[:, 0].min():.1f}..{s[:, 0].max():.1f}, y {s[:, 1].min():.1f}..{s[:, 1].max():.1f} mm (plate frame)"
                 if len(s) else "none"))
        h = r["case"].size[0] * 1e3
        for ax, pts, label in ((row[0], r["rest"], "rest"), (row[1], r["now"], f"after {r['frames']} frames")):
            for seg in section_lines(pts[:ns], faces, x_cut):
                ax.plot(seg[:, 1], seg[:, 2], "k-", lw=0.9)
            ax.add_patch(plt.Rectangle((-h, -0.5), 2 * h, 1.0, color="tab:blue", alpha=0.5))
            near = r["bone"] & (np.abs(pts[:, 0] - x_cut) < 1.0)
            ax.plot(pts[near, 1], pts[near, 2], ".", color="tab:brown", ms=2)
            if pts is r["now"] and len(s):
                band = np.abs(s[:, 0] - x_cut) < 1.0
                ax.plot(s[band, 1], s[band, 2], "r.", ms=4)
            ax.set_aspect("equal")
            ax.set_xlim(-22, 22)
            ax.set_ylim(16, -16)  # (+z into the hand: down)
            ax.set_xlabel("y (mm, plate frame)")
            ax.set_ylabel("z (mm): + into the hand")
            ax.set_title(f"{title}\n{label}, section x = {x_cut:.1f} mm", fontsize=9)
    fig.tight_layout()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=100)
    print("wrote", a.out)


if __name__ == "__main__":
    main()

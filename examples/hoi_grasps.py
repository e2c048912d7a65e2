"""The paper's HOI experiment (section 4.3, Table 2) on one or all seven scenes: a generated grasp
whose undeformed skin penetrates the object by a few millimetres, 36 frames of 10 substeps of the
soft hand, the penetration logged per substep.

Run:  python examples/hoi_grasps.py [OUT_DIR] [SCENE ...] [--contact vertex|opt|multires] [--device cuda]
      (SCENE: glass1 glass2 toothpaste phone apple bowl box; default all)
Success looks like: one line per scene with the initial penetration (mm deep) and the final one
(multires: 0 samples), and OUT_DIR/<scene>/ with log.csv, skin_final.ply, start.png (undeformed skin,
penetrating samples in magenta) and final.png (deformed skin).
"""

from pathlib import Path

import physhand_mj as ph
from physhand_mj import figures
from physhand_mj.build.hoi import SCENES
from physhand_mj.render import write_png
from physhand_mj.rollout import rollout


def picture(path: Path):
    return lambda hand, model, data: write_png(figures.render_grasp_view(model, data, hand), path)


def main(out: Path, scenes=tuple(SCENES), steps: int = 36, contact: str = "multires", device: str | None = None,
         pictures: bool = True) -> dict:
    results = {}
    print(f"{'scene':11s} {'initial count':>13s} {'max mm':>7s} {'final count':>11s} {'max um':>8s} {'ms/frame':>9s}")
    for name in scenes:
        d = out / name
        res = rollout(ph.scene_path(f"hoi_{name}"), "grasp", steps=steps, contact=contact, device=device, out=d,
                      progress=False, on_start=picture(d / "start.png") if pictures else None,
                      on_end=picture(d / "final.png") if pictures else None)
        results[name] = res
        print(f"{name:11s} {res['initial_penetration_count']:13d} {res['initial_penetration_max_um'] / 1e3:7.2f} "
              f"{res['penetration_count']:11d} {res['penetration_max_um']:8.3f} {res['ms_per_frame']:9.1f}")
    return results


def test_final(tmp_path=None):
    out = Path(tmp_path or "example_out")
    res = main(out, steps=3, pictures=False)
    for name, r in res.items():
        assert r["finite"], name
        assert 1500 < r["initial_penetration_max_um"] < 6000, (name, r)  # generated grasps: a few mm deep
        assert r["penetration_count"] <= 0.02 * r["initial_penetration_count"], (name, r)
    main(out / "picture", scenes=("apple",), steps=1)
    assert (out / "picture" / "apple" / "final.png").stat().st_size > 20_000


if __name__ == "__main__":
    import argparse

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", nargs="?", default="example_out", type=Path)
    p.add_argument("scenes", nargs="*", choices=[[]] + list(SCENES), default=[])
    p.add_argument("--contact", default="multires", choices=["vertex", "opt", "multires"])
    p.add_argument("--device", default=None)
    a = p.parse_args()
    main(a.out, tuple(a.scenes) or tuple(SCENES), contact=a.contact, device=a.device)

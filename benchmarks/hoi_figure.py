"""docs/images/hoi_grasps.png: the seven HOI grasps before (undeformed skin, the metric's penetrating
samples as magenta dots) and after 36 frames of multires contact (deformed skin), CPU.
Run: python benchmarks/hoi_figure.py"""

from pathlib import Path
import tempfile

import numpy as np

import physhand_mj as ph
from physhand_mj import figures
from physhand_mj.build.hoi import SCENES
from physhand_mj.render import look_at_camera, make_renderer, write_png
from physhand_mj.rollout import rollout

ROOT = Path(__file__).resolve().parents[1]


def grab(store: list, w: int = 400, h: int = 300):
    def take(hand, model, data):
        renderer = make_renderer(model, w, h)
        body = model.body([n for n in hand.objects.object_names if n != "world"][0]).id
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body]
        alpha = model.geom_rgba[geoms, 3].copy()
        model.geom_rgba[geoms, 3] = 0.45
        try:
            cam = look_at_camera(0.5 * (data.xpos[body] + hand.skin_vertices.mean(axis=0)), 0.3, 90.0, -88.0)
            store.append(figures.render_penetration_frame(renderer, model, data, hand, cam).copy())
        finally:
            model.geom_rgba[geoms, 3] = alpha
            renderer.close()
    return take


def main():
    cols = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in SCENES:
            pics: list = []
            res = rollout(ph.scene_path(f"hoi_{name}"), "grasp", steps=36, device="cpu", out=Path(tmp) / name,
                          progress=False, on_start=grab(pics), on_end=grab(pics))
            print(name, res["initial_penetration_count"], res["penetration_count"])
            cols.append(np.concatenate(pics, axis=0))
    grid = np.concatenate([np.concatenate(cols[:4], axis=1),
                           np.concatenate(cols[4:] + [np.full_like(cols[0], 255)], axis=1)], axis=0)
    print(write_png(grid, ROOT / "docs" / "images" / "hoi_grasps.png"))


if __name__ == "__main__":
    main()

"""docs/images/hoi_grasps.png: the seven HOI grasps before (undeformed skin, the metric's penetrating
samples as magenta dots) and after 36 frames of multires contact (deformed skin), CPU.
Run: python benchmarks/hoi_figure.py"""

from pathlib import Path
import tempfile

import numpy as np

import physhand_mj as ph
from physhand_mj import figures
from physhand_mj.build.hoi import SCENES
from physhand_mj.render import write_png
from physhand_mj.rollout import rollout

ROOT = Path(__file__).resolve().parents[1]


def grab(store: list, w: int = 400, h: int = 300):
    return lambda hand, model, data: store.append(figures.render_grasp_view(model, data, hand, w, h))


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

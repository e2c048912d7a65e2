"""Render the embedded layered hand: translucent skin over bones, and a cutaway of the three layers.

Run:  python examples/hand_layers.py [OUT_DIR]
Success looks like: OUT_DIR/hand_layers.png (skin over bones, open keyframe) and
OUT_DIR/hand_cutaway.png (skin, red flesh tets and white bones cut along the palm plane).
"""

import sys
from pathlib import Path

import physhand_mj as ph
from physhand_mj.figures import render_cutaway, render_layers


def main(out: Path) -> list[Path]:
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    return [render_layers(model, data, out / "hand_layers.png"),
            render_cutaway(asset, out / "hand_cutaway.png", normal=asset.meta["palm_normal"])]


def test_final(tmp_path=None):
    out = Path(tmp_path or "example_out")
    paths = main(out)
    assert all(p.stat().st_size > 20_000 for p in paths), paths


if __name__ == "__main__":
    print("\n".join(str(p) for p in main(Path(sys.argv[1] if len(sys.argv) > 1 else "example_out"))))

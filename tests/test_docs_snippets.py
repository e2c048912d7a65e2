"""The quickstart's Python snippets run as written (docs/quickstart.md) and say what the page says."""

import re
from pathlib import Path

import numpy as np

QUICKSTART = Path(__file__).parents[1] / "docs" / "quickstart.md"


def _python_blocks():
    return re.findall(r"```python\n(.*?)```", QUICKSTART.read_text(), flags=re.S)


def test_quickstart_snippets_run():
    blocks = _python_blocks()
    assert len(blocks) == 2, "the quickstart's two snippets: a scene of your own, the hand on a robot"
    own, robot = ({}, {})
    exec(compile(blocks[0], "quickstart-own-scene", "exec"), own)
    m = own["m"]
    assert m["finite"] and m["penetration_count"] == 0 and m["object_in_skin_count"] == 0, m
    assert own["ball"]["force_n"] > 0 and len(own["ball"]["vertices"]) > 0, "the lowered palm must touch the ball"
    exec(compile(blocks[1], "quickstart-robot", "exec"), robot)
    model, data = robot["model"], robot["data"]
    assert model.nmocap == 0
    assert np.allclose(data.xpos[model.body("right_hand_mount").id], [0, 0, 0.4], atol=1e-3)
    assert np.all(np.isfinite(robot["hand"].skin_vertices))

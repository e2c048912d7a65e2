"""The README's demo command works: the console script writes its picture and one JSON line."""

import json
import os
import shutil
import subprocess
import sys


def test_physhand_demo_writes_picture(tmp_path):
    import numpy as np

    exe = shutil.which("physhand") or None
    cmd = [exe] if exe else [sys.executable, "-m", "physhand_mj.cli"]
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "osmesa"))
    r = subprocess.run(cmd + ["demo", "--out", str(tmp_path)], capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    line = json.loads(r.stdout.strip().splitlines()[-1])
    png = tmp_path / "demo.png"
    assert line["picture"] == str(png)
    # the inverted-tet count comes with its reference: the same pose without the glass (joint creases)
    assert 0 <= line["inverted_tets_without_contact"] < line["inverted_tets"], line
    # and with how near the glass holds the bones (a bone inside it: clearance < 0 and counted)
    glass = line["objects"]["glass"]
    assert np.isfinite(glass["bone_clearance_mm"]) and isinstance(glass["bones_inside"], list), glass
    assert bool(glass["bones_inside"]) == (glass["bone_clearance_mm"] < 0), glass
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    # not a blank frame: decode rows and check the image has structure
    import zlib, struct
    import numpy as np

    w, h = struct.unpack(">II", data[16:24])
    idat = b"".join(data[i + 8:i + 8 + struct.unpack(">I", data[i:i + 4])[0]]
                    for i in range(8, len(data)) if data[i + 4:i + 8] == b"IDAT")
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + 3 * w)[:, 1:]
    assert raw.std() > 10


def test_cli_bad_input_is_one_line(tmp_path, monkeypatch):
    from physhand_mj import cli

    monkeypatch.setattr("physhand_mj.asset.DEFAULT_ASSET", tmp_path / "missing.npz")
    rc = cli.main(["demo", "--out", str(tmp_path)])
    assert rc == 1


def test_ci_runs_the_readmes_test_commands():
    """.ci/run's commands are the README's test block, line for line (the default set, then the slow set)."""
    from pathlib import Path

    root = Path(__file__).parents[1]
    readme = root.joinpath("README.md").read_text()
    block = readme.split("Install and run the tests", 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    ci = [x for x in root.joinpath(".ci", "run").read_text().splitlines()
          if x and not x.startswith(("#", "set ", "cd "))]
    assert block.splitlines() == ci, (block, ci)
    assert ci[0].endswith("MUJOCO_GL=osmesa python -m pytest -q") and ci[1].endswith("-m slow")

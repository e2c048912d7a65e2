"""The `physhand` command's first-contact behaviour: one-line device errors for every subcommand,
bundled scene names, `--version`, a missing render backend caught before any simulation."""

import importlib.metadata
import json
import os
import subprocess
import sys

import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.cli import main


def _physhand(*args, env=None, cwd=None):
    return subprocess.run([sys.executable, "-m", "physhand_mj.cli", *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=300)


def _own_lines(stderr: str) -> list[str]:
    """stderr without Warp's own banner line (its native library prints it on machines without CUDA)."""
    return [x for x in stderr.strip().splitlines() if not x.startswith("Warp CUDA")]


@pytest.mark.skipif(wp.is_cuda_available(), reason="needs a machine without CUDA")
@pytest.mark.parametrize("command", [["demo"], ["rollout", "hoi_apple"], ["bench", "solver"], ["bench", "cone"],
                                     ["bench", "accuracy"]], ids=" ".join)
def test_a_missing_cuda_device_is_one_line_for_every_command(command, tmp_path):
    r = _physhand(*command, "--device", "cuda", cwd=tmp_path)
    lines = _own_lines(r.stderr)
    assert r.returncode == 1 and r.stdout == "" and "Traceback" not in r.stderr, r.stderr
    want = f"physhand {command[0]}: error: --device cuda: no CUDA device is visible to Warp on this machine"
    assert lines == [want], r.stderr


def test_an_unknown_device_names_the_devices_there(capsys):
    assert main(["rollout", "hoi_apple", "--device", "gpu"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("physhand rollout: error: --device gpu:") and "cpu" in err, err


def test_rollout_takes_a_bundled_scene_name(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # (no hoi_apple file here: the bundled scene)
    assert main(["rollout", "hoi_apple", "--steps", "1", "--out", str(tmp_path / "o")]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["scene"] == str(ph.scene_path("hoi_apple")) and line["keyframe"] == "grasp", line


def test_a_scene_path_that_exists_wins_over_the_bundled_name(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "hoi_apple.xml").write_text("<mujoco><worldbody>")  # the user's own (broken) file
    assert main(["rollout", "hoi_apple.xml", "--steps", "1", "--out", str(tmp_path / "o")]) == 1
    assert "malformed MJCF hoi_apple.xml" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["rollout", "view"])
def test_an_unknown_scene_lists_the_bundled_names(command, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main([command, "hoi_appel"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith(f"physhand {command}: error: scene file not found: hoi_appel"), err
    assert "hoi_apple, " in err and "grasp_glass" in err, err


def test_view_takes_a_bundled_scene_name(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", "grasp_glass"]) == 1  # found: it gets as far as wanting a display
    assert "no display" in capsys.readouterr().err


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out == f"physhand_mj {ph.__version__}\n"
    assert ph.__version__ == importlib.metadata.version("physhand_mj")  # (the installed distribution's)


def test_demo_without_a_render_backend_fails_before_simulating(tmp_path):
    """GLFW without a display cannot make a context: one line, before the hand is built or stepped."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "glfw"
    r = _physhand("demo", "--frames", 30, "--out", tmp_path, env=env)
    lines = _own_lines(r.stderr)
    assert r.returncode == 1 and r.stdout == "" and "Traceback" not in r.stderr, r.stderr
    assert len(lines) == 1 and lines[0].startswith("physhand demo: error:") and "MUJOCO_GL=glfw" in lines[0], r.stderr
    assert "frame" not in r.stderr and not (tmp_path / "demo.png").exists(), r.stderr  # no progress bar: no frames


class _Blind:
    """A renderer whose backend made a context but cannot draw (as some EGL setups do)."""

    def __init__(self, *a, **k):
        self.closed = False

    def update_scene(self, *a, **k):
        pass

    def render(self):
        raise RuntimeError("eglMakeCurrent failed")

    def close(self):
        self.closed = True


def test_demo_draws_one_frame_before_building_the_hand(tmp_path, monkeypatch, capsys):
    import physhand_mj.figures  # noqa: F401  (imported first: it binds make_renderer at import, unpatched)

    built = []
    monkeypatch.setattr("physhand_mj.render.make_renderer", lambda *a, **k: built.append("renderer") or _Blind())
    monkeypatch.setattr("physhand_mj.coupling.SoftHand.__init__", lambda *a, **k: built.append("hand"))
    assert main(["demo", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert built == ["renderer"], built
    assert err.count("\n") == 0 and "cannot draw offscreen: eglMakeCurrent failed" in err, err


@pytest.mark.parametrize("gl, patch", [("nonsense", ""), ("egl", "import ctypes.util; ctypes.util.find_library = lambda n: None; ")],
                         ids=["unknown-backend", "egl-without-libEGL"])
def test_a_mujoco_gl_that_cannot_work_fails_the_demo_in_one_line(gl, patch, tmp_path):
    """A MUJOCO_GL that would make ``import mujoco`` raise (an unknown value; egl on a GPU host without
    libEGL, simulated by hiding the library) turns rendering off: the demo fails before it simulates,
    in one line naming the problem, and a command that draws nothing still runs."""
    env = dict(os.environ, MUJOCO_GL=gl)
    code = (patch + "import sys; from physhand_mj.cli import main; sys.exit(main(sys.argv[1:]))")
    r = subprocess.run([sys.executable, "-c", code, "demo", "--out", str(tmp_path)], capture_output=True, text=True,
                       env=env, timeout=300)
    lines = _own_lines(r.stderr)
    assert r.returncode == 1 and r.stdout == "" and "Traceback" not in r.stderr, r.stderr
    assert len(lines) == 1 and f"MUJOCO_GL={gl}" in lines[0] and "frame" not in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-c", patch + "import physhand_mj, mujoco; print(physhand_mj.__version__)"],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr

"""Measure the stress suite's margins (issue 14): run tests/stress and write what each test asserted,
its bound and the value measured, with the device, to a JSON file (docs/stability.md cites it).

    python benchmarks/stress_margins.py [--soak] [--out docs/benchmarks/stress_margins_cpu.json]

--soak also runs the tests behind the ``soak`` marker (the 10,000-frame soak, 40 hypothesis examples).
The margins come from the very runs the tests assert on (tests/stress/conftest.py records them).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--soak", action="store_true", help="also run the soak-marked tests")
    ap.add_argument("--out", default=str(ROOT / "docs/benchmarks/stress_margins_cpu.json"))
    args = ap.parse_args(argv)
    from physhand_mj.bench import device_name

    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "margins.json"
        env = dict(os.environ, PHYSHAND_STRESS_MARGINS=str(raw), MUJOCO_GL=os.environ.get("MUJOCO_GL", "osmesa"))
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/stress",
               "-m", "soak or not soak" if args.soak else "not soak"]
        t = time.perf_counter()
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t
        tail = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else proc.stderr.strip()[-300:]
        margins = json.loads(raw.read_text()) if raw.exists() else {}
    failed = [ln for ln in proc.stdout.splitlines() if ln.startswith(("FAILED", "ERROR"))]
    out = dict(command="python benchmarks/stress_margins.py" + (" --soak" if args.soak else ""),
               pytest=" ".join(cmd[1:]), device=device_name("cpu"), result=tail, failed=failed, wall_s=round(wall, 1),
               tests=margins)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(dict(out=args.out, result=tail, wall_s=out["wall_s"], device=out["device"])))
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())

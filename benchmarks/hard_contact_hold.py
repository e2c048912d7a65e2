"""Held frames of the hard contact cases, both measures, per Config variant (issue 11).

    python benchmarks/hard_contact_hold.py [--device cpu|cuda] [--frames 40] [--configs '{}' '{"feature_last": false}']
                                           [--paths 1] [--perturb 1e-4]

The 24 hard cases of benchmarks/hard_contact.py (six objects at the index fingertip and the palm,
pressed in over 15 frames or starting 4 mm deep) run ``--frames`` frames with ``Config(**variant)``;
every frame from 15 on (the object holds still) is a held frame. Counted per variant: held frames
in which anything is inside (skin samples in the object on the order-5 and order-9 lattices, or
object points and the denser check points in the skin), the worst depth over them, the cases not
clean at their last frame, the median solver ms per frame (device named; the first frame, which
compiles, excluded). A residue that comes and goes frame to frame (the feature push and Eq. 9
alternating) shows here and not at a last frame. Prints one line per variant (and the dirty
cases' per-frame depths); writes docs/benchmarks/hard_contact_hold_<device>.json.

The held contact is chaotic: a CPU run is one path of it (every run the same), a CUDA run another
each time (its atomics sum in no fixed order). ``--paths K`` runs every case K times per variant,
path k with ``contact_offset`` x (1 + k x ``--perturb``) (k = 0: the variant as given; 1e-4 moves
the default 4 um offset by 0.4 nm a path), and counts over all of them (docs/contact.md, "Held frames over many paths").
"""

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.cases import press_case, run_case  # noqa: E402

KINDS = ("cone_tip", "mesh_cone", "knife", "plate", "capsule", "coarse")
PRESS_FRAMES = 15  # press_case's: the object holds still from here on


def path_config(device: str, over: dict, path: int, perturb: float):
    """Config.from_dict(device, **over) (any Config, Tuning or Execution option, flat) on path ``path``:
    Tuning.contact_offset x (1 + path x perturb)."""
    import dataclasses

    over = dict(over)
    offset = over.pop("contact_offset", ph.Tuning().contact_offset)
    cfg = ph.Config.from_dict(dict(device=device, **over))
    return dataclasses.replace(cfg, tuning=dataclasses.replace(cfg.tuning, contact_offset=offset * (1.0 + path * perturb)))


def held_residue(r: dict, frames: int) -> tuple:
    """(skin, obj): per held frame of run_case's rows ``r``, the deepest skin sample inside (order 5
    or 9, um) and the deepest object point inside the skin (the contact's or the denser check
    points, um)."""
    h = slice(PRESS_FRAMES, frames)
    skin = np.maximum(np.asarray(r["skin_max_um"][h]), np.asarray(r["dense_max_um"][h]))
    obj = np.maximum(np.asarray(r["obj_max_um"][h]), np.asarray(r["check_max_um"][h]))
    return skin, obj


def run_variant(asset, device: str, frames: int, over: dict, progress=None, paths: int = 1,
                perturb: float = 1e-4) -> dict:
    held = total = skin_frames = obj_frames = dirty_end = dirty_runs = 0
    worst, ms, cases = 0.0, [], []
    for path, kind, site, start in itertools.product(range(paths), KINDS, ("fingertip", "palm"), (0.002, -0.004)):
        cfg = path_config(device, over, path, perturb)
        r = run_case(press_case(kind, site=site, depth=0.004, start=start), cfg, frames=frames, asset=asset)
        skin, obj = held_residue(r, frames)
        bad = (skin > 0) | (obj > 0)
        held += int(bad.sum())
        total += len(skin)
        skin_frames += int((skin > 0).sum())
        obj_frames += int((obj > 0).sum())
        worst = max(worst, float(skin.max(initial=0.0)), float(obj.max(initial=0.0)))
        dirty_end += bool(skin[-1] > 0 or obj[-1] > 0) if len(skin) else 0
        ms.append(float(np.median(r["ms"][1:])))
        dirty_runs += bool(bad.any())
        if bad.any():
            cases.append(dict(case=kind, site=site, start_mm=start * 1e3, path=path,
                              skin_um=np.round(skin, 1).tolist(), object_um=np.round(obj, 1).tolist()))
        if progress:
            progress()
    return dict(config=dict(over, contact_offset=path_config(device, over, 0, perturb).tuning.contact_offset), paths=paths, perturb=perturb if paths > 1 else 0.0,
                held_frames=total, held_with_residue=held, runs=paths * len(KINDS) * 4,
                runs_with_residue=dirty_runs, skin_frames=skin_frames, object_frames=obj_frames,
                worst_um=round(worst, 2), cases_dirty_at_end=dirty_end, median_ms=round(float(np.median(ms)), 2),
                dirty_cases=cases)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--frames", type=int, default=40, help="5 ms frames per case (held: 15 on)")
    ap.add_argument("--configs", nargs="+", default=["{}"], help="Config overrides as JSON, one per variant")
    ap.add_argument("--paths", type=int, default=1, help="paths of the held contact per variant (count; "
                    "path k moves contact_offset by a relative k x --perturb)")
    ap.add_argument("--perturb", type=float, default=1e-4, help="relative contact_offset step between paths")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/hard_contact_hold_<device>.json)")
    a = ap.parse_args()
    if a.frames <= PRESS_FRAMES:
        ap.error(f"--frames must exceed {PRESS_FRAMES} (the press)")
    from tqdm import tqdm

    asset = ph.load_asset()
    rows = []
    for spec in a.configs:
        over = json.loads(spec)
        with tqdm(total=len(KINDS) * 4 * a.paths, desc=spec, leave=False) as bar:
            row = run_variant(asset, a.device, a.frames, over, progress=bar.update, paths=a.paths, perturb=a.perturb)
        rows.append(row)
        print(f"{spec}: runs with residue {row['runs_with_residue']}/{row['runs']}, "
              f"held frames with residue {row['held_with_residue']}/{row['held_frames']} "
              f"(skin {row['skin_frames']}, object {row['object_frames']}), worst {row['worst_um']} um, "
              f"cases dirty at the end {row['cases_dirty_at_end']}, median {row['median_ms']} ms", flush=True)
        for c in row["dirty_cases"]:
            print(f"  {c['case']} {c['site']} {c['start_mm']:+.0f} mm (path {c['path']}): skin {c['skin_um']} "
                  f"object {c['object_um']}")
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    out = Path(a.out) if a.out else Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / \
        f"hard_contact_hold_{a.device.split(':')[0]}.json"
    out.write_text(json.dumps(dict(device=dev, frames=a.frames, held_from=PRESS_FRAMES, rows=rows), indent=1))
    print(f"{dev}; wrote {out}")


if __name__ == "__main__":
    main()

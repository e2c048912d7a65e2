"""What accuracy costs in time: a sweep of contact settings behind ``physhand bench accuracy``.

    points = sweep_points()                       # the settings swept (a list of SweepPoint)
    rows = run_sweep(points, WORKLOADS, device="cpu", frames=20)
    table = summarize_points(points, rows)         # one row per setting, Pareto flags set

Each setting (a :class:`SweepPoint`: strategy, multires samples x rounds, feature contact / side-aware
exits, contact passes, substeps, iterations; every other field is ``Config()``'s) runs on each
workload:

- ``hoi:<scene>``: a generated HOI grasp (docs/hoi.md) from its keyframe, the hand settled without
  contact first (as ``physhand rollout`` does), then ``frames`` frames of ``SoftHand.step``;
- ``case:<kind>@<site>``: a hard case (physhand_mj/bench/cases.py) pressed 4 mm into the rest skin from
  2 mm outside over 15 frames, then held; ``Solver.step`` alone;
- ``heldout:<seed>:<i>``: case ``i`` of the held-out generator (physhand_mj/bench/heldout.py: a random
  object at a random skin site, pressed in or embedded 0.5-4 mm over its first 10 frames, then held),
  ``Solver.step`` alone; the default four are feasible cases (the bones >= 1.2 mm clear) of four kinds;
- ``cone:paper``: the paper's cone experiment (section 4.2; physhand_mj.bench.runs.bench_cone's sheet and
  cone): a 2,400-vertex open sheet falls on an analytic cone; ``Solver.step``; an open sheet has no
  inside, so only the skin side is measured (the object features and side-aware exits need a closed
  skin and do not run: a setting's feature knobs make no difference here).

Measured per run: ms per frame (median of the timed frames: the first frame, which compiles, and on
CUDA the second, which captures the graph, are excluded; with ``repeats`` > 1 the smallest median
over the repeats, which run in alternating order so a busy host weighs on every setting alike), and
both penetration measures (DESIGN.md) at the end of the last frame: skin samples inside the object
on the metric's order-5 lattice and on an order-9 lattice (count, max um), object surface points
inside the closed skin (count, max um), these points being ``Contact.check_points``: edges 4x as
densely sampled as the features the contact pushes, none of them shared (the independent check,
docs/contact.md); ``hold_*``: the worst of the last ``HOLD`` frames (all frames when there are fewer).

Per setting: ``ms_per_frame`` = the mean over workloads; ``skin_um`` = the deepest skin sample
(order 5 or 9) and ``object_um`` = the deepest object point over workloads and the last ``HOLD``
frames; ``zero``: both are 0 (no sample, no point in any held frame of any workload).
:func:`pareto_front` keeps the settings no other setting beats on time and depth together;
:func:`cheapest_zero` is the fastest setting at zero (how ``Config()``'s contact is chosen,
docs/accuracy.md).
"""

from __future__ import annotations

import dataclasses

import time
from dataclasses import asdict, dataclass

import numpy as np

HOLD = 4  # frames at the end whose worst penetration the Pareto front uses (a setting must hold, not flicker)
# The sharp HOI object (box), a large smooth contact (apple), a cylinder (glass2); a knife edge into the
# fingertip, a cone tip into the palm, a 1 mm plate edge first into the fingertip; four held-out cases
# of seed 0 (heldout.py), each a kind the project's cases do not cover: a convex hull 3.4 mm into a
# fingertip (bones 1.2 mm clear), a 0.5 mm plate face first 4 mm into the palm, a 2.1 mm rod lying
# 3.9 mm across a middle phalanx (1.35 mm clear) and a 1 mm hemispherical shell rim first 3.4 mm into
# the palm.
WORKLOADS = ("hoi:box", "hoi:apple", "hoi:glass2", "case:knife@fingertip", "case:cone_tip@palm",
             "case:plate@fingertip", "cone:paper", "heldout:0:0", "heldout:0:51", "heldout:0:24", "heldout:0:4")
QUICK_WORKLOADS = ("hoi:box", "case:knife@fingertip", "heldout:0:24")


@dataclass(frozen=True)
class SweepPoint:
    """One contact setting; the Config fields it names (SI units and meanings: physhand_mj.types)."""

    contact: str = "multires"  # vertex | opt | multires
    samples: int = 21  # multires samples per round
    rounds: int = 2  # multires rounds
    features: bool = True  # Config.feature_contact
    side_aware: bool = True  # Config.tuning.side_aware
    passes: int = 8  # Config.contact_passes
    substeps: int = 10
    iterations: int = 1
    every: int = 1  # Config.contact_every (a contact stage every this many substeps)
    linear: bool = False  # Config.contact_linear (the skin held between stages)

    @property
    def name(self) -> str:
        strat = f"multires {self.samples}x{self.rounds}" if self.contact == "multires" else self.contact
        feat = "+feat+side" if self.features and self.side_aware else "+feat" if self.features else \
            "+side" if self.side_aware else ""
        it = f" it{self.iterations}" if self.iterations != 1 else ""
        every = (f" e{self.every}" if self.every != 1 else "") + ("+hold" if self.linear else "")
        return f"{strat}{feat} p{self.passes} s{self.substeps}{it}{every}"

    def config(self, device: str):
        """The Config of this setting (everything else at its default)."""
        from physhand_mj.types import Config, Strategy, Tuning

        return Config(device=device, contact=Strategy[self.contact.upper()], feature_contact=self.features,
                      contact_passes=self.passes, substeps=self.substeps, iterations=self.iterations,
                      contact_every=self.every, contact_linear=self.linear,
                      tuning=Tuning(multires_samples=self.samples, multires_rounds=self.rounds,
                                    side_aware=self.side_aware)).validate()

    def is_default(self) -> bool:
        """True when this setting is ``Config()``'s."""
        from physhand_mj.types import Config

        c = Config().validate()
        return (self.contact == c.contact.name.lower() and self.features == c.feature_contact
                and self.side_aware == c.side_aware and self.passes == c.contact_passes
                and self.substeps == c.substeps and self.iterations == c.iterations
                and self.every == c.contact_every and self.linear == c.contact_linear
                and (self.contact != "multires" or (self.samples, self.rounds) == (c.multires_samples,
                                                                                   c.multires_rounds)))


def default_point() -> SweepPoint:
    """The SweepPoint of ``Config()``."""
    from physhand_mj.types import Config

    c = Config().validate()
    return SweepPoint(c.contact.name.lower(), c.multires_samples, c.multires_rounds, c.feature_contact, c.side_aware,
                      c.contact_passes, c.substeps, c.iterations, c.contact_every, c.contact_linear)


def sweep_points(quick: bool = False) -> list[SweepPoint]:
    """The settings swept: each knob moved away from a stage every substep (``SweepPoint()``, the
    paper's Algorithm 1 with the project's contact), plus cheap combinations and ``Config()``'s."""
    P = SweepPoint
    if quick:
        return [P("vertex", features=False, side_aware=False, passes=2, substeps=5), default_point()]
    pts = []
    for c in ("vertex", "opt", "multires"):  # strategy x the paper's contact (Eq. 9 only) / features + side
        pts += [P(c, features=False, side_aware=False), P(c)]
    pts += [P(features=True, side_aware=False),  # features without the side-aware exits
            P(samples=16, rounds=2, features=False, side_aware=False),  # the paper's 16 x 2
            P(samples=16, rounds=2), P(samples=10, rounds=3),
            P(passes=4), P(passes=2), P(substeps=5), P(passes=4, substeps=5), P(passes=2, substeps=5),
            P(samples=16, rounds=2, passes=4, substeps=5), P(samples=16, rounds=2, passes=2, substeps=5),
            P(samples=10, rounds=3, passes=4, substeps=5), P(samples=10, rounds=3, passes=2, substeps=10),
            P("vertex", passes=4, substeps=5), P("opt", passes=4, substeps=5),
            P(features=False, side_aware=False, passes=4, substeps=5), P(substeps=5, iterations=2),
            # around the cheap accurate corner the first run found (8 passes, 5 substeps)
            P("vertex", substeps=5), P("opt", substeps=5), P(samples=16, rounds=2, substeps=5),
            P(samples=10, rounds=3, substeps=5), P("opt", substeps=5, iterations=2),
            # half the contact stages, the skin held between them (Config.contact_linear, 2026-11-28)
            P(every=2), P(every=2, linear=True), P("opt", every=2, linear=True), P(every=3, linear=True),
            # around the cheapest setting at zero on every workload in the 2026-12 run (e2+hold)
            P(every=2, linear=True, substeps=5), P(every=2, linear=True, passes=4),
            P(samples=10, rounds=3, every=2, linear=True)]
    if not any(p.is_default() for p in pts):  # (a Config() changed by hand is swept too)
        pts.append(default_point())
    return pts


def pareto_front(costs) -> np.ndarray:
    """Boolean mask of the non-dominated rows of ``costs`` (n, k), every column to be minimised:
    row i is dominated when some row is <= it in every column and < in at least one. Equal rows
    are all kept; NaN rows are never on the front."""
    c = np.asarray(costs, dtype=float)
    if c.ndim != 2:
        raise ValueError(f"costs must be a 2-D array (n points, k objectives), got shape {c.shape}")
    ok = ~np.isnan(c).any(axis=1)
    mask = ok.copy()
    for i in np.flatnonzero(ok):
        other = c[ok]
        dom = np.all(other <= c[i], axis=1) & np.any(other < c[i], axis=1)
        mask[i] = not dom.any()
    return mask


def _hoi_run(scene: str, pt: SweepPoint, device: str, frames: int, hold_frames: int) -> dict:
    import mujoco

    import physhand_mj as ph
    from physhand_mj.rollout import load_scene

    model, data, _ = load_scene(ph.scene_path(f"hoi_{scene}"), "grasp")
    cfg = dataclasses.replace(pt.config(device), frame_dt=float(model.opt.timestep))
    hand = ph.SoftHand(model, data, cfg, settle_contact=False)
    ms, hold, finite = [], [], True
    for f in range(frames):
        mujoco.mj_step(model, data)
        t = time.perf_counter()
        res = hand.step()
        ms.append((time.perf_counter() - t) * 1e3)
        finite = finite and int(res.get("nonfinite", 0)) == 0
        if f >= frames - hold_frames:  # both measures (the object side on the check points), not timed
            p5, p9 = hand.penetration(order=5), hand.penetration(order=9, check=True)
            hold.append((p5["penetration_count"], p5["penetration_max_um"], p9["penetration_count"],
                         p9["penetration_max_um"], p9["object_in_skin_count"], p9["object_in_skin_max_um"]))
    finite = finite and bool(np.all(np.isfinite(hand.skin_vertices)))
    return dict(ms=ms, hold=np.asarray(hold, float), finite=finite)


def heldout_case(spec: str, asset):
    """The :class:`~physhand_mj.bench.heldout.Heldout` of workload ``heldout:<seed>:<i>`` (``spec``:
    ``<seed>:<i>``), its bones' clearance measured."""
    from physhand_mj.bench.heldout import clearance_mm, draw_case

    seed, i = (int(v) for v in spec.split(":"))
    h = draw_case(seed, i, asset)
    h.clearance_mm = clearance_mm(h.case, asset)
    return h


def _case_run(case, pt: SweepPoint, device: str, frames: int, hold_frames: int, asset) -> dict:
    from physhand_mj.bench.cases import run_case

    r = run_case(case, pt.config(device), frames=frames, asset=asset)
    keys = ("skin_count", "skin_max_um", "dense_count", "dense_max_um", "check_count", "check_max_um")
    hold = np.stack([np.asarray(r[k][-hold_frames:], float) for k in keys], axis=1)
    return dict(ms=list(r["ms"]), hold=hold, finite=bool(r["finite"]))


def _cone_run(pt: SweepPoint, device: str, frames: int, hold_frames: int) -> dict:
    """The paper's cone experiment under setting ``pt`` (the sheet's own material, as
    physhand_mj.bench.runs.bench_cone builds it; the setting's strategy, passes, substeps, iterations)."""
    from dataclasses import replace

    from physhand_mj.bench.cases import CONE, SHEET
    from physhand_mj.bodies import sheet
    from physhand_mj.contact import Objects
    from physhand_mj.contact.metrics import summarize
    from physhand_mj.solver import Solver, make_model
    from physhand_mj.types import GeomType

    body = sheet(**SHEET)
    cfg = replace(pt.config(device), volumes=False, attachment=False, edge_compliance_skin=1.0e-6,
                  smooth_compliance=10.0, damping=0.0).validate()
    objects = Objects(device, 1)
    objects.add(GeomType.CONE, [CONE["radius"], CONE["height"]], name="cone")
    solver = Solver(make_model(body, cfg), cfg, objects=objects)
    state = solver.make_state()
    ms, hold, finite = [], [], True
    for f in range(frames):
        t = time.perf_counter()
        out = solver.step(state)
        ms.append((time.perf_counter() - t) * 1e3)
        finite = finite and int(out.get("nonfinite", 0)) == 0
        if f >= frames - hold_frames:  # the skin side (an open sheet has no inside), not timed
            p5 = summarize(solver.contact.measure(state, order=5, objects_side=False))
            p9 = summarize(solver.contact.measure(state, order=9, objects_side=False))
            hold.append((p5["penetration_count"], p5["penetration_max_um"], p9["penetration_count"],
                         p9["penetration_max_um"], 0.0, 0.0))
    finite = finite and bool(np.all(np.isfinite(state.x.numpy())))
    return dict(ms=ms, hold=np.asarray(hold, float), finite=finite)


ROW_COLUMNS = ["point", "workload", "contact", "samples", "rounds", "features", "side_aware", "passes", "substeps",
               "iterations", "every", "linear", "frames", "ms_per_frame", "skin5_count", "skin5_max_um", "skin9_count", "skin9_max_um",
               "object_count", "object_max_um", "hold_skin_max_um", "hold_object_max_um", "hold_count", "finite",
               "device"]


def check_workloads(workloads) -> None:
    """Raise ValueError naming the first workload that is not hoi:SCENE, case:KIND@SITE,
    heldout:SEED:I or cone:paper."""
    import physhand_mj as ph
    from physhand_mj.bench.cases import SITES, press_case

    for w in workloads:
        kind, _, spec = w.partition(":")
        if kind == "hoi":
            try:
                ph.scene_path(f"hoi_{spec}")
            except FileNotFoundError:
                raise ValueError(f"workload '{w}': no bundled scene hoi_{spec} (glass1, glass2, toothpaste, phone, "
                                 f"apple, bowl, box)") from None
        elif kind == "case" and "@" in spec:
            case, site = spec.split("@", 1)
            press_case(case)  # ValueError for an unknown kind
            if site not in SITES:
                raise ValueError(f"workload '{w}': site must be one of {', '.join(SITES)}")
        elif kind == "heldout":
            parts = spec.split(":")
            if len(parts) != 2 or not all(p.isdigit() for p in parts):
                raise ValueError(f"workload '{w}': heldout:SEED:I takes two integers >= 0 (the generator's seed "
                                 f"and case index, physhand_mj/bench/heldout.py), e.g. heldout:0:4")
        elif w == "cone:paper":
            pass
        else:
            raise ValueError(f"workload '{w}' must be hoi:SCENE, case:KIND@SITE, heldout:SEED:I or cone:paper")


def run_sweep(points, workloads, device: str = "cpu", frames: int = 20, repeats: int = 1, progress=None) -> list[dict]:
    """Run every point on every workload (``repeats`` passes, alternating order); one row per
    (point, workload) with ROW_COLUMNS. ``progress(str)`` is told each run."""
    import physhand_mj as ph

    asset = ph.load_asset()
    if frames < 2:
        raise ValueError(f"--frames must be >= 2 (the first frame compiles and is not timed), got {frames}")
    skip = min(2 if str(device).startswith("cuda") else 1, frames - 1)  # compile (and graph capture) frames
    hold = min(HOLD, frames)
    check_workloads(workloads)
    names = [p.name for p in points]
    if len(set(names)) != len(names):
        raise ValueError(f"sweep points must differ: {sorted(n for n in names if names.count(n) > 1)}")
    from physhand_mj.bench.cases import press_case

    cases = {w: (press_case(w[5:].split("@")[0], site=w[5:].split("@")[1], depth=0.004, start=0.002)
                 if w.startswith("case:") else heldout_case(w[8:], asset).case)
             for w in workloads if w.startswith(("case:", "heldout:"))}
    jobs = [(i, w) for i in range(len(points)) for w in workloads]
    ms: dict = {}
    meas: dict = {}
    for rep in range(repeats):
        order = jobs if rep % 2 == 0 else jobs[::-1]
        for n, (i, w) in enumerate(order):
            pt = points[i]
            kind, spec = w.split(":", 1)
            if kind == "hoi":
                r = _hoi_run(spec, pt, device, frames, hold)
            elif kind in ("case", "heldout"):
                r = _case_run(cases[w], pt, device, frames, hold, asset)
            else:  # cone:paper
                r = _cone_run(pt, device, frames, hold)
            med = float(np.median(r["ms"][skip:]))
            ms[i, w] = min(ms.get((i, w), np.inf), med)
            prev = meas.get((i, w))
            if prev is None:
                meas[i, w] = r
            else:  # the worse of the repeats (CPU runs repeat exactly; this guards against ones that do not)
                prev["hold"] = np.maximum(prev["hold"], r["hold"])
                prev["finite"] = prev["finite"] and r["finite"]
            if progress is not None:
                progress(f"[{rep + 1}/{repeats} {n + 1}/{len(order)}] {pt.name} | {w}: {med:.1f} ms, "
                         f"skin {r['hold'][-1, 3]:.1f} um, object {r['hold'][-1, 5]:.1f} um")
    rows = []
    for i, w in jobs:
        pt, r = points[i], meas[i, w]
        h = r["hold"]
        end = h[-1]
        rows.append(dict(point=pt.name, workload=w, **{k: v for k, v in asdict(pt).items()}, frames=frames,
                         ms_per_frame=round(ms[i, w], 3),
                         skin5_count=int(end[0]), skin5_max_um=round(float(end[1]), 3), skin9_count=int(end[2]),
                         skin9_max_um=round(float(end[3]), 3), object_count=int(end[4]),
                         object_max_um=round(float(end[5]), 3),
                         hold_skin_max_um=round(float(max(h[:, 1].max(), h[:, 3].max())), 3),
                         hold_object_max_um=round(float(h[:, 5].max()), 3),
                         hold_count=int(h[:, [0, 2, 4]].sum(axis=1).max()), finite=r["finite"], device=str(device)))
    return rows


POINT_COLUMNS = ["point", "contact", "samples", "rounds", "features", "side_aware", "passes", "substeps", "iterations",
                 "every", "linear", "ms_per_frame", "skin_um", "object_um", "skin_count", "object_count", "finite", "default",
                 "zero", "pareto_skin", "pareto_object", "pareto_both"]


def summarize_points(points, rows) -> list[dict]:
    """One row per point (POINT_COLUMNS): mean ms over workloads, the deepest penetration of each
    measure over workloads and held frames, counts at the end summed over workloads, ``zero`` (finite
    and no penetration by either measure on any workload in any held frame), and whether the point is
    on the Pareto front of (ms, skin_um), (ms, object_um) and (ms, skin_um, object_um)."""
    out = []
    for pt in points:
        mine = [r for r in rows if r["point"] == pt.name]
        out.append(dict(point=pt.name, **asdict(pt),
                        ms_per_frame=round(float(np.mean([r["ms_per_frame"] for r in mine])), 3),
                        skin_um=max(r["hold_skin_max_um"] for r in mine),
                        object_um=max(r["hold_object_max_um"] for r in mine),
                        skin_count=sum(r["skin5_count"] + r["skin9_count"] for r in mine),
                        object_count=sum(r["object_count"] for r in mine),
                        finite=all(r["finite"] for r in mine), default=pt.is_default()))
        p = out[-1]
        p["zero"] = bool(p["finite"] and p["skin_um"] == 0 and p["object_um"] == 0
                         and all(r.get("hold_count", 0) == 0 for r in mine))
    c = np.array([[p["ms_per_frame"], p["skin_um"], p["object_um"]] for p in out], float)
    for key, cols in (("pareto_skin", [0, 1]), ("pareto_object", [0, 2]), ("pareto_both", [0, 1, 2])):
        mask = pareto_front(c[:, cols])
        for p, m in zip(out, mask):
            p[key] = bool(m and p["finite"])
    return out


def cheapest_zero(table, substeps: int | None = None):
    """The fastest row of ``table`` (summarize_points) that is ``zero``, among those with ``substeps``
    substeps and one iteration when given (the material: fewer substeps make a softer hand,
    docs/accuracy.md); None when no row is."""
    rows = [p for p in table if p["zero"] and (substeps is None or (p["substeps"] == substeps and p["iterations"] == 1))]
    return min(rows, key=lambda p: p["ms_per_frame"], default=None)


def plot_front(table, path, title: str) -> None:
    """Two panels (skin samples in objects; object points in the skin: deepest um against ms per
    frame), every setting a dot (a circle at ``Config()``'s substeps, a triangle at others), the
    Pareto front joined and labelled with its settings, ``Config()`` a star."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from physhand_mj.types import Config

    steps = Config().substeps
    fig, axes = plt.subplots(1, 2, figsize=(15, 6.5))
    for ax, key, front, label in ((axes[0], "skin_um", "pareto_skin", "skin samples inside the object (order 5 and 9)"),
                                  (axes[1], "object_um", "pareto_object", "object points inside the skin")):
        x = np.array([p["ms_per_frame"] for p in table])
        y = np.array([p[key] for p in table])
        colors = {"vertex": "tab:red", "opt": "tab:orange", "multires": "tab:blue"}
        for c, col in colors.items():  # circles: Config()'s substeps (its material); triangles: others
            for mark, same in (("o", True), ("^", False)):
                sel = [i for i, p in enumerate(table) if p["contact"] == c and (p["substeps"] == steps) == same]
                ax.scatter(x[sel], y[sel], s=28, marker=mark, color=col, alpha=0.55,
                           label=f"{c}, {steps} substeps" if same else f"{c}, other substeps")
        on = sorted([i for i, p in enumerate(table) if p[front]], key=lambda i: x[i])
        ax.plot(x[on], y[on], "k-", lw=1, drawstyle="steps-post", label="Pareto front")
        ax.scatter(x[on], y[on], s=70, facecolors="none", edgecolors="k", lw=1.5)
        for k, i in enumerate(on):
            ax.annotate(table[i]["point"], (x[i], y[i]), textcoords="offset points", xytext=(6, 6 + 9 * (k % 3)),
                        fontsize=7.5)
        d = [i for i, p in enumerate(table) if p["default"]]
        if d:
            ax.scatter(x[d], y[d], marker="*", s=220, color="gold", edgecolors="k", zorder=5, label="Config()")
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_xlabel("ms per frame (mean over workloads)")
        ax.set_ylabel(f"deepest {label}, um")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=5)  # below the panels: no point hidden
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)

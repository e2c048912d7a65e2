"""Benchmarks behind ``physhand bench`` and the project's reference cases: above the library, which
never imports them.

- :mod:`~physhand_mj.bench.runs`: ``bench solver`` / ``cone`` / ``accuracy`` as dicts, timings that
  exclude compilation;
- :mod:`~physhand_mj.bench.cases`: the hard contact cases (objects pressed into the hand) and the
  paper's cone experiment's sheet and cone;
- :mod:`~physhand_mj.bench.accuracy`: what accuracy costs in time, the sweep and its Pareto front.
"""

from physhand_mj.bench.runs import bench_accuracy, bench_cone, bench_solver, hand_asset
from physhand_mj.launch import device_name

__all__ = ["bench_accuracy", "bench_cone", "bench_solver", "device_name", "hand_asset"]

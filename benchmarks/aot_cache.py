"""Compile physhand_mj's Warp kernel modules for a GPU architecture on a machine without a GPU, into
Warp's kernel-cache layout, so that a fresh GPU machine does not spend its first minutes compiling.

Warp's NVRTC compiles CUDA code without a driver: ``wp.compile_aot_module(module, device=None,
arch=90)`` writes the ``.cu``, ``.meta`` and ``.sm90.cubin`` that a device's kernel cache holds, under
the same module hash (checked on an H100, 2026-11-27: the hashes matched the device's and the bowl
batch's warm-up fell from 272 s to 17-24 s). A module holding tile kernels is compiled once per
block size it is launched with; ``BLOCK_DIMS`` lists those. Kernels made at run time (the fused
substep's, one per model size and block) are not covered: a device run adds them to its own cache.

    python benchmarks/aot_cache.py [--arch 90] [--merge .devc/warp_cache.tar.xz]
                                   [--out .devc/warp_cache.tar.xz]

Writes a tar.xz of ``<warp version>/wp_<module>_<hash>/...`` to unpack into ``~/.cache/warp`` on the
device (``benchmarks/gpu_session.sh``'s recipe), merged with the entries of ``--merge`` (kept where
this run did not make the same folder).
"""

from __future__ import annotations

import argparse
import importlib
import io
import pkgutil
import shutil
import tarfile
import tempfile
import time
from pathlib import Path

import warp as wp

import physhand_mj

ROOT = Path(__file__).resolve().parents[1]
# block sizes a module's kernels are launched with besides Warp's default (tile kernels: the shared
# tiles' shapes are compiled in)
BLOCK_DIMS = {
    "physhand_mj.contact.query_tiled": (32,),  # query_tiled.TILE_LANES
    "physhand_mj.contact.features": (128,),  # features.FEATURE_LANES
    "physhand_mj.contact.winding": (128,),
}


def kernel_modules() -> list[str]:
    """physhand_mj's modules that define Warp kernels (imported to look)."""
    names = []
    for info in pkgutil.walk_packages(physhand_mj.__path__, "physhand_mj."):
        try:
            mod = importlib.import_module(info.name)
        except Exception:  # optional integrations (MyoSuite, Ray) without their extras
            continue
        if any(isinstance(v, wp.Kernel) and v.module.name == info.name for v in vars(mod).values()):
            names.append(info.name)
    return names


def compile_all(arch: int, dest: Path) -> list[str]:
    """Compile every kernel module for ``arch`` at each of its block sizes into ``dest``/<warp version>/;
    returns the folders made."""
    made = []
    version = dest / wp.config.version
    for name in kernel_modules():
        mod = importlib.import_module(name)
        module = wp.get_module(name)
        default = module.options["block_dim"]
        for bd in (None, *BLOCK_DIMS.get(name, ())):
            if bd is not None:
                wp.set_module_options({"block_dim": bd}, module=mod)
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                for f in wp.compile_aot_module(mod, device=None, arch=arch, module_dir=tmp):
                    stem = f.name.split(f".sm{arch}")[0]
                    folder = version / stem
                    folder.mkdir(parents=True, exist_ok=True)
                    for g in Path(tmp).glob(stem + ".*"):
                        shutil.copy(g, folder / g.name)
                    made.append(stem)
                    print(f"{stem} (block {bd or default}): {time.perf_counter() - t0:.1f} s", flush=True)
        wp.set_module_options({"block_dim": default}, module=mod)
    return made


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arch", type=int, default=90, help="CUDA architecture (90: H100 and H200)")
    p.add_argument("--merge", default=None, help="a kernel-cache tar.xz whose other entries to keep")
    p.add_argument("--out", default=str(ROOT / ".devc" / "warp_cache.tar.xz"), help="tar.xz to write")
    a = p.parse_args()
    wp.init()
    with tempfile.TemporaryDirectory() as tmp:
        dest = Path(tmp)
        if a.merge and Path(a.merge).exists():
            with tarfile.open(a.merge) as t:
                t.extractall(dest, filter="data")
        made = compile_all(a.arch, dest)
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode="w:xz") as t:
            for entry in sorted(dest.iterdir()):
                t.add(entry, arcname=entry.name)
        out = Path(a.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(buf.getvalue())
        kept = sum(1 for d in dest.glob("*/*") if d.is_dir())
    print(f"{len(made)} modules compiled for sm_{a.arch}; {kept} in {out} ({out.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()

"""Compile physhand_mj's Warp kernel modules for a GPU architecture on a machine without a GPU, into
Warp's kernel-cache layout, so that a fresh GPU machine does not spend its first minutes compiling.

Warp's NVRTC compiles CUDA code without a driver: ``wp.compile_aot_module(module, device=None,
arch=90)`` writes the ``.cu``, ``.meta`` and ``.sm90.cubin`` that a device's kernel cache holds, under
the same module hash (checked on an H100, 2026-11-27: the hashes matched the device's and the bowl
batch's warm-up fell from 272 s to 17-24 s). A module holding tile kernels is compiled once per
block size it is launched with; ``BLOCK_DIMS`` lists those. Kernels made at run time (the fused
substep's, one per model size and block) are not covered: a device run adds them to its own cache.

    python benchmarks/aot_cache.py [--arch 90] [--merge .devc/warp_cache.tar.xz]
                                   [--out .devc/warp_cache.tar.xz] [--resources [PATTERN]] [--lineinfo]

Writes a tar.xz of ``<warp version>/wp_<module>_<hash>/...`` to unpack into ``~/.cache/warp`` on the
device (``benchmarks/gpu_run.sh`` does), merged with the entries of ``--merge`` (kept where
this run did not make the same folder). ``--resources`` also prints each kernel's registers and local
frame a thread (read from the cubin's ``.nv.info``: no CUDA tools needed), for kernels whose name
holds PATTERN: how many threads an SM can hold (65,536 registers an SM on sm_90) and what spills.
"""

from __future__ import annotations

import argparse
import importlib
import io
import pkgutil
import shutil
import struct
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
    "physhand_mj.contact.patches_tiled": (512,),  # patches_tiled.PATCH_LANES
}


# kernels made at run time that a device run uses (Config.execution.multires_registers' caps, with
# Config.execution.multires_block_dim's blocks); made_kernels adds the others in modules of their own
MADE = ((128, 256), (168, 256), (128, 128), (96, 128), (80, 128), (64, 128))


def made_kernels() -> list:
    """Kernels in modules of their own: the capped multires kernels, and the tiled multires kernel
    without the mesh branch (query_tiled.tiled_kernel_for, blocks of TILE_LANES)."""
    from physhand_mj.contact.query import multires_kernel
    from physhand_mj.contact.query_tiled import decide_and_project_tiled_analytic

    return [multires_kernel(r, b) for r, b in MADE] + [decide_and_project_tiled_analytic]


def decision_modules_with_lineinfo() -> list:
    """The decision-point kernels' modules with line info on, for Nsight Compute's source view
    (``batch_hoi.py --lineinfo`` sets the same): contact.query's (the generic kernel), contact.query_lanes'
    and the capped multires kernel's (128 registers, blocks of 256). Returns their Warp modules."""
    from physhand_mj.contact import query

    mods = []
    for m in (query,):
        wp.set_module_options({"lineinfo": True}, module=m)
        mods.append(wp.get_module(m.__name__))
    k = query.multires_kernel(128, 256)
    k.module.options["lineinfo"] = True
    return mods + [k.module]


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


def _compile(mod, label: str, arch: int, version: Path, made: list, resources: str | None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        for f in wp.compile_aot_module(mod, device=None, arch=arch, module_dir=tmp):
            stem = f.name.split(f".sm{arch}")[0]
            folder = version / stem
            folder.mkdir(parents=True, exist_ok=True)
            for g in Path(tmp).glob(stem + ".*"):
                shutil.copy(g, folder / g.name)
            made.append(stem)
            print(f"{stem} ({label}): {time.perf_counter() - t0:.1f} s", flush=True)
            if resources is not None:
                for name, (regs, frame) in sorted(cubin_resources(f.read_bytes() if f.exists() else
                                                                  (folder / f.name).read_bytes()).items()):
                    if resources in name and name.endswith("_forward"):
                        print(f"    {regs:4d} registers, {frame:5d} B local frame: {name}")


def compile_all(arch: int, dest: Path, resources: str | None = None) -> list[str]:
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
            _compile(mod, f"block {bd or default}", arch, version, made, resources)
        wp.set_module_options({"block_dim": default}, module=mod)
    for k in made_kernels():
        _compile(k.module, "made at run time", arch, version, made, resources)
    return made


def cubin_resources(data: bytes) -> dict:
    """{kernel: (registers, local frame bytes)} from a cubin's ELF ``.nv.info`` section (attributes
    EIATTR_REGCOUNT 0x2f and EIATTR_FRAME_SIZE 0x11, each (symbol index, value))."""
    shoff = struct.unpack_from("<Q", data, 0x28)[0]
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x3A)
    secs = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize) for i in range(shnum)]

    def cstr(off):
        return data[off:data.index(b"\0", off)].decode()

    names = [cstr(secs[shstrndx][4] + s[0]) for s in secs]
    symtab = next(s for s in secs if s[1] == 2)  # SHT_SYMTAB
    strtab = secs[symtab[6]]
    syms = [cstr(strtab[4] + struct.unpack_from("<I", data, symtab[4] + 24 * i)[0]) for i in range(symtab[5] // 24)]
    info = secs[names.index(".nv.info")]
    out: dict = {}
    o, end = info[4], info[4] + info[5]
    while o < end:
        fmt, attr = data[o], data[o + 1]
        if fmt == 0x04:  # EIFMT_SVAL: a 2-byte size, then the value
            size = struct.unpack_from("<H", data, o + 2)[0]
            if size == 8 and attr in (0x2F, 0x11):
                sym, value = struct.unpack_from("<II", data, o + 4)
                regs, frame = out.get(syms[sym], (0, 0))
                out[syms[sym]] = (value, frame) if attr == 0x2F else (regs, value)
            o += 4 + size
        else:  # EIFMT_NVAL / BVAL / HVAL: 4 bytes
            o += 4
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arch", type=int, default=90, help="CUDA architecture (90: H100 and H200)")
    p.add_argument("--merge", default=None, help="a kernel-cache tar.xz whose other entries to keep")
    p.add_argument("--out", default=str(ROOT / ".devc" / "warp_cache.tar.xz"), help="tar.xz to write")
    p.add_argument("--resources", nargs="?", const="", default=None,
                   help="print registers and local frame of the kernels whose name holds this text")
    p.add_argument("--lineinfo", action="store_true",
                   help="also the decision-point modules with line info (batch_hoi.py --lineinfo)")
    a = p.parse_args()
    wp.init()
    with tempfile.TemporaryDirectory() as tmp:
        dest = Path(tmp)
        if a.merge and Path(a.merge).exists():
            with tarfile.open(a.merge) as t:
                t.extractall(dest, filter="data")
        made = compile_all(a.arch, dest, a.resources)
        if a.lineinfo:
            for mod in decision_modules_with_lineinfo():
                _compile(mod, "line info", a.arch, dest / wp.config.version, made, a.resources)
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

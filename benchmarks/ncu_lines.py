"""Nsight Compute's source page (``ncu --import R --page source --csv --print-source cuda,sass``) summed per
source file and line: warp-stall samples, warp instructions and lanes per instruction, over every
kernel in the report. Warp's kernels built with line info (``batch_hoi.py --lineinfo``) map their
SASS to the Python lines of the ``wp.func`` they came from and to Warp's native headers.

    python benchmarks/ncu_lines.py SOURCE.csv [--top 45]
"""
import collections
import csv
import sys

TOP = int(sys.argv[sys.argv.index('--top') + 1]) if '--top' in sys.argv else 45
rows = csv.reader(open(sys.argv[1], newline=''))
path = None
hdr = None
agg = collections.defaultdict(lambda: [0, 0, 0])  # (file, line) -> samples, inst, thread inst
for r in rows:
    if not r: continue
    if r[0] == "File Path": path = r[1]; continue
    if r[0] == "Line No": hdr = r; continue
    if r[0] and r[0] != "" and hdr is not None and r[0].isdigit():
        try:
            s = int(r[4]); i = int(r[7]); t = int(r[8])
        except ValueError:
            continue
        a = agg[(path, int(r[0]))]; a[0] += s; a[1] += i; a[2] += t
tot = sum(v[0] for v in agg.values()); ti = sum(v[1] for v in agg.values())
print("total samples", tot, "inst", ti)
byfile = collections.defaultdict(lambda: [0,0,0])
for (p, l), v in agg.items():
    b = byfile[p]; b[0]+=v[0]; b[1]+=v[1]; b[2]+=v[2]
for p, v in sorted(byfile.items(), key=lambda kv: -kv[1][0]):
    print(f"{100*v[0]/tot:5.1f}% samples {100*v[1]/ti:5.1f}% inst  lanes {v[2]/max(v[1],1):5.1f}  {p}")
print()
for (p, l), v in sorted(agg.items(), key=lambda kv: -kv[1][0])[:TOP]:
    print(f"{100*v[0]/tot:5.1f}% {100*v[1]/ti:5.1f}% lanes {v[2]/max(v[1],1):5.1f}  {p.split('/')[-1]}:{l}")

#!/usr/bin/env python3
"""Markdown table of a bench_skinning JSON run (medians of its repetitions).

   python3 bench/skin_table.py skin.json
"""
import json
import sys

# The ozz / plain-loop ratios (Zen 4, same process), row order
# (1,P) (1,P+N) (2,P) (2,P+N) (4,P) (4,P+N) (8,P) (8,P+N); the target is 1.5x them.
OZZ_OVER_PLAIN = {(1, 0): 5.5, (1, 1): 4.4, (2, 0): 4.6, (2, 1): 4.1,
                  (4, 0): 3.2, (4, 1): 3.5, (8, 0): 3.0, (8, 1): 3.4}
FORMATS = {0: "F32", 1: "U16", 2: "U8"}


def load(path):
    rows = {}
    with open(path) as f:
        doc = json.load(f)
    for b in doc["benchmarks"]:
        if b.get("run_type") == "aggregate" and b.get("aggregate_name") != "median":
            continue
        name = b.get("run_name", b["name"])
        rows[name] = b
    return doc.get("context", {}), rows


def main():
    ctx, r = load(sys.argv[1])
    print(f"host: {ctx.get('host_name', '?')}, {ctx.get('num_cpus', '?')} CPUs, "
          f"{ctx.get('mhz_per_cpu', '?')} MHz; medians of the repetitions; rates from CPU time\n")
    target = None
    for n in (10000, 100000):
        print(f"N = {n:,} vertices, U16 weights, u8 joints (64 bones), unnormalised normals\n")
        print("| influences | attrs | plain loop Mvert/s | kernel Mvert/s | kernel / plain | target (1.5x ozz/plain) "
              "| vs target | kernel GB/s | triad GB/s | fraction of triad |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for i in (1, 2, 4, 8):
            for nn in (0, 1):
                p = r.get(f"BM_PlainLoop/{i}/{nn}/{n}")
                k = r.get(f"BM_Kernel/{i}/{nn}/{n}/1/0")
                t = r.get(f"BM_Triad/{i}/{nn}/{n}")
                if not (p and k and t):
                    continue
                target = target or k.get("label", "")
                ratio = k["Mvert/s"] / p["Mvert/s"]
                goal = 1.5 * OZZ_OVER_PLAIN[(i, nn)]
                print(f"| {i} | {'P+N' if nn else 'P'} | {p['Mvert/s']:.0f} | {k['Mvert/s']:.0f} | {ratio:.2f} | "
                      f"{goal:.2f} | {ratio / goal:.2f} | {k['GB/s']:.1f} | {t['GB/s']:.1f} | "
                      f"{k['GB/s'] / t['GB/s']:.2f} |")
        print()
    print(f"SIMD target: {target}\n")
    print("Other weight formats and renormalised normals, N = 100,000, P+N:\n")
    print("| influences | variant | kernel Mvert/s | kernel / plain |")
    print("|---|---|---|---|")
    for i in (1, 2, 4, 8):
        p = r.get(f"BM_PlainLoop/{i}/1/100000")
        for f, ren, label in ((1, 0, "U16"), (1, 1, "U16, renormalised"), (0, 0, "F32"), (2, 0, "U8")):
            k = r.get(f"BM_Kernel/{i}/1/100000/{f}/{ren}")
            if k and p:
                print(f"| {i} | {label} | {k['Mvert/s']:.0f} | {k['Mvert/s'] / p['Mvert/s']:.2f} |")
    print()
    print("Per SIMD target (forced), N = 100,000, 4 influences, U16:\n")
    print("| target | attrs | kernel Mvert/s | kernel / plain | target (1.5x ozz/plain) |")
    print("|---|---|---|---|---|")
    for t in range(5):
        for nn in (0, 1):
            k = r.get(f"BM_KernelPerTarget/{t}/{nn}")
            p = r.get(f"BM_PlainLoop/4/{nn}/100000")
            if k and p and "error_occurred" not in k:
                print(f"| {k.get('label', t)} | {'P+N' if nn else 'P'} | {k['Mvert/s']:.0f} | "
                      f"{k['Mvert/s'] / p['Mvert/s']:.2f} | {1.5 * OZZ_OVER_PLAIN[(4, nn)]:.2f} |")
    print()
    for a, label in ((2, "nothing (palettes only)"), (0, "skin_many"), (1, "SkinningJob::run")):
        c = r.get(f"BM_ClientFrame/{a}")
        if c:
            print(f"client frame, 100 Fox + 100 CesiumMan ({c['verts']:.0f} vertices), palettes + {label}: "
                  f"{c['cpu_time']:.0f} {c['time_unit']} per frame (CPU), {c['Mvert/s']:.0f} Mvert/s")


if __name__ == "__main__":
    main()

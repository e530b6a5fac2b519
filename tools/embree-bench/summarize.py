#!/usr/bin/env python3
"""Summarizes the RESULT lines of run.sh (out/results.txt): per configuration, the median over
rounds of each round's median; Embree's fastest trace mode per (model, res, threads); the
ratio Embree ms / our ms (> 1: ours is faster)."""
import statistics
import sys
from collections import defaultdict

rows = []
for line in open(sys.argv[1] if len(sys.argv) > 1 else "out/results.txt"):
    if line.startswith("RESULT "):
        rows.append(dict(kv.split("=", 1) for kv in line.split()[1:]))

med = defaultdict(list)
extra = {}
for r in rows:
    key = (r["tracer"], r["model"], r["res"], r["threads"], r["what"])
    med[key].append(float(r["median_ms"]))
    extra[key] = r
m = {k: statistics.median(v) for k, v in med.items()}
rounds = {k: len(v) for k, v in med.items()}

print("## All configurations (ms: median over rounds of per-round medians)\n")
print("| tracer | model | res | threads | what | ms | FPS | Mrays/s | rounds | hits |")
print("|---|---|---|---|---|---:|---:|---:|---:|---:|")
for k in sorted(m):
    t, model, res, th, what = k
    ms = m[k]
    fps = 1e3 / ms
    mr = f"{int(res) ** 2 / ms / 1e3:.2f}" if res != "-" else ""
    print(f"| {t} | {model} | {res} | {th} | {what} | {ms:.2f} | {fps:.1f} | {mr} | {rounds[k]} | {extra[k].get('hits', '')} |")

def against_embree(tracer):
    """Per (model, res, threads) with both: our render and ids ms, Embree's fastest mode and ms."""
    for model in ("footprint", "voxel"):
        for res in ("1024", "512"):
            for th in ("1", "2"):
                o = m.get((tracer, model, res, th, "render"))
                oi = m.get((tracer, model, res, th, "ids"))
                emb = [(v, k[0]) for k, v in m.items() if k[0].startswith("embree-") and k[0] != "embree-build" and k[1:4] == (model, res, th)]
                if o is not None and emb:
                    e, mode = min(emb)
                    yield model, res, th, o, oi, e, mode, int(res) ** 2


print("\n## Ours vs Embree (fastest Embree mode per row)\n")
print("| model | res | threads | ours render ms (FPS, Mrays/s) | ours ids ms | Embree best mode | Embree ms (FPS, Mrays/s) | Embree / ours render | hit px ours / Embree | same prim |")
print("|---|---|---|---|---:|---|---|---:|---|---:|")
for model, res, th, o, oi, e, mode, rays in against_embree("ours-packet"):
    x = extra[(mode, model, res, th, "trace")]
    print(f"| {model} | {res}² | {th} | {o:.1f} ({1e3 / o:.1f}, {rays / o / 1e3:.2f}) | {oi:.1f} | {mode} | {e:.1f} ({1e3 / e:.1f}, {rays / e / 1e3:.2f}) | {e / o:.2f} | {x['our_hits']} / {x['hits']} | {x['same_prim']} |")

print("\n## The default renderer (`spheres`, client path: unbuilt scene, shaded) vs Embree\n")
print("| model | res | threads | spheres render ms (FPS, Mrays/s) | splat-tiles ids ms (built scene) | Embree best mode | Embree ms (FPS) | Embree / spheres render | Embree / splat ids |")
print("|---|---|---|---|---:|---|---|---:|---:|")
for model, res, th, o, oi, e, mode, rays in against_embree("ours-spheres"):
    print(f"| {model} | {res}² | {th} | {o:.1f} ({1e3 / o:.1f}, {rays / o / 1e3:.2f}) | {oi:.1f} | {mode} | {e:.1f} ({1e3 / e:.1f}) | {e / o:.2f} | {e / oi:.2f} |")

print("\n## BVH build (ms)\n")
print("| model | threads | ours (ParallelBuilder, whole scene build) | Embree rtcCommitScene (SPHERE_POINT, default quality) | Embree / ours |")
print("|---|---|---:|---:|---:|")
for model in ("footprint", "voxel"):
    for th in ("1", "2"):
        o = m.get(("ours-lbvh", model, "-", th, "build"))
        e = m.get(("embree-build", model, "-", th, "build"))
        if o and e:
            print(f"| {model} | {th} | {o:.1f} | {e:.1f} | {e / o:.1f} |")

"""The table and plot of `scripts/load.sh`: OUT_DIR/load.md and, with matplotlib,
OUT_DIR/load.png, from the loadgen reports in OUT_DIR/runs.

    python3 scripts/lib/load_report.py OUT_DIR
"""
import glob, json, os, sys
out = sys.argv[1]
rows = []
for path in glob.glob(os.path.join(out, "runs", "*.json")):
    r = json.load(open(path))
    name = os.path.basename(path)[:-5].rsplit("-", 1)[0]
    s = r.get("server") or {}
    rows.append((name, r["robots"], r))
rows.sort(key=lambda t: (t[0], t[1]))
lines = ["| profile | robots | admitted at a time | scores/s per robot | dropped | p50 / p99 latency | server CPU (cores) | refused opens | RSS peak |",
         "|---|---|---|---|---|---|---|---|---|"]
for name, n, r in rows:
    s = r.get("server") or {}
    lat = r["latency_ms"]
    rate = r["image_rate_hz_per_robot"]
    admitted = r["scores_per_s"] / rate if rate else float("nan")
    lines.append(f"| {name} | {n} | {admitted:.1f} | {r['scores_per_s_per_robot']:.2f} | {r['dropped_reported']} | "
                 f"{lat['p50']} / {lat['p99']} ms | {s.get('cpu_cores_busy', float('nan')):.2f} | {r['error_count']} | {s.get('rss_mib_peak')} MiB |")
stages = {}
for name, n, r in rows:
    if n == 1:
        stages[name] = (r.get("server") or {}).get("stage_ms", {})
lines.append("")
lines.append("Mean ms per frame of each stage, one robot:")
lines.append("")
keys = sorted({k for v in stages.values() for k in v}, key=lambda k: -max(v.get(k, 0) for v in stages.values()))
lines.append("| profile | " + " | ".join(keys) + " |")
lines.append("|---" * (len(keys) + 1) + "|")
for name, v in sorted(stages.items()):
    lines.append(f"| {name} | " + " | ".join(str(v.get(k, "")) for k in keys) + " |")
open(os.path.join(out, "load.md"), "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
try:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    sys.exit(0)
fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
for name in sorted({t[0] for t in rows}):
    pts = [(n, r) for m, n, r in rows if m == name]
    ns = [n for n, _ in pts]
    a.plot(ns, [r["latency_ms"]["p50"] for _, r in pts], "o-", label=f"{name} p50")
    a.plot(ns, [r["latency_ms"]["p99"] for _, r in pts], "s--", label=f"{name} p99")
    b.plot(ns, [(r.get("server") or {}).get("cpu_cores_busy", 0) for _, r in pts], "o-", label=name)
a.set_xlabel("robots streaming 10 Hz"); a.set_ylabel("latency, ms"); a.set_yscale("log"); a.legend(fontsize=8)
b.set_xlabel("robots streaming 10 Hz"); b.set_ylabel("server CPU, cores"); b.axhline(1.6, color="gray", ls=":", label="admission_load x workers"); b.legend(fontsize=8)
fig.tight_layout()
fig.savefig(os.path.join(out, "load.png"), dpi=100)

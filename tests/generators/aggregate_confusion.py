"""Pool several run_confusion.py outputs into one table: detection and exact naming against SNR, per effect,
and the verdicts on effect-free draws.

    python tests/generators/aggregate_confusion.py /tmp/palpate-indep-seed2 \
        /tmp/palpate-indep-seed3 ... -o /tmp/palpate-indep-pooled.md

Every input is a folder with a confusion.json; draws keep the scores run_confusion.py gave them (run it with
--rescore first when the harness's name mapping changed). The binary of each folder (sha256) is listed, so a
reader sees which palpate each row measured.
"""
import argparse
import json
import math
import os

SNR_BINS = [0, 3, 10, 30, 100, math.inf]


def bin_of(snr):
    for lo, hi in zip(SNR_BINS, SNR_BINS[1:]):
        if lo <= snr < hi:
            return f"{lo}-{hi}" if hi != math.inf else f">={lo}"
    return "?"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", nargs="+")
    ap.add_argument("-o", "--out", required=True)
    a = ap.parse_args()
    rows, sources = [], []
    for f in a.folders:
        d = json.load(open(os.path.join(f, "confusion.json")))
        meta = d.get("meta", {})
        sources.append((f, meta.get("palpate_sha256", "?")[:12], len(d["rows"])))
        rows += [dict(r, source=f) for r in d["rows"] if r.get("verdict") not in (None, "error", "timeout")]
    effect = [r for r in rows if r["effect"] != "none"]
    none = [r for r in rows if r["effect"] == "none"]
    out = ["# Pooled confusion table of the independent generator", ""]
    out.append("| folder | palpate sha256 | draws |")
    out.append("|---|---|---|")
    out += [f"| `{f}` | {s} | {n} |" for f, s, n in sources]
    out.append("")
    named = sum(r["named_exact"] for r in effect)
    detected = sum(r["detected"] for r in effect)
    false_clean = sum(r["false_clean"] and r["snr"] > 5 for r in effect)
    out.append(f"Draws: {len(rows)} scored ({len(effect)} with an effect, {len(none)} without). "
               f"Detected (verdict not clean): {detected}/{len(effect)}; named exactly: {named}/{len(effect)}; "
               f"false clean at SNR > 5: {false_clean}. Effect-free draws: "
               + ", ".join(f"{r['id']} {r['verdict']} ({r['ratio']:.2f}×)" for r in none) + ".")
    times = sorted(r["palpate_seconds"] for r in rows if r.get("palpate_seconds") is not None)
    if times:
        out.append(f"palpate wall time per diagnosis: median {times[len(times) // 2]:.0f} s, max {times[-1]:.0f} s "
                   "(as each folder's run measured it, with whatever else ran beside it).")
    # The same table twice: binned by the harness's SNR, then by the SNR on displacements.
    for title, snr in [("Against SNR (positions; the harness's definition)", "snr"),
                       ("Against SNR on displacements (a shift common to rest scan and measurements left out)",
                        "snr_displacement")]:
        out += ["", f"## {title}", "",
                "| SNR bin | draws | detected | named exactly |", "|---|---|---|---|"]
        for lo, hi in zip(SNR_BINS, SNR_BINS[1:]):
            b = [r for r in effect if lo <= r[snr] < hi]
            if b:
                out.append(f"| {bin_of(lo)} | {len(b)} | {sum(r['detected'] for r in b)} | {sum(r['named_exact'] for r in b)} |")
    out += ["", "## Per effect", "", "| effect | draws | detected | named exactly | what palpate adopted |", "|---|---|---|---|---|"]
    for eff in sorted({r["effect"] for r in effect}):
        b = [r for r in effect if r["effect"] == eff]
        said = "; ".join(", ".join(r["adopted"]) or r["verdict"] for r in b)
        out.append(f"| {eff} | {len(b)} | {sum(r['detected'] for r in b)} | {sum(r['named_exact'] for r in b)} | {said} |")
    with open(a.out, "w") as fh:
        fh.write("\n".join(out) + "\n")
    print("\n".join(out[: 12]))


if __name__ == "__main__":
    main()

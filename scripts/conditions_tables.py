#!/usr/bin/env python3
"""Markdown tables of an `eval places` report with conditions (`report.json`).

    python3 scripts/conditions_tables.py OUT/report.json [--metric nearest|r1@R|f1]

prints one table of conditions x methods for the chosen metric (default: R@1 within the first
threshold), then one table per method of conditions x every metric: R@1 (queries with a match)
within each threshold, the nearest database scan, loop-closure F1 max and recall at 100 %
precision. Figures in %, one decimal; "n/a" where a condition does not apply.
"""

import argparse
import json


def metrics_of(condition, thresholds):
    """(name, value) of every metric of one condition entry; value None when not applicable."""
    if condition.get("not_applicable"):
        return [(f"R@1 {t:g} m", None) for t in thresholds] + [("nearest", None), ("F1 max", None), ("R@P100", None)]
    out = []
    for result in condition["results"]:
        with_match = result["with_match"]
        value = with_match["at_n"][0] if with_match["evaluated"] > 0 else None
        out.append((f"R@1 {result['threshold_m']:g} m", value))
    closure = condition["loop_closure"]["result"]
    out.append(("nearest", condition["nearest"]["recall_at_1"]))
    out.append(("F1 max", closure["f1_max"]))
    out.append(("R@P100", closure["recall_at_full_precision"]))
    return out


def cell(value):
    return "n/a" if value is None else f"{value:.1f}"


def table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("report")
    parser.add_argument("--metric", help="nearest, f1, or r1@R (R a threshold in m); default r1 at the first threshold")
    args = parser.parse_args()
    with open(args.report) as f:
        report = json.load(f)
    methods = report["methods"]
    thresholds = [r["threshold_m"] for r in methods[0]["results"]]
    names = [c["condition"] for c in methods[0]["conditions"]]
    wanted = args.metric or f"r1@{thresholds[0]:g}"
    label = {"nearest": "nearest", "f1": "F1 max"}.get(wanted, f"R@1 {wanted.removeprefix('r1@')} m")

    def value(method, i):
        return dict(metrics_of(method["conditions"][i], thresholds)).get(label)

    print(f"{label} (%)\n")
    rows = [[name] + [cell(value(m, i)) for m in methods] for i, name in enumerate(names)]
    print(table(["condition"] + [m["method"] for m in methods], rows))
    for m in methods:
        print(f"\n{m['method']} (%)\n")
        per = [metrics_of(c, thresholds) for c in m["conditions"]]
        header = ["condition"] + [n for n, _ in per[0]]
        print(table(header, [[name] + [cell(v) for _, v in row] for name, row in zip(names, per)]))


if __name__ == "__main__":
    main()

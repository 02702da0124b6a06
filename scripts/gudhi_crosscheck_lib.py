"""Helpers of the GUDHI cross-check scripts: parse `toporec diagram` output, match diagrams."""
import numpy as np

TOL = 1e-12


def rel(a, b):
    if a == b:
        return 0.0
    if not (np.isfinite(a) and np.isfinite(b)):
        return float("inf")
    return abs(a - b) / max(abs(a), abs(b))


def match(ours, ref):
    """The largest relative difference of a one-to-one matching (None when there is none)."""
    worst = 0.0
    for d in range(3):
        if len(ours[d]) != len(ref[d]):
            return None
        used = [False] * len(ref[d])
        for i, p in enumerate(ours[d]):
            # Sorted alike, pairs mostly sit at the same rank.
            e = max(rel(p[0], ref[d][i][0]), rel(p[1], ref[d][i][1]))
            if not used[i] and e <= TOL:
                used[i] = True
                worst = max(worst, e)
                continue
            best = None
            for j in range(max(0, i - 64), min(len(ref[d]), i + 65)):
                if not used[j]:
                    e = max(rel(p[0], ref[d][j][0]), rel(p[1], ref[d][j][1]))
                    if e <= TOL and (best is None or e < best[0]):
                        best = (e, j)
            if best is None:
                return None
            used[best[1]] = True
            worst = max(worst, best[0])
    return worst




def toporec_diagram(text):
    """Per-dimension sorted (birth, death) lists from `toporec diagram`'s CSV."""
    dims = [[], [], []]
    for line in text.splitlines()[1:]:
        d, b, e = line.split(",")
        dims[int(d)].append((float(b), float(e)))
    return [sorted(x) for x in dims]

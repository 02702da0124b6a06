"""toporec from Python, in five steps: load a scan, get its persistence diagram, plot it,
index the sample drive, query it.

Run from the repository root after `pip install ./python`:

    python3 python/examples/quickstart.py

It writes its plot and index under out/quickstart/.
"""

import pathlib

import matplotlib

matplotlib.use("Agg")  # no display needed
import matplotlib.pyplot as plt
import numpy as np

import toporec

REPO = pathlib.Path(__file__).resolve().parents[2]
OUT = REPO / "out" / "quickstart"
OUT.mkdir(parents=True, exist_ok=True)

# 1. Load a scan: NCLT's velodyne_sync format is 8 bytes per point, x/y/z as uint16 with a
#    scale of 5 mm and an offset of -100 m.
scan = sorted((REPO / "samples" / "town" / "velodyne_data" / "2026-01-01" / "velodyne_sync").glob("*.bin"))[0]
raw = np.frombuffer(scan.read_bytes(), dtype=[("x", "<u2"), ("y", "<u2"), ("z", "<u2"), ("i", "u1"), ("l", "u1")])
points = np.stack([raw[c] * 0.005 - 100.0 for c in "xyz"], axis=1)
points = points[np.linalg.norm(points, axis=1) > 0.5]  # drop returns at the sensor
print(f"{scan.name}: {len(points)} points")

# 2. Its persistence diagram (squared radii, as GUDHI's AlphaComplex).
diagram = toporec.alpha_persistence(points)
for dim, pairs in diagram.items():
    print(f"  H{dim}: {len(pairs)} pairs")

# 3. Plot it.
fig, ax = plt.subplots(figsize=(4, 4))
for dim, colour in zip((0, 1, 2), ("tab:blue", "tab:orange", "tab:green")):
    pairs = diagram[dim][np.isfinite(diagram[dim][:, 1])]
    ax.scatter(pairs[:, 0], pairs[:, 1], s=4, color=colour, label=f"H{dim}")
top = max(float(np.nanmax(diagram[d][np.isfinite(diagram[d])])) for d in (0, 1, 2))
ax.plot([0, top], [0, top], color="grey", linewidth=0.5)
ax.set_xlabel("birth (m²)")
ax.set_ylabel("death (m²)")
ax.legend()
fig.tight_layout()
fig.savefig(OUT / "diagram.png", dpi=120)
print(f"plot: {OUT / 'diagram.png'}")

# 4. Index the sample drive (two sessions) as `toporec run pipelines/sample.toml` does.
summary = toporec.run(REPO / "pipelines" / "sample.toml", index=OUT / "index", full=True)
print(f"indexed {summary['scans']['indexed']} scans, descriptor length {summary['descriptor_length']}")

# 5. Query it with the scan of step 1 (described as the index describes its scans).
index = toporec.Index(OUT / "index")
hits = index.query(points, k=3)
for row in hits.to_pylist():
    print(f"  rank {row['rank']}: {row['scan_id']} at distance {row['distance']:.3f}")
assert hits["scan_id"][0].as_py() == f"2026-01-01/{scan.stem}", "the scan should find itself first"
print(index.descriptors().select(["scan_id", "session", "dim_used"]).slice(0, 3))

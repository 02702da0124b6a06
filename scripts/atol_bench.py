"""Reference side of benches/atol.rs: GUDHI's Atol transform with the same centres and
scikit-learn's MiniBatchKMeans fit on the same points, single thread."""
import os, sys, time

os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np
from gudhi.representations import Atol
from sklearn.cluster import MiniBatchKMeans

d = sys.argv[1]
measure = np.loadtxt(f"{d}/measure.csv", delimiter=",")
centers = np.loadtxt(f"{d}/centers.csv", delimiter=",")
big = np.loadtxt(f"{d}/big.csv", delimiter=",")


class Fixed:
    n_clusters = len(centers)

    def fit(self, X, sample_weight=None):
        self.cluster_centers_ = centers
        return self


atol = Atol(Fixed(), contrast="laplacian").fit([measure])
times = []
for _ in range(7):
    t = time.perf_counter()
    atol(measure)
    times.append((time.perf_counter() - t) * 1e3)
print(f"GUDHI Atol transform 10,000 points, b = 1000: median {np.median(times):.1f} ms")
times = []
for seed in range(3):
    t = time.perf_counter()
    km = MiniBatchKMeans(n_clusters=50, random_state=seed).fit(big)
    times.append((time.perf_counter() - t) * 1e3)
    if seed == 0:
        inertia = ((big[:, None, :] - km.cluster_centers_[None]) ** 2).sum(-1).min(1).sum()
        print(f"  sklearn fit inertia (seed 0): {inertia:.6e}")
print(f"sklearn MiniBatchKMeans 1,000,000 points, b = 50: median {np.median(times):.0f} ms")

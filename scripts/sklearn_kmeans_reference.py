"""Reference inertias for tests/codebook.rs: scikit-learn 1.9.1 MiniBatchKMeans (mean over
random_state 0..19) and KMeans (Lloyd, random_state=0, n_init=1) on the finite points of the
fixture diagrams. Run from the repository root: python3 scripts/sklearn_kmeans_reference.py"""
import numpy as np
from sklearn.cluster import KMeans, MiniBatchKMeans

for name in ["uniform_cube_4096"]:
    rows = np.genfromtxt(f"tests/fixtures/diagrams/{name}.csv", delimiter=",", skip_header=1)
    for dim in [1, 2]:
        X = rows[(rows[:, 0] == dim) & np.isfinite(rows[:, 2])][:, 1:]
        for b in [10, 50]:
            inertias = []
            for seed in range(20):
                c = MiniBatchKMeans(n_clusters=b, random_state=seed).fit(X).cluster_centers_
                inertias.append(((X[:, None, :] - c[None]) ** 2).sum(-1).min(1).sum())
            lloyd = KMeans(n_clusters=b, random_state=0, n_init=1).fit(X).inertia_
            spread = np.std(inertias) / np.mean(inertias)
            print(f'("{name}", {dim}, {b}, {np.mean(inertias)!r}, {lloyd!r}),  # per-seed sd {spread:.3f}')

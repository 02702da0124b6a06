#!/usr/bin/env python3
"""A transcription of the PointNetVLAD benchmark's `generating_queries/generate_test_sets.py`
and `evaluate.py` (Uy & Lee, CVPR 2018), the cross-check of `toporec eval places --protocol
pointnetvlad`.

Reads the benchmark folder as it ships (`oxford/<run>/pointcloud_locations_20m.csv`,
`inhouse_datasets/<run>/pointcloud_centroids_25.csv`) and one method's descriptors from a
toporec index (`descriptors/method=<m>/session=<run>/*.parquet`, rows `scan_id` = `<run>/<timestamp>`),
builds the test sets (regions, 25 m positives by a KD-tree radius query) and evaluates every
ordered run pair with a KD-tree over the database descriptors (25 neighbours), as the reference
does. Prints JSON: {dataset: {"recall_at_n": [...25], "recall_at_one_percent": x, "pairs": n}}.

Run: `python3 scripts/pointnetvlad_reference.py BENCHMARK_ROOT INDEX METHOD`; needs numpy,
pyarrow, scikit-learn.
"""
import glob
import json
import os
import sys

import numpy as np
import pyarrow.parquet as pq
from sklearn.neighbors import KDTree

OXFORD_RUNS = [5, 6, 7, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 22, 24, 31, 32, 33, 38, 39, 43, 44]
P1 = [5735712.768124, 620084.402381]
P2 = [5735611.299219, 620540.270327]
P3 = [5735237.358209, 620543.094379]
P4 = [5734749.303802, 619932.693364]
P5 = [363621.292362, 142864.19756]
P6 = [364788.795462, 143125.746609]
P7 = [363597.507711, 144011.414174]
P8 = [360895.486453, 144999.915143]
P9 = [362357.024536, 144894.825301]
P10 = [361368.907155, 145209.663042]


def read_csv(path):
    rows = []
    with open(path) as f:
        for line in f:
            fields = line.strip().split(",")
            if len(fields) < 3:
                continue
            try:
                rows.append((int(fields[0]), float(fields[1]), float(fields[2])))
            except ValueError:
                continue  # the header
    return rows


def check_in_test_set(northing, easting, points, x_width=150, y_width=150):
    for point in points:
        if point[0] - x_width < northing < point[0] + x_width and point[1] - y_width < easting < point[1] + y_width:
            return True
    return False


def descriptors(index, method, run):
    out = {}
    for path in sorted(glob.glob(os.path.join(index, "descriptors", f"method={method}", f"session={run}", "*.parquet"))):
        table = pq.read_table(path, columns=["scan_id", "descriptor"]).to_pydict()
        for sid, vec in zip(table["scan_id"], table["descriptor"]):
            out[sid] = np.asarray(vec, dtype=np.float64)
    return out


def construct_sets(folders, csvs, regions):
    """generate_test_sets.construct_query_and_database_sets: per run, the database (every row)
    and the queries (rows in the regions, or all), with positives per other run."""
    database_trees, database_sets, test_sets = [], [], []
    for rows in csvs:
        database, test = {}, {}
        for timestamp, northing, easting in rows:
            database[len(database)] = {"timestamp": timestamp, "northing": northing, "easting": easting}
            if regions is None or check_in_test_set(northing, easting, regions):
                test[len(test)] = {"timestamp": timestamp, "northing": northing, "easting": easting}
        coords = np.array([[r[1], r[2]] for r in rows])
        database_trees.append(KDTree(coords))
        database_sets.append(database)
        test_sets.append(test)
    for i in range(len(database_sets)):
        tree = database_trees[i]
        for j in range(len(test_sets)):
            if i == j:
                continue
            for key in range(len(test_sets[j])):
                coor = np.array([[test_sets[j][key]["northing"], test_sets[j][key]["easting"]]])
                index = tree.query_radius(coor, r=25)
                test_sets[j][key][i] = index[0].tolist()
    return database_sets, test_sets


def get_recall(m, n, database_vectors, query_vectors, query_sets):
    """evaluate.get_recall."""
    database_output = database_vectors[m]
    queries_output = query_vectors[n]
    database_nbrs = KDTree(database_output)
    num_neighbors = 25
    recall = [0] * num_neighbors
    one_percent_retrieved = 0
    threshold = max(int(round(len(database_output) / 100.0)), 1)
    num_evaluated = 0
    for i in range(len(queries_output)):
        true_neighbors = query_sets[n][i][m]
        if len(true_neighbors) == 0:
            continue
        num_evaluated += 1
        distances, indices = database_nbrs.query(np.array([queries_output[i]]), k=min(num_neighbors, len(database_output)))
        for j in range(len(indices[0])):
            if indices[0][j] in true_neighbors:
                recall[j] += 1
                break
        if len(list(set(indices[0][0:threshold]).intersection(set(true_neighbors)))) > 0:
            one_percent_retrieved += 1
    if num_evaluated == 0:
        return None
    one_percent_recall = (one_percent_retrieved / float(num_evaluated)) * 100
    recall = (np.cumsum(recall) / float(num_evaluated)) * 100
    return recall, one_percent_recall


def evaluate(root, index, method, name, runs, csv_name, regions):
    csvs = [read_csv(os.path.join(run, csv_name)) for run in runs]
    database_sets, query_sets = construct_sets(runs, csvs, regions)
    names = [os.path.basename(run) for run in runs]
    vectors = [descriptors(index, method, r) for r in names]
    database_vectors = [np.array([vectors[k][f"{names[k]}/{database_sets[k][i]['timestamp']}"] for i in range(len(database_sets[k]))]) for k in range(len(runs))]
    query_vectors = [np.array([vectors[k][f"{names[k]}/{query_sets[k][i]['timestamp']}"] for i in range(len(query_sets[k]))]) for k in range(len(runs))]
    recall = np.zeros(25)
    one_percent = []
    count = 0
    for m in range(len(runs)):
        for n in range(len(runs)):
            if m == n:
                continue
            r = get_recall(m, n, database_vectors, query_vectors, query_sets)
            if r is None:
                continue
            pair_recall, pair_one_percent = r
            recall += np.array(pair_recall)
            one_percent.append(pair_one_percent)
            count += 1
    return {"recall_at_n": (recall / count).tolist(), "recall_at_one_percent": float(np.mean(one_percent)), "pairs": count}


def main(root, index, method):
    out = {}
    oxford_dir = os.path.join(root, "oxford")
    if os.path.isdir(oxford_dir):
        folders = sorted(os.listdir(oxford_dir))
        if len(folders) > OXFORD_RUNS[-1]:
            runs = [os.path.join(oxford_dir, folders[i]) for i in OXFORD_RUNS]
            out["oxford"] = evaluate(root, index, method, "oxford", runs, "pointcloud_locations_20m.csv", [P1, P2, P3, P4])
    inhouse_dir = os.path.join(root, "inhouse_datasets")
    if os.path.isdir(inhouse_dir):
        folders = sorted(os.listdir(inhouse_dir))
        for name, first, regions in [("business", 0, None), ("residential", 5, [P8, P9, P10]), ("university", 10, [P5, P6, P7])]:
            if len(folders) >= first + 5:
                runs = [os.path.join(inhouse_dir, f) for f in folders[first:first + 5]]
                out[name] = evaluate(root, index, method, name, runs, "pointcloud_centroids_25.csv", regions)
    print(json.dumps(out))


if __name__ == "__main__":
    main(*sys.argv[1:4])

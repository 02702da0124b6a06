//! ATOL against `gudhi.representations.Atol` 3.13 output for given centres.

use crate::util::*;
use toporec::vectorize::atol::{Atol, Contrast, Point2, Weighting};

/// Stated tolerance of the acceptance: 1e-12 relative (absolute for exact zeros).
const TOL: f64 = 1e-12;

fn assert_close(a: &[f64], b: &[f64], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: length");
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        let ok = if *y == 0.0 { x.abs() <= TOL } else { ((x - y) / y).abs() <= TOL };
        assert!(ok, "{what}[{k}]: {x} vs {y}");
    }
}

fn json(path: &str) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(root().join(path)).unwrap()).unwrap()
}

fn points(v: &serde_json::Value) -> Vec<Point2> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|p| [p[0].as_f64().unwrap_or(f64::INFINITY), p[1].as_f64().unwrap_or(f64::INFINITY)])
        .collect()
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

fn contrast(name: &str) -> Contrast {
    match name {
        "gaussian" => Contrast::Gaussian,
        "laplacian" => Contrast::Laplacian,
        _ => Contrast::Indicator,
    }
}

#[test]
fn fixed_centres_inertias_and_all_contrasts_match_gudhi() {
    let f = json("tests/fixtures/atol/atol_fixed_centers.json");
    let centres = points(&f["centers"]);
    assert_eq!(f["diagram_dim"], 2);
    for c in ["gaussian", "laplacian", "indicator"] {
        let model = Atol::from_centers(centres.clone(), 8, &[], contrast(c), Weighting::Cloud).unwrap();
        assert_eq!(model.centers, centres, "fixture centres are already in lexsort order");
        assert_close(&model.inertias, &floats(&f["inertias"]), "inertias");
        let vectors = f["vectors"][c].as_object().unwrap();
        // One vector per fixture cloud with an H2 diagram (the planar cloud has none).
        assert_eq!(vectors.len(), 7);
        for (cloud, expected) in vectors {
            let diagram = read_diagram_csv(&root().join(format!("tests/fixtures/diagrams/{cloud}.csv")));
            let h2: Vec<Point2> = diagram[2].iter().map(|p| [p.0, p.1]).collect();
            assert_close(&model.transform(&h2), &floats(expected), &format!("{c}/{cloud}"));
        }
    }
}

#[test]
fn golden_lexsort_inertias_and_vectors_every_contrast_and_weighting() {
    let g = json("tests/fixtures/golden/alpha_atol_golden.json");
    let raw = points(&g["atol"]["raw_centers_from_quantiser"]);
    let diagrams: Vec<Vec<Point2>> = (0..3).map(|d| points(&g["diagrams_exact"][d.to_string()])).collect();
    assert!(diagrams[0].iter().any(|p| p[1].is_infinite()), "H0 carries its (0, inf) point");
    for (key, res) in g["atol"]["results"].as_object().unwrap() {
        let (c, w) = key.split_once('/').unwrap();
        let weighting = if w == "cloud" { Weighting::Cloud } else { Weighting::Iidproba };
        let model = Atol::from_centers(raw.clone(), 5, &[], contrast(c), weighting).unwrap();
        assert_eq!(model.centers, points(&res["centers_after_lexsort"]), "{key}");
        assert_close(&model.inertias, &floats(&res["inertias"]), key);
        for (d, expected) in res["vectors_dim0_dim1_dim2"].as_array().unwrap().iter().enumerate() {
            assert_close(&model.transform(&diagrams[d]), &floats(expected), &format!("{key} H{d}"));
        }
    }
}

#[test]
fn degenerate_models_follow_gudhi() {
    // One centre: σ = half the diameter of the fitted points (1 if that is 0).
    let pts = [[0.0, 1.0], [3.0, 5.0], [1.0, 1.0]];
    let m = Atol::from_centers(vec![[1.0, 2.0]], 1, &pts, Contrast::Laplacian, Weighting::Cloud).unwrap();
    assert_eq!(m.inertias, vec![2.5]);
    let m = Atol::from_centers(vec![[1.0, 2.0]], 1, &[[1.0, 1.0]], Contrast::Laplacian, Weighting::Cloud)
        .unwrap();
    assert_eq!(m.inertias, vec![1.0]);
    // Too few points: filler centres (inf, inf) with σ = 0; finite points give 0 there, an
    // infinite point NaN (GUDHI's inf − inf).
    let m = Atol::from_centers(vec![[0.0, 1.0], [0.0, 3.0]], 4, &[], Contrast::Gaussian, Weighting::Cloud)
        .unwrap();
    assert_eq!(m.centers[2], [f64::INFINITY; 2]);
    assert_eq!(m.inertias, vec![1.0, 1.0, 0.0, 0.0]);
    let v = m.transform(&[[0.0, 1.0]]);
    assert_eq!(v[..2], [1.0, (-4.0f64).exp()]);
    assert_eq!(v[2..], [0.0, 0.0]);
    assert!(m.transform(&[[0.0, f64::INFINITY]])[2].is_nan());
    // Identical centres: σ = +inf. Empty measure: zeros.
    let m = Atol::from_centers(vec![[1.0, 1.0], [1.0, 1.0]], 2, &[], Contrast::Laplacian, Weighting::Cloud)
        .unwrap();
    assert_eq!(m.inertias, vec![f64::INFINITY; 2]);
    assert_eq!(m.transform(&[]), vec![0.0, 0.0]);
}

//! ATOL benchmark: transform of a 10,000-point diagram with b = 1000 (design goal < 50 ms on one
//! core) and a b = 50 mini-batch fit on 1,000,000 diagram points (design goal < 2 s), then the same
//! two jobs in GUDHI / scikit-learn on the same data (`scripts/atol_bench.py`) when available.
//!
//! Run: `cargo bench --bench atol`.

use std::path::Path;
use std::process::Command;
use std::time::Instant;
use toporec::rng::SplitMix64;
use toporec::vectorize::atol::{Atol, Contrast, Point2, Weighting};
use toporec::vectorize::kmeans::{self, KMeansParams};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // A real diagram: H1 of the uniform_cube_4096 fixture (11,054 pairs), first 10,000.
    let text = std::fs::read_to_string(root.join("tests/fixtures/diagrams/uniform_cube_4096.csv")).unwrap();
    let diagram = toporec::diagram_csv::parse(&text).unwrap();
    let measure: Vec<Point2> = diagram.dimension(1).iter().take(10_000).map(|p| [p.birth, p.death]).collect();
    // 1,000,000 fit points: the diagram's points, jittered by 1 % (seeded).
    let mut rng = SplitMix64(11);
    let big: Vec<Point2> = (0..1_000_000)
        .map(|i| {
            let p = measure[i % measure.len()];
            [p[0] * (1.0 + 0.01 * (rng.next_f64() - 0.5)), p[1] * (1.0 + 0.01 * (rng.next_f64() - 0.5))]
        })
        .collect();
    let ones = vec![1.0; big.len()];

    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| {
        let centers =
            kmeans::fit(&measure, &vec![1.0; measure.len()], 1000, &KMeansParams::default(), 0).unwrap();
        let model =
            Atol::from_centers(centers, 1000, &measure, Contrast::Laplacian, Weighting::Cloud).unwrap();
        let times: Vec<f64> = (0..15)
            .map(|_| {
                let t = Instant::now();
                std::hint::black_box(model.transform(&measure));
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        println!(
            "transform  10,000 points, b = 1000, laplacian: median {:.1} ms (design goal < 50 ms)",
            median(times)
        );
        let tmp = root.join("target/tmp/bench-atol");
        std::fs::create_dir_all(&tmp).unwrap();
        let dump = |name: &str, pts: &[Point2]| {
            let s: String = pts.iter().map(|p| format!("{:?},{:?}\n", p[0], p[1])).collect();
            std::fs::write(tmp.join(name), s).unwrap();
        };
        dump("measure.csv", &measure);
        dump("centers.csv", &model.centers);
        dump("big.csv", &big);

        let times: Vec<f64> = (0..5)
            .map(|seed| {
                let t = Instant::now();
                let c = kmeans::fit(&big, &ones, 50, &KMeansParams::default(), seed).unwrap();
                let ms = t.elapsed().as_secs_f64() * 1e3;
                if seed == 0 {
                    println!("  fit inertia (seed 0): {:.6e}", kmeans::inertia(&big, &ones, &c));
                }
                ms
            })
            .collect();
        println!(
            "fit        1,000,000 points, b = 50, mini-batch: median {:.0} ms (design goal < 2000 ms)",
            median(times)
        );
    });

    let script = root.join("scripts/atol_bench.py");
    match Command::new("python3").arg(&script).arg(root.join("target/tmp/bench-atol")).status() {
        Ok(s) if s.success() => {}
        _ => println!("(reference skipped: python3 with gudhi and scikit-learn not available)"),
    }
}

//! Loop detector benchmark: what one `toporec::loops::Detector::add` costs once the detector
//! holds 10,000 and 100,000 scans, split into describing the scan and searching plus inserting
//! (design goal: searching plus inserting under 10 ms at 100,000 scans, one thread), for
//! toporec-plus and ScanContext at their default settings.
//!
//! Scans: 2,000 simulated HDL-64E scans (`toporec simulate`'s town, seed 3, as the toporec-plus
//! benchmark). Describing is timed on 24 of them. The detector is filled to 100,000 entries
//! (`TOPOREC_BENCH_ENTRIES`) with synthetic ones: the distinct scans' descriptors, then copies
//! with their sectors turned by a random shift, scaled by a random factor in [0.8, 1.2] and
//! noised by ±5 %, added as a single drive, a scan every 0.1 s (the 30 s exclusion window
//! leaves out the last 300). The 100 adds before 10,000 and before the last entry are timed.
//!
//! Run: `cargo bench --bench loops`.

mod common;

use common::{simulated_scans, turned_copy};
use toporec::loops::{Detector, Exclusion};
use toporec::methods::Method;
use toporec::methods::scancontext::ScanContextParams;
use toporec::methods::toporec_plus::PlusParams;
use toporec::rng::SplitMix64;

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn main() {
    let n: usize =
        std::env::var("TOPOREC_BENCH_ENTRIES").ok().and_then(|v| v.parse().ok()).unwrap_or(100_000);
    let scans = simulated_scans(2_000);
    let (plus, sc) = (PlusParams::default(), ScanContextParams::default());
    // Each method with its sectors, and whether its values are codes (toporec-plus).
    let methods =
        [(Method::of(plus.clone()), plus.sectors, true), (Method::of(sc.clone()), sc.sectors, false)];
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    println!("| method | describe ms | search + insert ms at 10,000 scans | at {n} scans |");
    println!("|---|---:|---:|---:|");
    pool.install(|| {
        for (method, sectors, codes) in methods {
            let threshold = toporec::loops::default_threshold(&method).expect("a default threshold");
            let exclusion = Exclusion::Seconds(30.0);
            // Describing, as `add` times it.
            let mut detector = Detector::new(method.clone(), exclusion, threshold).expect("a detector");
            let mut describe = Vec::new();
            for (i, scan) in scans.iter().step_by(scans.len() / 24).take(24).enumerate() {
                detector.add(scan, Some(i as i64 * 100_000), "describe", None).expect("described");
                describe.push(detector.last_times().describe * 1e3);
            }
            let described: Vec<Vec<f32>> =
                scans.iter().map(|s| method.describe_raw(s).expect("raw").expect("described")).collect();
            let mut detector = Detector::new(method.clone(), exclusion, threshold).expect("a detector");
            let mut rng = SplitMix64(7);
            let (mut at_10k, mut at_n) = (Vec::new(), Vec::new());
            for i in 0..n {
                let d = &described[i % described.len()];
                let entry =
                    if i < described.len() { d.clone() } else { turned_copy(d, sectors, codes, &mut rng) };
                detector.add_descriptor(&entry, Some(i as i64 * 100_000), "bench", None);
                let t = detector.last_times().search_insert * 1e3;
                if (9_900..10_000).contains(&i) {
                    at_10k.push(t);
                }
                if i + 100 >= n {
                    at_n.push(t);
                }
            }
            println!(
                "| {} | {:.2} | {:.2} | {:.2} |",
                method.name,
                mean(&describe),
                mean(&at_10k),
                mean(&at_n)
            );
        }
    });
}

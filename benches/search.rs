//! Search benchmark: 100,000 database descriptors of length b = 1000 (design goal: search under
//! 10 ms per query on one core), plus b = 16 (k-d tree route); every result checked against the
//! brute-force scan.
//!
//! Run: `cargo bench --bench search`.

use std::time::Instant;
use toporec::methods::euclidean::Database;
use toporec::rng::SplitMix64;

fn random(n: usize, b: usize, seed: u64) -> Vec<f32> {
    let mut rng = SplitMix64(seed);
    // ATOL-like: non-negative, decaying magnitudes.
    (0..n * b).map(|i| (rng.next_f64() * 10.0 / (1.0 + (i % b) as f64 * 0.01)) as f32).collect()
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| {
        for (n, b, queries) in [(100_000usize, 1000usize, 256usize), (100_000, 16, 2000)] {
            let t = Instant::now();
            let db = Database::new(random(n, b, 1), b);
            let build = t.elapsed().as_secs_f64();
            let q = random(queries, b, 2);
            let t = Instant::now();
            let batched = db.search_many(&q, 25);
            let per_query_batched = t.elapsed().as_secs_f64() * 1e3 / queries as f64;
            let t = Instant::now();
            let singles: Vec<_> = q.chunks(b).take(16).map(|v| db.search(v, 25)).collect();
            let per_query_single = t.elapsed().as_secs_f64() * 1e3 / 16.0;
            let t = Instant::now();
            let brute: Vec<_> = q.chunks(b).take(16).map(|v| db.brute_force(v, 25)).collect();
            let per_query_brute = t.elapsed().as_secs_f64() * 1e3 / 16.0;
            assert_eq!(&batched[..16], &brute[..], "batched results equal brute force");
            assert_eq!(singles, brute, "single-query results equal brute force");
            println!(
                "n = {n}, b = {b}: build {build:.2} s; search per query: {per_query_batched:.3} ms batched ({queries} queries), {per_query_single:.3} ms one at a time, brute force {per_query_brute:.2} ms (1 thread, k = 25)"
            );
        }
    });
}

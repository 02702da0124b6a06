//! The ranges of numeric flags, checked when the command line is parsed (clap value parsers):
//! a value that cannot make sense is refused with the flag, the value and the range. Values
//! larger than the data allows (a `-k` above the database size) are clamped, with a warning,
//! where they are used. Pipeline-file keys are checked by the pipeline validator
//! (`crate::pipeline::config`) under the same rules.

/// A number, or the reason it is not one.
fn number(s: &str) -> Result<f64, String> {
    s.trim().parse::<f64>().map_err(|_| format!("`{s}` is not a number"))
}

/// A finite number.
pub fn finite(s: &str) -> Result<f64, String> {
    let x = number(s)?;
    if x.is_finite() { Ok(x) } else { Err(format!("`{s}` is not a finite number")) }
}

/// A finite number > 0.
pub fn positive(s: &str) -> Result<f64, String> {
    let x = number(s)?;
    if x.is_finite() && x > 0.0 { Ok(x) } else { Err(format!("`{s}` is not in the range (0, inf)")) }
}

/// A finite number ≥ 0.
pub fn non_negative(s: &str) -> Result<f64, String> {
    let x = number(s)?;
    if x.is_finite() && x >= 0.0 { Ok(x) } else { Err(format!("`{s}` is not in the range [0, inf)")) }
}

/// A share of a whole: in (0, 1].
pub fn fraction(s: &str) -> Result<f64, String> {
    let x = number(s)?;
    if x > 0.0 && x <= 1.0 { Ok(x) } else { Err(format!("`{s}` is not in the range (0, 1]")) }
}

/// A probability of losing something: in [0, 1).
pub fn probability(s: &str) -> Result<f64, String> {
    let x = number(s)?;
    if (0.0..1.0).contains(&x) { Ok(x) } else { Err(format!("`{s}` is not in the range [0, 1)")) }
}

/// A count ≥ 1.
pub fn count(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!("`{s}` is not a whole number in the range [1, ∞)")),
    }
}

/// A number in `[lo, hi]`.
pub fn within(s: &str, lo: f64, hi: f64) -> Result<f64, String> {
    let x = number(s)?;
    if (lo..=hi).contains(&x) { Ok(x) } else { Err(format!("`{s}` is not in the range [{lo}, {hi}]")) }
}

/// A whole number in `[lo, hi]`.
pub fn count_within(s: &str, lo: usize, hi: usize) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if (lo..=hi).contains(&n) => Ok(n),
        _ => Err(format!("`{s}` is not a whole number in the range [{lo}, {hi}]")),
    }
}

/// The azimuth resolution of a simulated sensor, degrees: [0.01, 10] (finer would allocate
/// millions of rays per scan).
pub fn azimuth_resolution(s: &str) -> Result<f64, String> {
    within(s, 0.01, 10.0)
}

/// The street spacing of a simulated town, metres: (20, 10000].
pub fn block_size(s: &str) -> Result<f64, String> {
    let x = number(s)?;
    if x > 20.0 && x <= 10_000.0 { Ok(x) } else { Err(format!("`{s}` is not in the range (20, 10000]")) }
}

/// Blocks per side of a simulated town: [1, 50].
pub fn blocks(s: &str) -> Result<usize, String> {
    count_within(s, 1, 50)
}

/// Centres per codebook: [1, 100000].
pub fn centres(s: &str) -> Result<usize, String> {
    count_within(s, 1, 100_000)
}

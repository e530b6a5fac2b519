//! Order statistics of measured figures (frame times, metric values): the one `median` the
//! benches, the client's `--bench` and the evaluation report with.

/// The median of some values (sorted in place by `total_cmp`, so NaN sorts last and never
/// panics); `None` if empty. An even count gives the mean of the two middle values.
pub fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_unstable_by(|a, b| a.total_cmp(b));
    let n = values.len();
    Some(if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) })
}

#[cfg(test)]
mod tests {
    use super::median;

    #[test]
    fn odd_even_empty() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [f64::NAN, 1.0, 2.0]), Some(2.0), "NaN sorts last");
    }
}

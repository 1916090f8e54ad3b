//! Cubic interpolation of periodic samples (Catmull-Rom): the weights of the four samples
//! around a position. Used by the wind tables and the pier-vibration noise.

/// Catmull-Rom weights of samples `-1, 0, 1, 2` at fraction `t` in `[0, 1)`.
#[inline]
pub fn catmull_rom(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// Index of the sample before position `u` (in samples, periodic of period `n`), the four
/// indices around it and the Catmull-Rom weights.
#[inline]
pub fn periodic_stencil(u: f64, n: usize) -> ([usize; 4], [f64; 4]) {
    let u = u.rem_euclid(n as f64);
    let fl = u.floor();
    // rem_euclid can round up to n itself.
    let i0 = (fl as usize) % n;
    let w = catmull_rom(u - fl);
    let idx = [(i0 + n - 1) % n, i0, (i0 + 1) % n, (i0 + 2) % n];
    (idx, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn catmull_rom_is_a_partition_of_unity_and_interpolates() {
        for t in [0.0, 0.25, 0.5, 0.9] {
            let w = catmull_rom(t);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        }
        assert_eq!(catmull_rom(0.0), [0.0, 1.0, 0.0, 0.0]);
        let (idx, _) = periodic_stencil(-0.5, 8);
        assert_eq!(idx, [6, 7, 0, 1]);
    }
}

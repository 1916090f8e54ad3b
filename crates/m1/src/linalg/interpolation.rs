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
/// indices around it and the Catmull-Rom weights. The indices wrap by comparison, not by
/// integer division (a 64-bit division takes tens of cycles, and the wind FMU takes a stencil
/// per segment per step).
#[inline]
pub fn periodic_stencil(u: f64, n: usize) -> ([usize; 4], [f64; 4]) {
    // `rem_euclid` without its `fmod` call where that returns `u` as it is (the same values).
    let nf = n as f64;
    let u = if (0.0..nf).contains(&u) {
        u
    } else if (-nf..0.0).contains(&u) {
        u + nf
    } else if (-2.0 * nf..-nf).contains(&u) {
        // `u + n` is exact here (Sterbenz), as `u % n` is: the same steps as `rem_euclid`.
        (u + nf) + nf
    } else {
        u.rem_euclid(nf)
    };
    // u >= 0 (or NaN): truncation is the floor, without a call (baseline x86-64 has no
    // rounding instruction).
    let i0 = u as usize;
    let fl = i0 as f64;
    let w = catmull_rom(u - fl);
    // rem_euclid can round up to n itself.
    let i0 = if i0 >= n { i0 - n } else { i0 };
    if n < 3 {
        return ([(i0 + n - 1) % n, i0, (i0 + 1) % n, (i0 + 2) % n], w);
    }
    let wrap = |i: usize| if i >= n { i - n } else { i };
    let before = if i0 == 0 { n - 1 } else { i0 - 1 };
    ([before, i0, wrap(i0 + 1), wrap(i0 + 2)], w)
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

    #[test]
    fn stencil_indices_wrap_as_the_remainder_does() {
        for n in 1..=6usize {
            for k in -100..=100 {
                let u = f64::from(k) * 0.37;
                let (idx, w) = periodic_stencil(u, n);
                let r = u.rem_euclid(n as f64);
                let i0 = (r.floor() as usize) % n;
                let want = [(i0 + n - 1) % n, i0, (i0 + 1) % n, (i0 + 2) % n];
                assert_eq!(idx, want, "u {u}, n {n}");
                assert_eq!(w, catmull_rom(r - r.floor()), "u {u}, n {n}");
                assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            }
        }
        // A position just below a whole period rounds up to it: sample 0, weight on it.
        let (idx, w) = periodic_stencil(-1e-17, 8);
        assert_eq!((idx, w), ([7, 0, 1, 2], [0.0, 1.0, 0.0, 0.0]));
    }
}

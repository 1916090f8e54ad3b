//! Krylov estimates of extreme eigenvalues of operators given only as matrix-vector products.
//!
//! Arnoldi with full re-orthogonalisation builds an orthonormal basis $V_m$ of the Krylov space
//! $\mathcal K_m(M, v_0)$ and the Hessenberg matrix $H_m = V_m^T M V_m$; the eigenvalues of $H_m$
//! (Ritz values) approximate the extreme eigenvalues of $M$ first, to high accuracy when they are
//! separated from the bulk. The largest singular value of $Q$ is the square root of the largest
//! eigenvalue of $Q^T Q$.

use nalgebra::{Complex, DMatrix};

/// Ritz values of `op` (an n x n operator, `op(x, out)` writes M x) from an m-step Arnoldi
/// process started at `v0`. Stops early on an invariant subspace (the Ritz values are then
/// exact eigenvalues of M restricted to it): when the new direction is below 1e-13 of `scale`
/// (the magnitude below which M x counts as round-off, e.g. 1 for Q - I with Q of order 1) or of
/// the largest |M v| seen.
pub fn ritz_values(
    n: usize,
    m: usize,
    v0: &[f64],
    scale: f64,
    mut op: impl FnMut(&[f64], &mut [f64]),
) -> Vec<Complex<f64>> {
    let m = m.min(n).max(1);
    let mut basis: Vec<Vec<f64>> = Vec::with_capacity(m + 1);
    let norm0 = v0.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm0 == 0.0 {
        return Vec::new();
    }
    basis.push(v0.iter().map(|x| x / norm0).collect());
    let mut h = DMatrix::<f64>::zeros(m + 1, m);
    let mut w = vec![0.0; n];
    let mut steps = m;
    let mut largest = scale.abs();
    for j in 0..m {
        op(&basis[j], &mut w);
        let wnorm0 = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        largest = largest.max(wnorm0);
        // Two passes of classical Gram-Schmidt: orthogonal to working precision.
        for _ in 0..2 {
            for (i, v) in basis.iter().enumerate() {
                let d: f64 = v.iter().zip(&w).map(|(a, b)| a * b).sum();
                h[(i, j)] += d;
                for (wk, vk) in w.iter_mut().zip(v) {
                    *wk -= d * vk;
                }
            }
        }
        let wn = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        h[(j + 1, j)] = wn;
        if wn <= 1e-13 * largest || wn == 0.0 {
            steps = j + 1;
            break;
        }
        basis.push(w.iter().map(|x| x / wn).collect());
    }
    let hm = h.view((0, 0), (steps, steps)).into_owned();
    match nalgebra::linalg::Schur::try_new(hm.clone(), f64::EPSILON, 100_000) {
        Some(schur) => schur.complex_eigenvalues().iter().copied().collect(),
        // No convergence (not seen in practice): the diagonal is a crude fallback.
        None => (0..steps).map(|i| Complex::new(hm[(i, i)], 0.0)).collect(),
    }
}

/// Largest eigenvalue modulus estimate (spectral radius) of `op`.
pub fn spectral_radius(
    n: usize,
    m: usize,
    v0: &[f64],
    scale: f64,
    op: impl FnMut(&[f64], &mut [f64]),
) -> f64 {
    ritz_values(n, m, v0, scale, op)
        .iter()
        .map(|l| l.norm())
        .fold(0.0, f64::max)
}

/// Largest singular value estimate of Q from `q(x, out)` and `qt(x, out)` (its transpose).
pub fn largest_singular_value(
    n: usize,
    m: usize,
    v0: &[f64],
    mut q: impl FnMut(&[f64], &mut [f64]),
    mut qt: impl FnMut(&[f64], &mut [f64]),
) -> f64 {
    let mut tmp = vec![0.0; n];
    let lmax = ritz_values(n, m, v0, 0.0, |x, out| {
        q(x, &mut tmp);
        qt(&tmp, out);
    })
    .iter()
    .map(|l| l.re)
    .fold(0.0, f64::max);
    lmax.max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ritz_values_find_the_extreme_eigenvalues() {
        // Diagonal operator with a separated top and bottom eigenvalue.
        let n = 400;
        let d: Vec<f64> = (0..n)
            .map(|i| match i {
                0 => 10.0,
                1 => -3.0,
                _ => 1.0 + (i as f64) / n as f64,
            })
            .collect();
        let v0: Vec<f64> = (0..n).map(|i| 1.0 + ((i * 37) % 11) as f64).collect();
        let op = |x: &[f64], out: &mut [f64]| {
            for ((o, xi), di) in out.iter_mut().zip(x).zip(&d) {
                *o = di * xi;
            }
        };
        let ritz = ritz_values(n, 40, &v0, 0.0, op);
        let max = ritz.iter().map(|l| l.re).fold(f64::MIN, f64::max);
        let min = ritz.iter().map(|l| l.re).fold(f64::MAX, f64::min);
        assert!((max - 10.0).abs() < 1e-10, "{max}");
        assert!((min + 3.0).abs() < 1e-10, "{min}");
        assert!((spectral_radius(n, 40, &v0, 0.0, op) - 10.0).abs() < 1e-10);
    }

    #[test]
    fn singular_value_of_a_rotation_scaled() {
        // Q = 2 R (rotation by 90 degrees in pairs): all singular values 2, eigenvalues +-2i.
        let n = 50;
        let q = |x: &[f64], out: &mut [f64]| {
            for k in 0..n / 2 {
                out[2 * k] = -2.0 * x[2 * k + 1];
                out[2 * k + 1] = 2.0 * x[2 * k];
            }
        };
        let qt = |x: &[f64], out: &mut [f64]| {
            for k in 0..n / 2 {
                out[2 * k] = 2.0 * x[2 * k + 1];
                out[2 * k + 1] = -2.0 * x[2 * k];
            }
        };
        let v0: Vec<f64> = (0..n).map(|i| (i as f64).sin() + 2.0).collect();
        assert!((largest_singular_value(n, 20, &v0, q, qt) - 2.0).abs() < 1e-10);
        assert!((spectral_radius(n, 20, &v0, 0.0, q) - 2.0).abs() < 1e-10);
    }
}

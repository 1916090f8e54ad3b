//! The nominal control setup of a geometry: its A-matrix, the reconstructor $B_0$ (global
//! piston/tip/tilt projected out) and focus-mode, the least observable mode, found by inverse
//! iteration on $A^TA$.

use faer::sparse::SparseColMat;

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::control::reconstructor::{ModalGain, SparseReconstructor, sparse_mul};
use crate::sensing::interaction::{a_matrix, global_ptt};

/// The nominal control setup of a geometry: A, the reconstructor, focus-mode.
pub struct Nominal {
    /// The geometry.
    pub geometry: Geometry,
    /// The A-matrix.
    pub a: SparseColMat<usize, f64>,
    /// $B_0$ (no modal gains).
    pub b0: SparseReconstructor,
    /// Focus-mode (unit norm), the least observable mode.
    pub focus: Vec<f64>,
    /// Its singular value.
    pub focus_singular_value: f64,
}

impl Nominal {
    /// Builds A and its reconstructor; focus-mode by inverse iteration on $A^TA$ restricted to
    /// the observable subspace (the reconstructor's factorisation).
    pub fn new(geometry: Geometry) -> Result<Self, M1Error> {
        let a = a_matrix(&geometry);
        let b0 = SparseReconstructor::new(&a, global_ptt(&geometry).as_ref(), Vec::new())?;
        let (focus, sv) = least_observable_mode(&a, &b0)?;
        Ok(Self {
            geometry,
            a,
            b0,
            focus,
            focus_singular_value: sv,
        })
    }

    /// The reconstructor with focus-mode's gain multiplied by `gain`.
    pub fn with_focus_gain(&self, gain: f64) -> Result<SparseReconstructor, M1Error> {
        SparseReconstructor::new(
            &self.a,
            self.b0.null_space(),
            vec![ModalGain {
                mode: self.focus.clone(),
                gain,
            }],
        )
    }
}

/// Euclidean norm.
pub(crate) fn norm(x: &[f64]) -> f64 {
    x.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// Removes from `x` its components on the orthonormal columns of `null`.
pub(crate) fn project_out(null: faer::MatRef<'_, f64>, x: &mut [f64]) {
    for c in 0..null.ncols() {
        let col = null.col(c);
        let d: f64 = (0..x.len()).map(|i| col[i] * x[i]).sum();
        for (i, xi) in x.iter_mut().enumerate() {
            *xi -= d * col[i];
        }
    }
}

/// Smallest non-zero singular value of A and its right singular vector, by inverse iteration:
/// $x \leftarrow (A^TA)^+ x$, where $(A^TA)^+ = B_0 B_0^T$.
pub fn least_observable_mode(
    a: &SparseColMat<usize, f64>,
    b0: &SparseReconstructor,
) -> Result<(Vec<f64>, f64), M1Error> {
    let na = a.ncols();
    let mut x: Vec<f64> = (0..na)
        .map(|i| 1.0 + ((i * 7919) % 97) as f64 / 97.0)
        .collect();
    project_out(b0.null_space(), &mut x);
    let mut lambda = 0.0;
    for _ in 0..200 {
        let n = norm(&x);
        if n == 0.0 {
            return Err(M1Error::Numerical(
                "inverse iteration lost its vector".into(),
            ));
        }
        x.iter_mut().for_each(|v| *v /= n);
        let y = b0.apply(&b0.apply_transpose(&x));
        let next = x.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>();
        let done = (next - lambda).abs() <= 1e-12 * next.abs();
        lambda = next;
        x = y;
        if done {
            break;
        }
    }
    let n = norm(&x);
    x.iter_mut().for_each(|v| *v /= n);
    // Rayleigh quotient of A^T A for the singular value.
    let mut ax = vec![0.0; a.nrows()];
    sparse_mul(a, &x, &mut ax);
    Ok((x, norm(&ax)))
}

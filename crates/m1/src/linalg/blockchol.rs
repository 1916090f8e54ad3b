//! Sparse Cholesky factorisation of a symmetric positive definite matrix made of dense
//! `B x B` blocks, for the reconstructor's normal equations.
//!
//! The normal matrix $A^T A$ of a segmented mirror couples the three actuators of a segment with
//! those of its neighbours: it is a sparse matrix of dense 3 x 3 blocks on the segment graph.
//! Factorising it block by block (fill-reducing ordering of the segment graph by faer's
//! approximate minimum degree, right-looking elimination with dense blocks) gives a factor whose
//! triangular solves touch one index per nine values and run as short fixed-size loops, several
//! times faster than a scalar sparse solve of the same factor.
//!
//! The factor is $P K P^T = L L^T$ with $L$ block lower triangular; the diagonal blocks are kept
//! inverted so a solve is only block matrix-vector products.

// Index loops read as the block formulas they implement.
#![allow(clippy::needless_range_loop)]

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMat;
use faer::sparse::linalg::amd;

use crate::M1Error;

/// A dense `B x B` block, row-major.
pub type Block<const B: usize> = [[f64; B]; B];

/// Smallest accepted ratio of a pivot (squared diagonal of the factor) to the matrix's original
/// diagonal entry: below it the matrix is taken as singular rather than factorised into noise.
const PIVOT_RATIO: f64 = 1e-13;

/// The block Cholesky factor.
#[derive(Debug, Clone)]
pub struct BlockCholesky<const B: usize> {
    nb: usize,
    /// `perm[new] = old` block index.
    perm: Vec<usize>,
    /// Strictly lower blocks of L by block column (new indices).
    col_ptr: Vec<usize>,
    row_idx: Vec<u32>,
    vals: Vec<Block<B>>,
    /// The inverses of L's diagonal blocks (lower triangular).
    diag_inv: Vec<Block<B>>,
}

fn zero<const B: usize>() -> Block<B> {
    [[0.0; B]; B]
}

/// Lower Cholesky factor of a symmetric block; `None` if a pivot is not clearly positive.
fn chol_block<const B: usize>(m: &Block<B>, diag0: &[f64; B]) -> Option<Block<B>> {
    let mut l = zero::<B>();
    for j in 0..B {
        let mut d = m[j][j];
        for k in 0..j {
            d -= l[j][k] * l[j][k];
        }
        let clearly_positive = d.is_finite() && d > PIVOT_RATIO * diag0[j].abs();
        if !clearly_positive {
            return None;
        }
        let d = d.sqrt();
        l[j][j] = d;
        for i in j + 1..B {
            let mut s = m[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            l[i][j] = s / d;
        }
    }
    Some(l)
}

/// Inverse of a lower-triangular block.
fn inv_lower<const B: usize>(l: &Block<B>) -> Block<B> {
    let mut x = zero::<B>();
    for c in 0..B {
        // Solve L x_c = e_c by forward substitution.
        for i in c..B {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in c..i {
                s -= l[i][k] * x[k][c];
            }
            x[i][c] = s / l[i][i];
        }
    }
    x
}

/// `a * b^T`.
fn mul_abt<const B: usize>(a: &Block<B>, b: &Block<B>) -> Block<B> {
    let mut c = zero::<B>();
    for i in 0..B {
        for j in 0..B {
            let mut s = 0.0;
            for k in 0..B {
                s += a[i][k] * b[j][k];
            }
            c[i][j] = s;
        }
    }
    c
}

fn sub_assign<const B: usize>(a: &mut Block<B>, b: &Block<B>) {
    for i in 0..B {
        for j in 0..B {
            a[i][j] -= b[i][j];
        }
    }
}

fn transpose<const B: usize>(a: &Block<B>) -> Block<B> {
    let mut t = zero::<B>();
    for i in 0..B {
        for j in 0..B {
            t[j][i] = a[i][j];
        }
    }
    t
}

impl<const B: usize> BlockCholesky<B> {
    /// Factorises the symmetric matrix of `nb x nb` blocks given by its lower blocks
    /// `(i, j, block)` with `i >= j` (block row, block column); repeated positions are summed.
    /// Diagonal blocks must be given whole (both triangles), and be symmetric.
    ///
    /// # Errors
    /// [`M1Error::Numerical`] if the matrix is not numerically positive definite (a pivot below
    /// 1e-13 of its diagonal entry), [`M1Error::InvalidInput`] for an index out of range or
    /// above the diagonal.
    pub fn new(nb: usize, blocks: &[(usize, usize, Block<B>)]) -> Result<Self, M1Error> {
        // Sum the input by position.
        let mut diag = vec![zero::<B>(); nb];
        let mut lower: Vec<std::collections::BTreeMap<usize, Block<B>>> =
            vec![std::collections::BTreeMap::new(); nb];
        for &(i, j, ref b) in blocks {
            if i >= nb || j > i {
                return Err(M1Error::InvalidInput(format!(
                    "block ({i}, {j}) is outside the lower triangle of a {nb} x {nb} block matrix"
                )));
            }
            let t = if i == j {
                &mut diag[i]
            } else {
                lower[j].entry(i).or_insert_with(zero::<B>)
            };
            for r in 0..B {
                for c in 0..B {
                    t[r][c] += b[r][c];
                }
            }
        }
        let perm = Self::amd_order(nb, &lower)?;
        let mut new_of = vec![0usize; nb];
        for (new, &old) in perm.iter().enumerate() {
            new_of[old] = new;
        }
        // The permuted matrix, lower blocks by column (new indices).
        let mut pdiag = vec![zero::<B>(); nb];
        for (old, d) in diag.iter().enumerate() {
            pdiag[new_of[old]] = *d;
        }
        let mut pcols: Vec<Vec<(usize, Block<B>)>> = vec![Vec::new(); nb];
        for (oj, col) in lower.iter().enumerate() {
            for (&oi, b) in col {
                let (ni, nj) = (new_of[oi], new_of[oj]);
                if ni > nj {
                    pcols[nj].push((ni, *b));
                } else {
                    pcols[ni].push((nj, transpose(b)));
                }
            }
        }
        // Symbolic factorisation: pattern(j) = adj(j) U (pattern of children) \ {j}, parent(j)
        // = the smallest row of pattern(j) (the elimination tree).
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); nb];
        let mut patterns: Vec<Vec<usize>> = Vec::with_capacity(nb);
        for j in 0..nb {
            let mut set: std::collections::BTreeSet<usize> =
                pcols[j].iter().map(|&(i, _)| i).collect();
            for &c in &children[j] {
                let pc: &Vec<usize> = &patterns[c];
                set.extend(pc.iter().copied().filter(|&i| i > j));
            }
            let pat: Vec<usize> = set.into_iter().collect();
            if let Some(&parent) = pat.first() {
                children[parent].push(j);
            }
            patterns.push(pat);
        }
        let mut col_ptr = Vec::with_capacity(nb + 1);
        col_ptr.push(0);
        let mut row_idx = Vec::new();
        for p in &patterns {
            row_idx.extend(p.iter().map(|&i| i as u32));
            col_ptr.push(row_idx.len());
        }
        // Numeric factorisation, right-looking: W holds the Schur complement in L's layout.
        let mut vals = vec![zero::<B>(); row_idx.len()];
        let mut pos = vec![usize::MAX; nb];
        for j in 0..nb {
            for (k, &i) in row_idx[col_ptr[j]..col_ptr[j + 1]].iter().enumerate() {
                pos[i as usize] = col_ptr[j] + k;
            }
            for &(i, ref b) in &pcols[j] {
                vals[pos[i]] = *b;
            }
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                pos[i as usize] = usize::MAX;
            }
        }
        let diag0: Vec<[f64; B]> = pdiag
            .iter()
            .map(|d| std::array::from_fn(|k| d[k][k]))
            .collect();
        let mut wdiag = pdiag;
        let mut diag_inv = vec![zero::<B>(); nb];
        for j in 0..nb {
            let l = chol_block(&wdiag[j], &diag0[j]).ok_or_else(|| {
                M1Error::Numerical(format!(
                    "the matrix is not positive definite: pivot block {} (block {} of the input) \
                     is singular",
                    j, perm[j]
                ))
            })?;
            let linv = inv_lower(&l);
            diag_inv[j] = linv;
            let (lo, hi) = (col_ptr[j], col_ptr[j + 1]);
            // L_ij = W_ij L_jj^{-T}
            for p in lo..hi {
                vals[p] = mul_abt(&vals[p], &linv);
            }
            // W_ab -= L_aj L_bj^T for a >= b in pattern(j).
            for pb in lo..hi {
                let b = row_idx[pb] as usize;
                let (blo, bhi) = (col_ptr[b], col_ptr[b + 1]);
                for (k, &i) in row_idx[blo..bhi].iter().enumerate() {
                    pos[i as usize] = blo + k;
                }
                let lb = vals[pb];
                let upd = mul_abt(&lb, &lb);
                sub_assign(&mut wdiag[b], &upd);
                for pa in pb + 1..hi {
                    let a = row_idx[pa] as usize;
                    let upd = mul_abt(&vals[pa], &lb);
                    let target = pos[a];
                    debug_assert!(target != usize::MAX, "fill outside the symbolic pattern");
                    sub_assign(&mut vals[target], &upd);
                }
                for &i in &row_idx[blo..bhi] {
                    pos[i as usize] = usize::MAX;
                }
            }
        }
        Ok(Self {
            nb,
            perm,
            col_ptr,
            row_idx,
            vals,
            diag_inv,
        })
    }

    /// Approximate minimum degree ordering of the block graph (`perm[new] = old`).
    fn amd_order(
        nb: usize,
        lower: &[std::collections::BTreeMap<usize, Block<B>>],
    ) -> Result<Vec<usize>, M1Error> {
        let mut adj: Vec<Vec<usize>> = vec![Vec::new(); nb];
        for (j, col) in lower.iter().enumerate() {
            for &i in col.keys() {
                adj[j].push(i);
                adj[i].push(j);
            }
        }
        let mut col_ptr = Vec::with_capacity(nb + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0usize);
        for a in &mut adj {
            a.sort_unstable();
            row_idx.extend_from_slice(a);
            col_ptr.push(row_idx.len());
        }
        let nnz = row_idx.len();
        let pattern = SymbolicSparseColMat::<usize>::new_checked(nb, nb, col_ptr, None, row_idx);
        let mut perm = vec![0usize; nb];
        let mut perm_inv = vec![0usize; nb];
        let mut buf = MemBuffer::new(amd::order_scratch::<usize>(nb, nnz));
        amd::order(
            &mut perm,
            &mut perm_inv,
            pattern.as_ref(),
            amd::Control::default(),
            MemStack::new(&mut buf),
        )
        .map_err(|e| M1Error::Numerical(format!("fill-reducing ordering failed: {e:?}")))?;
        Ok(perm)
    }

    /// Matrix size in scalars.
    pub fn dim(&self) -> usize {
        self.nb * B
    }

    /// Number of stored blocks of L (off-diagonal plus diagonal).
    pub fn n_blocks(&self) -> usize {
        self.vals.len() + self.nb
    }

    /// Solves $K x = b$ in place (`x` holds $b$ on entry). `work` is scratch space of
    /// [`Self::dim`] values.
    ///
    /// # Panics
    /// If `x` or `work` is not of length [`Self::dim`].
    pub fn solve_in_place(&self, x: &mut [f64], work: &mut [f64]) {
        assert_eq!(x.len(), self.dim(), "right-hand side length");
        assert_eq!(work.len(), self.dim(), "work length");
        let (xs, _) = x.as_chunks_mut::<B>();
        let (w, _) = work.as_chunks_mut::<B>();
        for (wn, &old) in w.iter_mut().zip(&self.perm) {
            *wn = xs[old];
        }
        // Forward: L v = b, column by column (scatter updates).
        for j in 0..self.nb {
            let d = &self.diag_inv[j];
            let bj = w[j];
            let vj: [f64; B] = std::array::from_fn(|r| (0..B).map(|c| d[r][c] * bj[c]).sum());
            w[j] = vj;
            let (lo, hi) = (self.col_ptr[j], self.col_ptr[j + 1]);
            for (l, &i) in self.vals[lo..hi].iter().zip(&self.row_idx[lo..hi]) {
                let wi = &mut w[i as usize];
                for r in 0..B {
                    let mut s = wi[r];
                    for c in 0..B {
                        s -= l[r][c] * vj[c];
                    }
                    wi[r] = s;
                }
            }
        }
        // Backward: L^T x = v, column by column (gathered dot products, B x B independent
        // accumulators so the sums do not serialise on one register).
        for j in (0..self.nb).rev() {
            let (lo, hi) = (self.col_ptr[j], self.col_ptr[j + 1]);
            let mut acc = zero::<B>();
            for (l, &i) in self.vals[lo..hi].iter().zip(&self.row_idx[lo..hi]) {
                let wi = &w[i as usize];
                for r in 0..B {
                    for c in 0..B {
                        acc[r][c] += l[r][c] * wi[r];
                    }
                }
            }
            let s: [f64; B] =
                std::array::from_fn(|c| w[j][c] - (0..B).map(|r| acc[r][c]).sum::<f64>());
            let d = &self.diag_inv[j];
            // x_j = L_jj^{-T} s
            w[j] = std::array::from_fn(|c| (0..B).map(|r| d[r][c] * s[r]).sum());
        }
        for (wn, &old) in w.iter().zip(&self.perm) {
            xs[old] = *wn;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A block tridiagonal-plus-corner SPD matrix, dense copy alongside.
    type Blocks = Vec<(usize, usize, Block<3>)>;

    fn sample(nb: usize) -> (Blocks, Vec<Vec<f64>>) {
        let n = 3 * nb;
        let mut dense = vec![vec![0.0; n]; n];
        let mut blocks = Vec::new();
        let mut put = |i: usize, j: usize, b: Block<3>, dense: &mut Vec<Vec<f64>>| {
            for r in 0..3 {
                for c in 0..3 {
                    dense[3 * i + r][3 * j + c] += b[r][c];
                    if i != j {
                        dense[3 * j + c][3 * i + r] += b[r][c];
                    }
                }
            }
            blocks.push((i, j, b));
        };
        for i in 0..nb {
            let f = i as f64;
            let d = [
                [8.0 + f, 0.5, 0.1],
                [0.5, 7.0, 0.2 * f.sin()],
                [0.1, 0.2 * f.sin(), 9.0],
            ];
            put(i, i, d, &mut dense);
            if i + 1 < nb {
                let o = [
                    [-1.0, 0.3, 0.0],
                    [0.2, -1.5, 0.1],
                    [0.0, 0.4 * f.cos(), -0.8],
                ];
                put(i + 1, i, o, &mut dense);
            }
            if i >= 5 && i % 4 == 1 {
                put(
                    i,
                    i - 5,
                    [[0.3, 0.0, 0.1], [0.0, -0.2, 0.0], [0.1, 0.0, 0.25]],
                    &mut dense,
                );
            }
        }
        (blocks, dense)
    }

    #[test]
    fn solves_match_the_dense_matrix() {
        let nb = 23;
        let (blocks, dense) = sample(nb);
        let f = BlockCholesky::<3>::new(nb, &blocks).expect("SPD");
        let n = 3 * nb;
        let x_true: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin() + 0.1).collect();
        let mut b: Vec<f64> = (0..n)
            .map(|r| (0..n).map(|c| dense[r][c] * x_true[c]).sum())
            .collect();
        let mut work = vec![0.0; n];
        f.solve_in_place(&mut b, &mut work);
        for (x, t) in b.iter().zip(&x_true) {
            assert!((x - t).abs() < 1e-12, "{x} vs {t}");
        }
    }

    #[test]
    fn singular_and_malformed_input_are_errors() {
        let one = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        // [[I, I], [I, I]] is singular.
        let blocks = vec![(0, 0, one), (1, 1, one), (1, 0, one)];
        assert!(matches!(
            BlockCholesky::<3>::new(2, &blocks),
            Err(M1Error::Numerical(_))
        ));
        assert!(matches!(
            BlockCholesky::<3>::new(2, &[(0, 1, one)]),
            Err(M1Error::InvalidInput(_))
        ));
        assert!(matches!(
            BlockCholesky::<3>::new(2, &[(2, 0, one)]),
            Err(M1Error::InvalidInput(_))
        ));
    }
}

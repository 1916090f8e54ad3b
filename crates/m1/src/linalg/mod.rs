//! Numerical building blocks: SIMD kernels, Krylov estimates, the extreme singular values of a
//! dense matrix, the complex symmetric modal stiffness's $L D L^T$, single right-hand-side LU
//! solves, the block Cholesky factor, block Lanczos for the lowest modes, the skyline Cholesky of the FE cell, the NPY/NPZ reader,
//! periodic cubic interpolation, the products of upper trapezoidal and symmetric matrices
//! stored from the diagonal on, and the on-disk cache of computed arrays (the structure's
//! modes, the wind's tables).

pub mod blockchol;
pub mod cache;
pub mod complex_symmetric;
pub mod extreme;
pub mod interpolation;
pub mod kernels;
pub mod krylov;
pub mod lanczos;
pub mod lu_solve;
pub mod npy;
pub mod packed_ldlt;
pub mod pair;
pub mod skyline;
pub mod symmetric;
pub mod symmetric_scaled;
pub mod trapezoid;

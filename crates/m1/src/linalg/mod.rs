//! Numerical building blocks: SIMD kernels, Krylov estimates, the block Cholesky factor, the
//! skyline Cholesky of the FE cell, the NPY/NPZ reader, periodic cubic interpolation.

pub mod blockchol;
pub mod interpolation;
pub mod kernels;
pub mod krylov;
pub mod npy;
pub mod skyline;

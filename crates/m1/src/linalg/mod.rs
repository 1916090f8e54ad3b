//! Numerical building blocks: SIMD kernels, Krylov estimates, the block Cholesky factor.

pub mod blockchol;
pub mod kernels;
pub mod krylov;

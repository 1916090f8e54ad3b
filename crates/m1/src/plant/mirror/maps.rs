//! The exact maps of one coupled tick: a structural mode's response to its state, a held force
//! and a force ramp (first-order hold, [`foh_mode`]), and a segment channel's sub-step maps with
//! its response to a ramp of the cell displacement.

use nalgebra::{SMatrix, SVector};

use crate::plant::segment::{Channel, Gamma, N_CONT, N_STATE, Phi, SegmentModel};

/// Exact response of one mode over `h` to its state, a held force and a force ramp:
/// `(A, b0, b1)` with `A` row-major 2x2 and `b0`, `b1` the (q, q') responses to a unit held
/// force and to a force rising linearly from 0 to 1 over the step.
pub fn foh_mode(w: f64, zeta: f64, h: f64) -> ([f64; 4], [f64; 2], [f64; 2]) {
    // State (q, v, u0, rho, sigma): v' = -w^2 q - 2 zeta w v + u0 + rho, rho' = sigma / h.
    let mut m = SMatrix::<f64, 5, 5>::zeros();
    m[(0, 1)] = 1.0;
    m[(1, 0)] = -w * w;
    m[(1, 1)] = -2.0 * zeta * w;
    m[(1, 2)] = 1.0;
    m[(1, 3)] = 1.0;
    m[(3, 4)] = 1.0 / h;
    let e = (m * h).exp();
    (
        [e[(0, 0)], e[(0, 1)], e[(1, 0)], e[(1, 1)]],
        [e[(0, 2)], e[(1, 2)]],
        [e[(0, 4)], e[(1, 4)]],
    )
}

/// Exact response of a segment channel's continuous part over one tick to a cell displacement
/// rising linearly from 0 to 1 (drive and other inputs zero).
fn channel_ramp(model: &SegmentModel, ch: Channel, h: f64) -> SVector<f64, N_STATE> {
    const M: usize = N_CONT + 2;
    let p = model.plant(ch);
    let mut m = SMatrix::<f64, M, M>::zeros();
    for i in 0..N_CONT {
        for j in 0..N_CONT {
            m[(i, j)] = p.a[(i, j)];
        }
        m[(i, N_CONT)] = p.b[(i, 1)];
    }
    m[(N_CONT, N_CONT + 1)] = 1.0 / h;
    let e = (m * h).exp();
    let mut g = SVector::<f64, N_STATE>::zeros();
    for i in 0..N_CONT {
        g[i] = e[(i, N_CONT + 1)];
    }
    g
}

/// The maps of one coupled sub-step of `1 / substeps` servo period for a channel, `(P, S)`
/// for the sub-step that starts with the servo's sample and for the others (the drive held),
/// and `gamma`: `X+ = P X + S w + gamma Delta` when the cell displacement ramps by `Delta` over
/// the sub-step.
pub(super) fn substep_maps(
    model: &SegmentModel,
    ch: Channel,
    substeps: u32,
) -> ([(Phi, Gamma); 2], SVector<f64, N_STATE>) {
    let d = model.servo_period() / f64::from(substeps);
    (
        [model.closed_loop_over(ch, d), model.plant_only(ch, d)],
        channel_ramp(model, ch, d),
    )
}

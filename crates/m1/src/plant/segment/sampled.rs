//! The sampled channel: the exact zero-order-hold discretisation of the continuous part, the
//! servo tick maps of the closed loop (whole and partial periods), their stability and
//! frequency response, and the propagation of a tick map over many ticks ([`propagate`]).

use nalgebra::SMatrix;
use std::f64::consts::TAU;

use super::model::SegmentModel;
use super::{Channel, Drive, Gamma, N_CONT, N_IN, N_STATE, Phi, state};

impl SegmentModel {
    /// The servo period (s).
    pub fn servo_period(&self) -> f64 {
        1.0 / self.actuator.servo.rate
    }

    /// Zero-order-hold discretisation of a channel's continuous part over `d` seconds:
    /// $\exp\left(\begin{bmatrix}A & B\\ 0 & 0\end{bmatrix} d\right) =
    /// \begin{bmatrix}A_d & B_d\\ 0 & I\end{bmatrix}$.
    pub fn zoh(
        &self,
        ch: Channel,
        d: f64,
    ) -> (SMatrix<f64, N_CONT, N_CONT>, SMatrix<f64, N_CONT, N_IN>) {
        let p = self.plant(ch);
        let mut m = SMatrix::<f64, { N_CONT + N_IN }, { N_CONT + N_IN }>::zeros();
        m.fixed_view_mut::<N_CONT, N_CONT>(0, 0)
            .copy_from(&(p.a * d));
        m.fixed_view_mut::<N_CONT, N_IN>(0, N_CONT)
            .copy_from(&(p.b * d));
        let e = m.exp();
        (
            e.fixed_view::<N_CONT, N_CONT>(0, 0).into_owned(),
            e.fixed_view::<N_CONT, N_IN>(0, N_CONT).into_owned(),
        )
    }

    /// The plant alone over `d` seconds with the drive held (no servo sample): used to finish
    /// or start a servo period cut by a communication point.
    pub fn plant_only(&self, ch: Channel, d: f64) -> (Phi, Gamma) {
        let (ad, bd) = self.zoh(ch, d);
        let mut phi = Phi::identity();
        let mut gam = Gamma::zeros();
        for i in 0..N_CONT {
            for j in 0..N_CONT {
                phi[(i, j)] = ad[(i, j)];
            }
            phi[(i, state::DRIVE)] = bd[(i, 0)];
            gam[(i, 1)] = bd[(i, 1)];
            gam[(i, 2)] = bd[(i, 2)];
        }
        (phi, gam)
    }

    /// One servo tick of the sampled closed loop of a channel: $X_{k+1} = \Phi X_k + \Gamma w$.
    pub fn closed_loop(&self, ch: Channel) -> (Phi, Gamma) {
        self.closed_loop_over(ch, self.servo_period())
    }

    /// A servo sample followed by `d` seconds of the plant with the new drive held
    /// (`d` = the servo period for a whole tick).
    pub fn closed_loop_over(&self, ch: Channel, d: f64) -> (Phi, Gamma) {
        use state::*;
        let v = &self.actuator.servo;
        let ts = self.servo_period();
        let (ad, bd) = self.zoh(ch, d);

        let ai = (-TAU * v.integrator_leak * ts).exp();
        let a_d = (-TAU * v.derivative_cutoff * ts).exp();
        let c1 = (1.0 - a_d) / ts;
        let mut phi = Phi::zeros();
        let mut gam = Gamma::zeros();
        // Integrator: I' = a_i I + Ts (u_cmd - x_a + z_c).
        phi[(INTEGRATOR, INTEGRATOR)] = ai;
        phi[(INTEGRATOR, NODE_POS)] = -ts;
        gam[(INTEGRATOR, 0)] = ts;
        gam[(INTEGRATOR, 1)] = ts;
        // Previous stroke: s' = x_a - z_c.
        phi[(PREV_STROKE, NODE_POS)] = 1.0;
        gam[(PREV_STROKE, 1)] = -1.0;
        // Derivative on the measurement: D' = a_d D - c1 (x_a - z_c - s_prev).
        phi[(DERIVATIVE, DERIVATIVE)] = a_d;
        phi[(DERIVATIVE, NODE_POS)] = -c1;
        phi[(DERIVATIVE, PREV_STROKE)] = c1;
        gam[(DERIVATIVE, 1)] = c1;
        // Output u = kp (u_cmd - x_a + z_c) + ki I' + kd D'.
        let mut ux = SMatrix::<f64, 1, N_STATE>::zeros();
        let mut uw = SMatrix::<f64, 1, N_IN>::zeros();
        for j in 0..N_STATE {
            ux[j] = v.ki * phi[(INTEGRATOR, j)] + v.kd * phi[(DERIVATIVE, j)];
        }
        for j in 0..N_IN {
            uw[j] = v.ki * gam[(INTEGRATOR, j)] + v.kd * gam[(DERIVATIVE, j)];
        }
        ux[NODE_POS] -= v.kp;
        uw[0] += v.setpoint_weight * v.kp + v.feedforward;
        uw[1] += v.kp;
        for j in 0..N_STATE {
            phi[(DRIVE, j)] = ux[j];
        }
        for j in 0..N_IN {
            gam[(DRIVE, j)] = uw[j];
        }
        // Plant over the tick with u held: x' = Ad x + Bd0 u + Bd1 z_c + Bd2 f_w.
        for i in 0..N_CONT {
            for j in 0..N_CONT {
                phi[(i, j)] += ad[(i, j)];
            }
            for j in 0..N_STATE {
                phi[(i, j)] += bd[(i, 0)] * ux[j];
            }
            for j in 0..N_IN {
                gam[(i, j)] += bd[(i, 0)] * uw[j];
            }
            gam[(i, 1)] += bd[(i, 1)];
            gam[(i, 2)] += bd[(i, 2)];
        }
        (phi, gam)
    }

    /// Whether the shunt states take part in the dynamics (they stay zero otherwise).
    pub fn has_shunt(&self) -> bool {
        matches!(self.actuator.drive, Drive::Piezo { shunt: Some(_), .. })
    }

    /// Largest eigenvalue modulus of a channel's one-tick closed-loop map, over the states that
    /// take part in the dynamics (without a shunt its two states are inert zeros).
    pub fn spectral_radius(&self, ch: Channel) -> f64 {
        let (phi, _) = self.closed_loop(ch);
        let active: Vec<usize> = (0..N_STATE)
            .filter(|&i| self.has_shunt() || !(i == state::SHUNT || i == state::SHUNT_RATE))
            .collect();
        let sub = nalgebra::DMatrix::from_fn(active.len(), active.len(), |i, j| {
            phi[(active[i], active[j])]
        });
        sub.complex_eigenvalues()
            .iter()
            .map(|l| l.norm())
            .fold(0.0, f64::max)
    }

    /// Output row of the force on the cell from the tick state and held inputs:
    /// $f_{cell} = C X + D w$ (the drive is the one applied over the last servo period).
    pub fn cell_force_map(&self, ch: Channel) -> (SMatrix<f64, 1, N_STATE>, SMatrix<f64, 1, N_IN>) {
        let p = self.plant(ch);
        let mut c = SMatrix::<f64, 1, N_STATE>::zeros();
        for j in 0..N_CONT {
            c[j] = p.cf[j];
        }
        c[state::DRIVE] = p.df[0];
        let mut d = SMatrix::<f64, 1, N_IN>::zeros();
        d[1] = p.df[1];
        d[2] = p.df[2];
        (c, d)
    }

    /// Frequency response of a channel's sampled closed loop from the held inputs
    /// (u_cmd, z_c, f_w) to the mirror displacement, at frequency `f` (Hz):
    /// $H(z) = e_{mirror}^T (zI - \Phi)^{-1}\Gamma$, $z = e^{j 2\pi f T_s}$.
    pub fn mirror_response(&self, ch: Channel, f: f64) -> [nalgebra::Complex<f64>; N_IN] {
        use nalgebra::Complex;
        let (phi, gam) = self.closed_loop(ch);
        let z = Complex::from_polar(1.0, TAU * f * self.servo_period());
        let m: SMatrix<Complex<f64>, N_STATE, N_STATE> =
            SMatrix::<Complex<f64>, N_STATE, N_STATE>::identity() * z
                - phi.map(|x| Complex::new(x, 0.0));
        let g = gam.map(|x| Complex::new(x, 0.0));
        let mut out = [Complex::new(0.0, 0.0); N_IN];
        if let Some(sol) = m.lu().solve(&g) {
            for (j, o) in out.iter_mut().enumerate() {
                *o = sol[(state::MIRROR_POS, j)];
            }
        }
        out
    }
}

/// $(\Phi^M, \sum_{i<M}\Phi^i\Gamma)$: the exact map of M servo ticks with held inputs, by binary
/// powering (no heap allocation).
pub fn propagate(phi: &Phi, gam: &Gamma, ticks: u64) -> (Phi, Gamma) {
    // (P, S) represents X -> P X + S w. Composition "b then a": (Pa Pb, Pa Sb + Sa).
    let mut acc_p = Phi::identity();
    let mut acc_s = Gamma::zeros();
    let mut base_p = *phi;
    let mut base_s = *gam;
    let mut n = ticks;
    while n > 0 {
        if n & 1 == 1 {
            acc_s = base_p * acc_s + base_s;
            acc_p = base_p * acc_p;
        }
        n >>= 1;
        if n > 0 {
            base_s = base_p * base_s + base_s;
            base_p = base_p * base_p;
        }
    }
    (acc_p, acc_s)
}

//! The mirror as one exact discrete-time state-space model at the servo rate
//! ([`StateSpaceMirror`]): the coupled channel subspaces and modes discretised by one matrix
//! exponential, the servo's recursions on the samples, the rest of each channel on a rigid
//! base; and a wind run of it under the global loop ([`wind_run`]).

use faer::c64;
use nalgebra::{DMatrix, DVector, SMatrix};
use std::f64::consts::TAU;

use super::{FrequencyModel, retained_modes, to_actuator_order, to_channel_order, whole_periods};
use crate::M1Error;
use crate::plant::segment::{Channel, N_CONT, SegmentModel, modal_basis, state};
use crate::plant::structure::{ModalModel, ModalSolver};

/// The mirror as one discrete-time state-space model at the servo rate, for time responses:
/// the coupled continuous plant (segment channels and structural modes, coupled without
/// delay) discretised exactly over each servo period with the drive, the wind and the pier
/// held, and the servo's PID recursions on the samples.
///
/// **Size.** The cell moves the channels of a kind only within the span of their shapes
/// (`Phi_k = Q_k R_k`, `Q_k` orthonormal, rank `r_k <= r`), and identical channels keep any
/// subspace to itself, so only `Q_k^T X` couples to the modes: `10 (r_p + r_t) + 2 r` states
/// (660 for Keck with 30 modes). The rest of each channel's state, `(I - Q_k Q_k^T) X`,
/// evolves as on a rigid base and is taken from a [`SegmentArray`](crate::plant::segment::SegmentArray) driven by the same command
/// and wind on a cell at rest. Built once by one matrix exponential of the coupled plant: meant
/// for Keck, or TMT with tens of modes.
#[derive(Debug, Clone)]
pub struct StateSpaceMirror {
    n_segments: usize,
    ts: f64,
    /// Orthonormal bases of the coupled channel subspaces, by kind (n_k x r_k).
    q_basis: [nalgebra::DMatrix<f64>; 2],
    /// Channel shapes in channel order (na x r).
    phic: nalgebra::DMatrix<f64>,
    /// One-tick map of the coupled state and its input map (inputs: projected command, projected
    /// wind, pier).
    tick: nalgebra::DMatrix<f64>,
    tick_in: nalgebra::DMatrix<f64>,
    /// Cached maps of a communication step: (ticks, map, input map).
    step: Option<(u64, nalgebra::DMatrix<f64>, nalgebra::DMatrix<f64>)>,
    /// Offsets of the coupled state: kind blocks, then q, then v.
    ranks: [usize; 2],
    r: usize,
    state: nalgebra::DVector<f64>,
    free: crate::plant::segment::SegmentArray,
    zeros: Vec<f64>,
    basis: SMatrix<f64, 3, 3>,
}

impl StateSpaceMirror {
    /// Same arguments as [`crate::plant::mirror::CoupledMirror::new`] (without the coupling interval:
    /// this model has none).
    pub fn new(
        n_segments: usize,
        model: SegmentModel,
        cell: ModalModel,
        n_modes: usize,
        damping_ratio: f64,
    ) -> Result<Self, M1Error> {
        use crate::plant::segment::N_STATE;
        model.validate()?;
        let na = 3 * n_segments;
        let structure = retained_modes(n_segments, cell, n_modes, damping_ratio)?;
        let fm = FrequencyModel::from_solver(n_segments, model.clone(), &structure)?;
        let r = fm.n_modes();
        let n = n_segments;
        let phic = DMatrix::from_fn(na, r, |i, j| fm.phic[(i, j)]);
        // Q_k, R_k = Q_k^T Phi_k from the SVD of each kind's shapes.
        let (q_basis, r_mat) = coupled_bases(&phic, n)?;
        let ranks = [q_basis[0].ncols(), q_basis[1].ncols()];
        let (a, b) = continuous_plant(&model, &structure, &r_mat, ranks, r);
        // Exact zero-order hold over the servo period.
        let ts = model.servo_period();
        let (ad, bd) = discretise(a, b, ts);
        let (tick, tick_in) = tick_maps(&model, &r_mat, ranks, r, ad, bd, ts);
        let ns = tick.nrows();
        let _ = N_STATE;
        Ok(Self {
            n_segments,
            ts,
            q_basis,
            phic,
            tick,
            tick_in,
            step: None,
            ranks,
            r,
            state: DVector::zeros(ns),
            free: crate::plant::segment::SegmentArray::new(n, model)?,
            zeros: vec![0.0; na],
            basis: modal_basis(),
        })
    }

    /// Back to rest.
    pub fn reset(&mut self) {
        self.state.fill(0.0);
        self.free.reset();
    }

    /// Number of states of the coupled part.
    pub fn n_states(&self) -> usize {
        self.state.len()
    }

    /// Advances `h` seconds (a whole number of servo periods) with the command, the wind
    /// forces (actuator order, length 3N) and the pier displacement held.
    pub fn advance(
        &mut self,
        h: f64,
        u_cmd: &[f64],
        f_wind: &[f64],
        pier_z: f64,
    ) -> Result<(), M1Error> {
        let na = 3 * self.n_segments;
        crate::error::check_lengths(na, &[("u_cmd", u_cmd), ("f_wind", f_wind)])?;
        let k = whole_periods(h, self.ts, "step")?;
        let step = match self.step.take() {
            Some(s) if s.0 == k => s,
            _ => {
                let mut p = nalgebra::DMatrix::identity(self.tick.nrows(), self.tick.ncols());
                let mut g = nalgebra::DMatrix::zeros(self.tick_in.nrows(), self.tick_in.ncols());
                for _ in 0..k {
                    g = &self.tick * g + &self.tick_in;
                    p = &self.tick * p;
                }
                (k, p, g)
            }
        };
        self.free.advance(h, u_cmd, &self.zeros, f_wind)?;
        let nch = self.ranks[0] + self.ranks[1];
        let uc = self.channels(u_cmd);
        let wc = self.channels(f_wind);
        let mut w = nalgebra::DVector::<f64>::zeros(2 * nch + 1);
        let n = self.n_segments;
        let mut off = 0;
        for (kind, (lo, cnt)) in [(0, n), (n, 2 * n)].into_iter().enumerate() {
            let q = &self.q_basis[kind];
            for i in 0..self.ranks[kind] {
                let (mut a, mut b) = (0.0, 0.0);
                for c in 0..cnt {
                    a += q[(c, i)] * uc[lo + c];
                    b += q[(c, i)] * wc[lo + c];
                }
                w[off + i] = a;
                w[nch + off + i] = b;
            }
            off += self.ranks[kind];
        }
        w[2 * nch] = pier_z;
        self.state = &step.1 * &self.state + &step.2 * w;
        self.step = Some(step);
        Ok(())
    }

    fn channels(&self, a: &[f64]) -> Vec<f64> {
        to_channel_order(&self.basis, a)
    }

    fn actuators(&self, c: &[f64], z: &mut [f64]) {
        z.copy_from_slice(&to_actuator_order(&self.basis, c));
    }

    /// Steady-state response of the mirror displacement, sampled at the end of each step of
    /// `h` seconds, to a unit pier tone at `f` Hz sampled at the steps' starts and held over
    /// each: `z_k = Re(X e^{i 2 pi f t_k})` for `p_k = Re(e^{i 2 pi f t_k})`, actuator order.
    pub fn pier_response_sampled(&self, f: f64, h: f64) -> Result<Vec<c64>, M1Error> {
        use nalgebra::Complex;
        let k = whole_periods(h, self.ts, "step")?;
        let mut p = DMatrix::<f64>::identity(self.tick.nrows(), self.tick.ncols());
        let mut g = DVector::<f64>::zeros(self.tick.nrows());
        let pier = self.tick_in.column(self.tick_in.ncols() - 1);
        for _ in 0..k {
            g = &self.tick * g + pier;
            p = &self.tick * p;
        }
        // x_{k+1} = P x_k + g p_k; with x_k = X e^{iwt_k} (the state at t_k, after the step
        // that ends there): (z I - P) X = g, z = e^{iwh}.
        let z = Complex::from_polar(1.0, TAU * f * h);
        let ns = p.nrows();
        let m = DMatrix::<Complex<f64>>::from_fn(ns, ns, |i, j| {
            let d = if i == j { z } else { Complex::new(0.0, 0.0) };
            d - Complex::new(p[(i, j)], 0.0)
        });
        let rhs = g.map(|x| Complex::new(x, 0.0));
        let x = m.lu().solve(&rhs).ok_or(M1Error::Unstable {
            channel: "coupled segments and structure",
            spectral_radius: f64::NAN,
            hint: "the step map has an eigenvalue on the unit circle at this frequency",
        })?;
        // The free part is at rest: channels are Q y.
        let n = self.n_segments;
        let mp = state::MIRROR_POS;
        let mut c = vec![c64::new(0.0, 0.0); 3 * n];
        let mut off = 0;
        for (kind, (lo, cnt)) in [(0, n), (n, 2 * n)].into_iter().enumerate() {
            let q = &self.q_basis[kind];
            for i in 0..self.ranks[kind] {
                let y = x[N_CONT * (off + i) + mp];
                for cc in 0..cnt {
                    c[lo + cc] += y * q[(cc, i)];
                }
            }
            off += self.ranks[kind];
        }
        Ok(to_actuator_order(&self.basis, &c))
    }

    /// Mirror displacement `z` at each actuator (length 3N).
    pub fn mirror(&self, z: &mut [f64]) {
        let n = self.n_segments;
        let mp = state::MIRROR_POS;
        let mut c = vec![0.0; 3 * n];
        let mut off = 0;
        for (kind, (lo, cnt)) in [(0, n), (n, 2 * n)].into_iter().enumerate() {
            let free = &self.free.state()[kind][mp * cnt..(mp + 1) * cnt];
            let q = &self.q_basis[kind];
            // (I - Q Q^T) x_free + Q y.
            for i in 0..self.ranks[kind] {
                let proj: f64 = (0..cnt).map(|c| q[(c, i)] * free[c]).sum();
                let y = self.state[N_CONT * (off + i) + mp];
                for cc in 0..cnt {
                    c[lo + cc] += q[(cc, i)] * (y - proj);
                }
            }
            for cc in 0..cnt {
                c[lo + cc] += free[cc];
            }
            off += self.ranks[kind];
        }
        self.actuators(&c, z);
    }

    /// Cell displacement at each attachment (length 3N).
    pub fn cell_displacement(&self) -> Vec<f64> {
        let nch = self.ranks[0] + self.ranks[1];
        let oq = N_CONT * nch;
        let qv = self.state.rows(oq, self.r);
        let c = &self.phic * qv;
        let mut z = vec![0.0; 3 * self.n_segments];
        self.actuators(c.as_slice(), &mut z);
        z
    }
}

/// One matrix per channel kind (piston, tilt).
type PerKind = [DMatrix<f64>; 2];

/// The orthonormal bases `Q_k` of the channel subspaces the modes move, by kind (rows `0..n` of
/// `phic` for the piston channels, `n..3n` for the tilt channels), and `R_k = Q_k^T Phi_k`,
/// from the SVD of each kind's shapes.
fn coupled_bases(phic: &DMatrix<f64>, n: usize) -> Result<(PerKind, PerKind), M1Error> {
    let mut q_basis = [DMatrix::zeros(0, 0), DMatrix::zeros(0, 0)];
    let mut r_mat = [DMatrix::zeros(0, 0), DMatrix::zeros(0, 0)];
    for (k, (lo, cnt)) in [(0, n), (n, 2 * n)].into_iter().enumerate() {
        let phik = phic.rows(lo, cnt).into_owned();
        let svd = phik.clone().svd(true, false);
        let Some(u) = svd.u else {
            return Err(M1Error::InvalidInput(
                "SVD of the mode shapes did not converge".into(),
            ));
        };
        let smax = svd.singular_values.iter().fold(0.0f64, |a, b| a.max(*b));
        let rank = svd
            .singular_values
            .iter()
            .filter(|&&x| x > 1e-10 * smax)
            .count();
        // nalgebra's SVD does not sort: keep the columns of the significant values.
        let keep: Vec<usize> = (0..svd.singular_values.len())
            .filter(|&i| svd.singular_values[i] > 1e-10 * smax)
            .collect();
        let q = DMatrix::from_fn(cnt, rank, |i, j| u[(i, keep[j])]);
        r_mat[k] = q.transpose() * &phik;
        q_basis[k] = q;
    }
    Ok((q_basis, r_mat))
}

/// The continuous coupled plant `(A, B)`: states the channel states (`N_CONT` per projected
/// channel), then the modal coordinates q and velocities v; inputs the drive and the wind per
/// projected channel, then the pier.
fn continuous_plant(
    model: &SegmentModel,
    structure: &ModalSolver,
    r_mat: &[DMatrix<f64>; 2],
    ranks: [usize; 2],
    r: usize,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let nch = ranks[0] + ranks[1];
    // Continuous coupled plant: channel states (6 per projected channel), then q, v.
    let nc = N_CONT * nch + 2 * r;
    let ni = 2 * nch + 1; // drive, wind (per projected channel), pier
    let mut a = DMatrix::<f64>::zeros(nc, nc);
    let mut b = DMatrix::<f64>::zeros(nc, ni);
    let (oq, ov) = (N_CONT * nch, N_CONT * nch + r);
    let omega: Vec<f64> = structure.frequencies().iter().map(|f| TAU * f).collect();
    let zeta = structure.damping_ratios();
    for j in 0..r {
        a[(oq + j, ov + j)] = 1.0;
        a[(ov + j, oq + j)] = -omega[j] * omega[j];
        a[(ov + j, ov + j)] = -2.0 * zeta[j] * omega[j];
        b[(ov + j, 2 * nch)] = structure.pier_gains()[j];
    }
    let mut ch0 = 0;
    for (k, kind) in [Channel::Piston, Channel::Tilt].into_iter().enumerate() {
        let p = model.plant(kind);
        let rk = &r_mat[k];
        for i in 0..ranks[k] {
            let c = ch0 + i;
            let o = N_CONT * c;
            for x in 0..N_CONT {
                for y in 0..N_CONT {
                    a[(o + x, o + y)] = p.a[(x, y)];
                }
                b[(o + x, c)] = p.b[(x, 0)];
                b[(o + x, nch + c)] = p.b[(x, 2)];
                // z_i = sum_j R[i, j] q_j.
                for j in 0..r {
                    a[(o + x, oq + j)] += p.b[(x, 1)] * rk[(i, j)];
                }
            }
            // Modal force: R_k^T f_k, f = cf x + df (drive, z, wind).
            for j in 0..r {
                let g = rk[(i, j)];
                if g == 0.0 {
                    continue;
                }
                for y in 0..N_CONT {
                    a[(ov + j, o + y)] += g * p.cf[y];
                }
                for l in 0..r {
                    a[(ov + j, oq + l)] += g * p.df[1] * rk[(i, l)];
                }
                b[(ov + j, c)] += g * p.df[0];
                b[(ov + j, nch + c)] += g * p.df[2];
            }
        }
        ch0 += ranks[k];
    }
    (a, b)
}

/// The exact zero-order hold of `(a, b)` over `ts`, `(A_d, B_d)`, from one matrix exponential.
fn discretise(a: DMatrix<f64>, b: DMatrix<f64>, ts: f64) -> (DMatrix<f64>, DMatrix<f64>) {
    let (nc, ni) = (a.nrows(), b.ncols());
    let mut m = DMatrix::<f64>::zeros(nc + ni, nc + ni);
    m.view_mut((0, 0), (nc, nc)).copy_from(&(&a * ts));
    m.view_mut((0, nc), (nc, ni)).copy_from(&(&b * ts));
    let e = m.exp();
    let ad = e.view((0, 0), (nc, nc)).into_owned();
    let bd = e.view((0, nc), (nc, ni)).into_owned();
    (ad, bd)
}

/// The one-tick map `(tick, tick_in)` of the coupled state with the servo: the servo's PID
/// recursions on the sampled strokes of the projected channels, and the continuous part
/// `(ad, bd)` driven by the servo's output.
fn tick_maps(
    model: &SegmentModel,
    r_mat: &[DMatrix<f64>; 2],
    ranks: [usize; 2],
    r: usize,
    ad: DMatrix<f64>,
    bd: DMatrix<f64>,
    ts: f64,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let nch = ranks[0] + ranks[1];
    let (nc, ni) = (ad.nrows(), bd.ncols());
    let oq = N_CONT * nch;
    // The tick map on [continuous (nc), servo (4 per projected channel)], inputs
    // [command (nch), wind (nch), pier].
    let ns = nc + 4 * nch;
    let mut tick = DMatrix::<f64>::zeros(ns, ns);
    let mut tick_in = DMatrix::<f64>::zeros(ns, ni);
    let v = &model.actuator.servo;
    let ai = (-TAU * v.integrator_leak * ts).exp();
    let adf = (-TAU * v.derivative_cutoff * ts).exp();
    let c1 = (1.0 - adf) / ts;
    // Drive u = ux . state + ur r per projected channel; the servo rows.
    let mut ux = DMatrix::<f64>::zeros(nch, ns);
    let mut ur = DVector::<f64>::zeros(nch);
    let mut ch0 = 0;
    for k in 0..2 {
        let rk = &r_mat[k];
        for i in 0..ranks[k] {
            let c = ch0 + i;
            let (si, sp, sd, su) = (nc + 4 * c, nc + 4 * c + 1, nc + 4 * c + 2, nc + 4 * c + 3);
            // Stroke s = x_a - z, z = R q.
            let mut srow = DVector::<f64>::zeros(ns);
            srow[N_CONT * c + state::NODE_POS] = 1.0;
            for j in 0..r {
                srow[oq + j] -= rk[(i, j)];
            }
            // I' = a_i I + Ts (r - s).
            for y in 0..ns {
                tick[(si, y)] = -ts * srow[y];
            }
            tick[(si, si)] += ai;
            tick_in[(si, c)] = ts;
            // s_prev' = s.
            for y in 0..ns {
                tick[(sp, y)] = srow[y];
            }
            // D' = a_d D - c1 (s - s_prev).
            for y in 0..ns {
                tick[(sd, y)] = -c1 * srow[y];
            }
            tick[(sd, sd)] += adf;
            tick[(sd, sp)] += c1;
            // u = k_ff r + kp (b r - s) + ki I' + kd D'.
            for y in 0..ns {
                ux[(c, y)] = -v.kp * srow[y] + v.ki * tick[(si, y)] + v.kd * tick[(sd, y)];
            }
            ur[c] = v.kp * v.setpoint_weight + v.ki * ts + v.feedforward;
            for y in 0..ns {
                tick[(su, y)] = ux[(c, y)];
            }
            tick_in[(su, c)] = ur[c];
        }
        ch0 += ranks[k];
    }
    // Continuous part: x+ = Ad x + Bd_drive u + Bd_wind w + Bd_pier p.
    tick.view_mut((0, 0), (nc, nc)).copy_from(&ad);
    let bdu = bd.columns(0, nch);
    let t_u = bdu * &ux;
    tick.view_mut((0, 0), (nc, ns))
        .zip_apply(&t_u, |x, y| *x += y);
    for c in 0..nch {
        for x in 0..nc {
            tick_in[(x, c)] += bdu[(x, c)] * ur[c];
        }
    }
    tick_in
        .view_mut((0, nch), (nc, nch + 1))
        .copy_from(&bd.columns(nch, nch + 1));
    (tick, tick_in)
}

/// A wind run of the monolithic mirror with (or without) the global loop, scheduled as the
/// co-simulation master runs the standard system (wind, mirror, sensors, controller) in
/// Gauss-Seidel order with a base step `step` under the FMI timing: a component's outputs
/// after its step from t to t + H are visible from the base step that ends at t + H. So the
/// wind, stepping every `wind_period` from t, gives the forces at t + `wind_period`, which the
/// mirror takes on its step that ends then, and holds them; the edge sensors (ideal, $y = A
/// z$) read the mirror at the end of each step; the controller samples them every controller
/// period right after the mirror's first step of it, and its new command reaches the mirror on
/// the step that ends one controller period after the sample began (or on the next step, when
/// the controller steps every base step). Returns the mirror's metrics at the end of every
/// step.
///
/// # Errors
/// [`M1Error::InvalidParameter`] for steps that are not whole multiples, and the errors of
/// the parts.
#[allow(clippy::too_many_arguments)]
pub fn wind_run(
    mirror: &mut StateSpaceMirror,
    metrics: &crate::optics::metrics::MirrorMetrics,
    wind: &crate::loads::wind::WindLoads,
    wind_period: f64,
    control: Option<(
        &crate::control::controller::ControlModes,
        &crate::control::controller::ControllerParams,
    )>,
    step: f64,
    duration: f64,
) -> Result<Vec<(f64, crate::optics::metrics::SurfaceMetrics)>, M1Error> {
    let every = |period: f64, name: &'static str| -> Result<usize, M1Error> {
        whole_periods(period, step, name).map(|k| k as usize)
    };
    let wind_every = every(wind_period, "wind_period")?;
    let na = 3 * mirror.n_segments;
    let steps = (duration / step).round() as usize;
    let mut u = vec![0.0; na];
    let mut fw = vec![0.0; na];
    let mut z = vec![0.0; na];
    let mut out = Vec::with_capacity(steps);
    let mut metrics_scratch = crate::optics::metrics::MetricsScratch::default();
    let ctrl = match control {
        Some((modes, params)) => {
            let gains = params.gains()?;
            let (_, ns) = modes.shape();
            Some((
                modes,
                gains,
                every(1.0 / params.rate, "controller period")?,
                modes.scratch(),
                vec![0.0; ns],
                vec![0.0; ns],
            ))
        }
        None => None,
    };
    let mut ctrl = ctrl;
    // The outputs computed ahead of their time, and the base step from which the mirror takes
    // them.
    let (mut fw_next, mut u_next) = (vec![0.0; na], vec![0.0; na]);
    let (mut fw_at, mut u_at) = (None, None);
    // The wind's initial output: the forces at the start.
    wind.forces(0.0, &mut fw)?;
    for k in 0..steps {
        let t = k as f64 * step;
        if k % wind_every == 0 {
            wind.forces(t + wind_every as f64 * step, &mut fw_next)?;
            fw_at = Some(k + wind_every - 1);
        }
        if fw_at == Some(k) {
            fw.copy_from_slice(&fw_next);
        }
        if u_at == Some(k) {
            u.copy_from_slice(&u_next);
        }
        mirror.advance(step, &u, &fw, 0.0)?;
        mirror.mirror(&mut z);
        if let Some((modes, gains, ctrl_every, scratch, y, y_ref)) = ctrl.as_mut()
            && k % *ctrl_every == 0
        {
            let a = &modes.nominal().a;
            let sym = a.symbolic();
            let (cp, ri, v) = (sym.col_ptr(), sym.row_idx(), a.val());
            y.fill(0.0);
            for (j, &zj) in z.iter().enumerate() {
                for q in cp[j]..cp[j + 1] {
                    y[ri[q]] += v[q] * zj;
                }
            }
            // The controller's integrator is its command as computed, ahead of the mirror's.
            modes.sample(gains, &mut u_next, y, y_ref, scratch)?;
            u_at = Some(k + (*ctrl_every - 1).max(1));
        }
        out.push((t + step, metrics.evaluate_with(&z, &mut metrics_scratch)?));
    }
    Ok(out)
}

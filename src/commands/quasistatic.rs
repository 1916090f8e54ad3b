//! `m1cs amatrix | robustness | noise | clocking | calibration`: the quasi-static analyses of the
//! interaction matrix, each with a readable summary, `--json` (one JSON object on stdout) and
//! `--plot FILE` (PNG).

use clap::Args;
use serde_json::json;

use m1::analysis::defaults::calibration as calibration_defaults;
use m1::analysis::quasistatic::{self, Case, RobustnessParams, default_geometry, svd_summary};
use m1::aperture::geometry::Geometry;
use m1::aperture::layout::{DEFAULT_LAYOUT, Layout};
use m1::aperture::zernike::{ZernikeBasis, noll_to_nm};
use m1::control::nominal::Nominal;
use m1::sensing::interaction::{a_matrix, global_ptt, interaction_matrices};

use crate::plot;

/// Options shared by the analyses: which mirror.
#[derive(Args, Debug, Clone)]
pub struct MirrorArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = DEFAULT_LAYOUT)]
    pub layout: String,
    /// Treat the mirror as flat (ignore the prescription's curvature).
    #[arg(long)]
    pub flat: bool,
    /// Effective moment arm of the sensors' dihedral sensitivity, m (default 0.1).
    #[arg(long)]
    pub leff: Option<f64>,
    /// Print one JSON object instead of the summary.
    #[arg(long)]
    pub json: bool,
}

fn load(m: &MirrorArgs) -> Result<(Layout, Geometry), String> {
    let layout = super::load_layout(&m.layout)?;
    if let Some(l) = m.leff
        && !(l.is_finite() && l >= 0.0)
    {
        return Err(format!("--leff {l}: must be a finite length >= 0 (m)"));
    }
    let g = default_geometry(&layout, m.flat, m.leff).map_err(|e| e.to_string())?;
    Ok((layout, g))
}

/// Segment piston/tip/tilt of an actuator pattern ([`m1::optics::metrics::actuators_to_ptt`]) with
/// the error as CLI text.
fn actuators_to_ptt(g: &Geometry, z: &[f64]) -> Result<Vec<[f64; 3]>, String> {
    m1::optics::metrics::actuators_to_ptt(g, z).map_err(|e| e.to_string())
}

fn unit(v: &mut [f64]) {
    let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if n > 0.0 {
        v.iter_mut().for_each(|x| *x /= n);
    }
}

/// The Zernike (Noll j, n, m) that dominates an actuator pattern, and its share of the fit.
fn dominant_zernike(g: &Geometry, basis: &ZernikeBasis, z: &[f64]) -> (usize, u32, i32, f64) {
    let Ok(ptt) = actuators_to_ptt(g, z) else {
        return (0, 0, 0, 0.0);
    };
    match basis.fit(&ptt) {
        Ok(c) => {
            let total: f64 = c.iter().skip(3).map(|x| x * x).sum();
            let (j, v) = c.iter().enumerate().skip(3).fold((0, 0.0), |acc, (j, x)| {
                if x * x > acc.1 { (j, x * x) } else { acc }
            });
            let (n, m) = noll_to_nm(j + 1);
            (j + 1, n, m, if total > 0.0 { v / total } else { 0.0 })
        }
        Err(_) => (0, 0, 0, 0.0),
    }
}

/// `m1cs amatrix`.
#[derive(Args, Debug)]
pub struct AmatrixArgs {
    #[command(flatten)]
    pub mirror: MirrorArgs,
    /// Also the rank of the full interaction matrix (eq. 1) and of A_gw (dense SVDs of the
    /// larger blocks: seconds for Keck, minutes for TMT).
    #[arg(long)]
    pub full: bool,
    /// Singular-value spectrum PNG.
    #[arg(long)]
    pub plot: Option<String>,
    /// Maps of focus-mode and the next modes: FILE gets "-focus", "-mode2".. suffixes.
    #[arg(long)]
    pub maps: Option<String>,
    /// Number of least-observable modes to report after focus-mode.
    #[arg(long, default_value_t = NEXT_MODES)]
    pub next: usize,
}

/// Least-observable modes reported after focus-mode by default.
const NEXT_MODES: usize = 5;
/// Relative singular-value threshold of the ranks.
const RANK_TOLERANCE: f64 = 1e-9;
/// Radial degree of the Zernike basis the modes are compared with.
const ZERNIKE_DEGREE: u32 = 8;
/// Modes mapped after focus-mode by `--maps`.
const MAPPED_MODES: usize = 3;

/// What `m1cs amatrix` finds.
struct AmatrixReport {
    layout: Layout,
    g: Geometry,
    /// SVD of A itself.
    raw: quasistatic::SvdSummary,
    /// SVD of A P, global piston/tip/tilt projected out.
    obs: quasistatic::SvdSummary,
    /// Right singular vectors of A P (columns).
    v: faer::Mat<f64>,
    /// Focus-mode: the last observable right singular vector.
    focus: Vec<f64>,
    /// |correlation| of focus-mode with Z4 (global PTT projected out).
    corr: f64,
    next: Vec<serde_json::Value>,
    near_null: Vec<f64>,
    full: Option<serde_json::Value>,
}

impl AmatrixReport {
    /// Observable rank.
    fn rank(&self) -> usize {
        self.obs.rank
    }

    /// Right singular vector `col` of A P.
    fn mode(&self, col: usize) -> Vec<f64> {
        (0..self.g.n_actuators())
            .map(|i| self.v[(i, col)])
            .collect()
    }
}

/// Z4 as actuator displacements with global PTT (the orthonormal columns `n`) projected out,
/// unit norm.
fn z4_actuators(
    g: &Geometry,
    basis: &ZernikeBasis,
    n: &faer::Mat<f64>,
) -> Result<Vec<f64>, String> {
    let na = g.n_actuators();
    let z4 = basis.mode(4).ok_or("no Z4 in the basis")?;
    let mut z4a = m1::optics::metrics::ptt_to_actuators(g, &z4).map_err(|e| e.to_string())?;
    for c in 0..3 {
        let d: f64 = (0..na).map(|i| n[(i, c)] * z4a[i]).sum();
        for (i, x) in z4a.iter_mut().enumerate() {
            *x -= d * n[(i, c)];
        }
    }
    unit(&mut z4a);
    Ok(z4a)
}

/// Ranks of the full interaction matrix (eq. 1) and of A_gw (`--full`).
fn full_ranks(g: &Geometry) -> Result<serde_json::Value, String> {
    let im = interaction_matrices(g);
    let (f, _) = svd_summary(&im.full().to_dense(), RANK_TOLERANCE).map_err(|e| e.to_string())?;
    let (gw, _) = svd_summary(&im.a_gw.to_dense(), RANK_TOLERANCE).map_err(|e| e.to_string())?;
    Ok(json!({
        "full_shape": f.shape, "full_rank": f.rank, "full_expected_rank": 6 * g.n_segments() - 6,
        "a_gw_shape": gw.shape, "a_gw_rank": gw.rank,
        "a_gw_smallest": gw.singular_values[gw.singular_values.len().saturating_sub(5)..].to_vec(),
    }))
}

fn amatrix_report(a: &AmatrixArgs) -> Result<AmatrixReport, String> {
    let (layout, g) = load(&a.mirror)?;
    let am = a_matrix(&g);
    let dense = am.to_dense();
    // SVD of A itself: the near-null global piston/tip/tilt and the rank.
    let (raw, _) = svd_summary(&dense, RANK_TOLERANCE).map_err(|e| e.to_string())?;
    // SVD of A P (global PTT projected out): the observable modes.
    let n = m1::control::reconstructor::orthonormalize(global_ptt(&g).as_ref());
    let ap = &dense - (&dense * &n) * n.transpose();
    let (obs, v) = svd_summary(&ap, RANK_TOLERANCE).map_err(|e| e.to_string())?;
    let r = obs.rank;
    let na = g.n_actuators();
    let basis = ZernikeBasis::up_to_degree(&layout, ZERNIKE_DEGREE).map_err(|e| e.to_string())?;
    // Focus-mode against Z4.
    let focus: Vec<f64> = (0..na).map(|i| v[(i, r - 1)]).collect();
    let z4a = z4_actuators(&g, &basis, &n)?;
    let corr = focus
        .iter()
        .zip(&z4a)
        .map(|(a, b)| a * b)
        .sum::<f64>()
        .abs();
    let mut next = Vec::new();
    for k in 0..a.next.min(r.saturating_sub(1)) {
        let col = r - 2 - k;
        let mode: Vec<f64> = (0..na).map(|i| v[(i, col)]).collect();
        let (j, nn, mm, share) = dominant_zernike(&g, &basis, &mode);
        next.push(json!({
            "index": col + 1,
            "singular_value": obs.singular_values[col],
            "dominant_zernike": {"noll": j, "n": nn, "m": mm, "share": share},
        }));
    }
    let near_null: Vec<f64> =
        raw.singular_values[raw.singular_values.len().saturating_sub(3)..].to_vec();
    let full = if a.full { Some(full_ranks(&g)?) } else { None };
    Ok(AmatrixReport {
        layout,
        g,
        raw,
        obs,
        v,
        focus,
        corr,
        next,
        near_null,
        full,
    })
}

fn amatrix_json(a: &AmatrixArgs, r: &AmatrixReport) -> serde_json::Value {
    json!({
        "layout": r.layout.name,
        "flat": a.mirror.flat || r.g.prescription.is_flat(),
        "leff_m": r.g.params.leff,
        "shape": r.raw.shape,
        "rank_of_a": r.raw.rank,
        "global_ptt_singular_values": r.near_null,
        "observable_rank": r.rank(),
        "largest": r.obs.largest,
        "smallest_nonzero": r.obs.smallest_nonzero,
        "condition_number": r.obs.condition_number,
        "focus_singular_value": r.obs.smallest_nonzero,
        "focus_z4_correlation": r.corr,
        "next_modes": r.next,
        "full": r.full,
        "singular_values": r.obs.singular_values,
    })
}

/// `--plot`: the observable singular values, focus-mode and the next marked.
fn plot_spectrum(p: &str, r: &AmatrixReport) -> Result<(), String> {
    let rank = r.rank();
    let mut marks = vec![(rank - 1, "focus-mode")];
    if rank >= 2 {
        marks.push((rank - 2, "next (astigmatism-like)"));
    }
    let title = format!(
        "Singular values of A ({}, {} x {}), global PTT projected out",
        r.layout.name, r.raw.shape.0, r.raw.shape.1
    );
    plot::spectrum(
        p,
        &r.obs.singular_values[..rank],
        &title,
        "singular value",
        true,
        &marks,
    )
    .map_err(|e| e.to_string())
}

/// `--maps`: focus-mode and the next [`MAPPED_MODES`] modes as segment PTT maps.
fn plot_maps(base: &str, r: &AmatrixReport) -> Result<(), String> {
    let stem = base.trim_end_matches(".png");
    let ptt = actuators_to_ptt(&r.g, &r.focus)?;
    plot::mirror_map_ptt(
        format!("{stem}-focus.png"),
        &r.layout,
        &ptt,
        "Focus-mode (unit norm)",
        "",
    )
    .map_err(|e| e.to_string())?;
    for k in 0..MAPPED_MODES.min(r.rank().saturating_sub(1)) {
        let col = r.rank() - 2 - k;
        let ptt = actuators_to_ptt(&r.g, &r.mode(col))?;
        let title = format!(
            "Mode {} (singular value {:.3e})",
            col + 1,
            r.obs.singular_values[col]
        );
        plot::mirror_map_ptt(
            format!("{stem}-mode{}.png", k + 2),
            &r.layout,
            &ptt,
            &title,
            "",
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn print_amatrix(r: &AmatrixReport, out: &serde_json::Value) {
    let (g, raw, obs, near_null) = (&r.g, &r.raw, &r.obs, &r.near_null);
    println!(
        "A-matrix of {} ({}; Leff = {} m): {} sensors x {} actuators",
        r.layout.name,
        if g.prescription.is_flat() {
            "flat"
        } else {
            "curved prescription"
        },
        g.params.leff,
        raw.shape.0,
        raw.shape.1
    );
    println!("  rank of A (1e-9 relative): {}", raw.rank);
    println!(
        "  global piston/tip/tilt singular values (weakly observable through curvature): {:.3e} {:.3e} {:.3e}",
        near_null.first().copied().unwrap_or(0.0),
        near_null.get(1).copied().unwrap_or(0.0),
        near_null.get(2).copied().unwrap_or(0.0)
    );
    println!(
        "  with global PTT projected out: rank {} of {}",
        r.rank(),
        g.n_actuators()
    );
    println!(
        "  largest singular value {:.4}, smallest non-zero (focus-mode) {:.4e}, condition number {:.1}",
        obs.largest, obs.smallest_nonzero, obs.condition_number
    );
    println!("  focus-mode correlation with Zernike Z4: {:.5}", r.corr);
    println!("  next least observable modes:");
    for m in &r.next {
        println!(
            "    #{:>5}  sv {:.4e}  dominant Z{} (n={}, m={}), {:.0}% of the fit",
            m["index"],
            m["singular_value"].as_f64().unwrap_or(0.0),
            m["dominant_zernike"]["noll"],
            m["dominant_zernike"]["n"],
            m["dominant_zernike"]["m"],
            100.0 * m["dominant_zernike"]["share"].as_f64().unwrap_or(0.0)
        );
    }
    if let Some(f) = out["full"].as_object() {
        let shape = |v: &serde_json::Value| format!("{} x {}", v[0], v[1]);
        println!(
            "  full matrix {}: rank {} (expected 6N - 6 = {}); A_gw {}: rank {}",
            shape(&f["full_shape"]),
            f["full_rank"],
            f["full_expected_rank"],
            shape(&f["a_gw_shape"]),
            f["a_gw_rank"]
        );
    }
}

/// Runs `m1cs amatrix`.
pub fn amatrix(a: &AmatrixArgs) -> Result<(), String> {
    let r = amatrix_report(a)?;
    let out = amatrix_json(a, &r);
    if let Some(p) = &a.plot {
        plot_spectrum(p, &r)?;
    }
    if let Some(base) = &a.maps {
        plot_maps(base, &r)?;
    }
    if a.mirror.json {
        println!("{out}");
        return Ok(());
    }
    print_amatrix(&r, &out);
    Ok(())
}

/// `m1cs robustness`.
#[derive(Args, Debug)]
pub struct RobustnessArgs {
    #[command(flatten)]
    pub mirror: MirrorArgs,
    /// Realizations per random case.
    #[arg(long, default_value_t = RobustnessParams::default().realizations)]
    pub realizations: usize,
    /// Realizations of the element-error cases (their instability risk, to 1 in this many).
    #[arg(long, default_value_t = RobustnessParams::default().risk_realizations)]
    pub risk_realizations: usize,
    /// Focus-mode gain reduction factor of Gamma.
    #[arg(long, default_value_t = RobustnessParams::default().focus_gain_factor)]
    pub focus_gain_factor: f64,
    /// Seed of the realizations.
    #[arg(long, default_value_t = RobustnessParams::default().seed)]
    pub seed: u64,
    /// Krylov dimension of the eigenvalue and singular-value estimates.
    #[arg(long, default_value_t = RobustnessParams::default().krylov_dim)]
    pub krylov: usize,
    /// Histogram PNG of sigma_max(Gamma Psi Q Psi^T) over the realizations of every case.
    #[arg(long)]
    pub plot: Option<String>,
}

/// Runs `m1cs robustness`.
pub fn robustness(a: &RobustnessArgs) -> Result<(), String> {
    if a.realizations == 0 || a.risk_realizations == 0 {
        return Err("--realizations and --risk-realizations must be at least 1".into());
    }
    if !(a.focus_gain_factor.is_finite() && a.focus_gain_factor >= 1.0) {
        return Err(format!(
            "--focus-gain-factor {}: must be >= 1",
            a.focus_gain_factor
        ));
    }
    if a.krylov < 4 {
        return Err("--krylov must be at least 4".into());
    }
    let (layout, g) = load(&a.mirror)?;
    let nominal = Nominal::new(g).map_err(|e| e.to_string())?;
    let params = RobustnessParams {
        realizations: a.realizations,
        focus_gain_factor: a.focus_gain_factor,
        seed: a.seed,
        krylov_dim: a.krylov,
        risk_realizations: a.risk_realizations,
        ..RobustnessParams::default()
    };
    let cases = Case::defaults();
    let bar = indicatif::ProgressBar::new(0);
    if a.mirror.json {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} realizations, {elapsed} (eta {eta})",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let t0 = std::time::Instant::now();
    let results = quasistatic::robustness(&nominal, &cases, &params, &|k, n| {
        bar.set_length(n as u64);
        bar.set_position(k as u64);
    })
    .map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    let seconds = t0.elapsed().as_secs_f64();
    if let Some(p) = &a.plot {
        let series: Vec<(String, Vec<(f64, f64)>)> = results
            .iter()
            .map(|r| {
                let mut v = r.sigma_gamma_q.values.clone();
                v.sort_by(|a, b| a.total_cmp(b));
                let n = v.len() as f64;
                (
                    r.case.name.clone(),
                    v.iter()
                        .enumerate()
                        .map(|(i, x)| (*x, (i + 1) as f64 / n))
                        .collect(),
                )
            })
            .collect();
        let refs: Vec<(&str, &[(f64, f64)])> = series
            .iter()
            .map(|(n, s)| (n.as_str(), s.as_slice()))
            .collect();
        plot::lines(
            p,
            &refs,
            &format!(
                "Cumulative distribution of sigma_max(Gamma Psi Q Psi^T), {}",
                layout.name
            ),
            "sigma_max(Gamma Psi Q Psi^T)",
            "fraction of realizations",
            true,
            false,
        )
        .map_err(|e| e.to_string())?;
    }
    if a.mirror.json {
        let out = json!({
            "layout": layout.name,
            "params": params,
            "focus_singular_value": nominal.focus_singular_value,
            "seconds": seconds,
            "cases": results,
        });
        println!("{out}");
        return Ok(());
    }
    println!(
        "Robustness of the reconstructor to A-matrix errors, {} ({} realizations per random case, focus gain / {}):",
        layout.name, a.realizations, a.focus_gain_factor
    );
    println!(
        "{:<26} {:>10} {:>8} {:>8} {:>9} {:>10} {:>8} | {:>8} {:>6} {:>6} {:>7}",
        "case",
        "rho(Q-I)",
        "sig(Q)",
        "sig(GQ)",
        "median sQ",
        "min Re eig",
        "unstable",
        "paper: rho",
        "sig(Q)",
        "sig(GQ)",
        "risk"
    );
    for r in &results {
        let paper = match r.case.published {
            Some(quasistatic::Published::Metrics([a, b, c])) => {
                format!("{a:>10.1e} {b:>6.2} {c:>6.2} {:>7}", "")
            }
            Some(quasistatic::Published::Risk { fraction, at_least }) => format!(
                "{:>10} {:>6} {:>6} {:>7}",
                "",
                "",
                "",
                format!(
                    "{}{:.1}%",
                    if at_least { ">" } else { "" },
                    100.0 * fraction
                )
            ),
            None => String::new(),
        };
        println!(
            "{:<26} {:>10.2e} {:>8.3} {:>8.3} {:>9.3} {:>10.3} {:>7.1}% | {paper}",
            r.case.name,
            r.rho_q_minus_i.worst,
            r.sigma_q.worst,
            r.sigma_gamma_q.worst,
            r.sigma_q.median,
            r.min_real_eigenvalue
                .values
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min),
            100.0 * r.unstable_fraction
        );
    }
    println!(
        "(worst case over the realizations; stable if rho(Q - I) < 1 and every eigenvalue of Q has a positive real part; {seconds:.1} s)"
    );
    Ok(())
}

/// `m1cs noise`.
#[derive(Args, Debug)]
pub struct NoiseArgs {
    #[command(flatten)]
    pub mirror: MirrorArgs,
    /// Map PNG of the rms error per segment per unit rms sensor noise.
    #[arg(long)]
    pub plot: Option<String>,
}

/// Runs `m1cs noise`.
pub fn noise(a: &NoiseArgs) -> Result<(), String> {
    let (layout, g) = load(&a.mirror)?;
    let nominal = Nominal::new(g).map_err(|e| e.to_string())?;
    let r = quasistatic::noise_propagation(&nominal);
    if let Some(p) = &a.plot {
        plot::mirror_map(
            p,
            &layout,
            &r.per_segment_rms,
            "rms error per segment per unit rms sensor noise",
            "m/m",
        )
        .map_err(|e| e.to_string())?;
    }
    if a.mirror.json {
        println!(
            "{}",
            json!({"layout": layout.name, "noise": r, "focus_singular_value": nominal.focus_singular_value})
        );
    } else {
        println!(
            "Sensor-noise propagation, {} (global piston/tip/tilt removed):",
            layout.name
        );
        println!(
            "  rms actuator error per unit rms sensor noise: {:.3} (m/m)",
            r.rms_per_noise
        );
        println!(
            "  without focus-mode:                           {:.3} (m/m)",
            r.rms_per_noise_without_focus
        );
        println!(
            "  focus-mode share of the variance:             {:.1}%",
            100.0 * r.focus_share
        );
    }
    Ok(())
}

/// `m1cs clocking`.
#[derive(Args, Debug)]
pub struct ClockingArgs {
    #[command(flatten)]
    pub mirror: MirrorArgs,
    /// The clocked segment: its name (A1..F82 for TMT) or index [default: the layout's first
    /// segment, A1 for TMT].
    #[arg(long)]
    pub segment: Option<String>,
    /// Map PNG of the out-of-plane correction.
    #[arg(long)]
    pub plot: Option<String>,
}

/// Runs `m1cs clocking`.
pub fn clocking(a: &ClockingArgs) -> Result<(), String> {
    let (layout, g) = load(&a.mirror)?;
    let name = a
        .segment
        .clone()
        .unwrap_or_else(|| layout.segments[0].name.clone());
    let seg = layout
        .find(&name)
        .or_else(|| {
            name.parse::<usize>()
                .ok()
                .filter(|&i| i < layout.n_segments())
        })
        .ok_or_else(|| format!("--segment {name}: no such segment in {}", layout.name))?;
    let nominal = Nominal::new(g).map_err(|e| e.to_string())?;
    let r = quasistatic::clocking(&nominal, seg).map_err(|e| e.to_string())?;
    if let Some(p) = &a.plot {
        let ptt = actuators_to_ptt(&nominal.geometry, &r.z)?;
        let ptt_nm: Vec<[f64; 3]> = ptt
            .iter()
            .map(|s| [s[0] * 1e9, s[1] * 1e9, s[2] * 1e9])
            .collect();
        plot::mirror_map_ptt(
            p,
            &layout,
            &ptt_nm,
            &format!(
                "Correction for 1 mrad clocking of {}",
                layout.segments[seg].name
            ),
            "nm",
        )
        .map_err(|e| e.to_string())?;
    }
    if a.mirror.json {
        println!(
            "{}",
            json!({"layout": layout.name, "segment": layout.segments[seg].name, "clocking": r})
        );
    } else {
        println!(
            "Clocking of segment {} by 1 mrad on {} ({}):",
            layout.segments[seg].name,
            layout.name,
            if nominal.geometry.prescription.is_flat() {
                "flat"
            } else {
                "curved prescription"
            }
        );
        println!(
            "  rms out-of-plane correction: {:.3} nm per mrad ({:.3} nm without focus-mode)",
            r.rms_per_mrad * 1e9,
            r.rms_per_mrad_without_focus * 1e9
        );
    }
    Ok(())
}

/// `m1cs calibration`.
#[derive(Args, Debug)]
pub struct CalibrationArgs {
    #[command(flatten)]
    pub mirror: MirrorArgs,
    /// Monte Carlo samples of the check of the exact figures.
    #[arg(long, default_value_t = calibration_defaults::SAMPLES)]
    pub samples: usize,
    /// Seed of the Monte Carlo check.
    #[arg(long, default_value_t = calibration_defaults::SEED)]
    pub seed: u64,
    /// Relative singular-value threshold of the pseudo-inverse of A_gw: smaller singular values
    /// (gap-unobservable and weakly observable in-plane modes) are not inverted.
    #[arg(long, default_value_t = quasistatic::SHEAR_RANK_TOLERANCE)]
    pub rank_tolerance: f64,
    /// Map PNG of the rms shear error per segment from gap-unobservable in-plane motion.
    #[arg(long)]
    pub plot: Option<String>,
}

/// Runs `m1cs calibration`.
pub fn calibration(a: &CalibrationArgs) -> Result<(), String> {
    if a.samples == 0 {
        return Err("--samples must be at least 1".into());
    }
    if !(a.rank_tolerance > 0.0 && a.rank_tolerance < 1.0) {
        return Err(format!(
            "--rank-tolerance {}: must be in (0, 1)",
            a.rank_tolerance
        ));
    }
    let (layout, g) = load(&a.mirror)?;
    let r = quasistatic::calibration(&g, a.samples, a.seed, a.rank_tolerance)
        .map_err(|e| e.to_string())?;
    if let Some(p) = &a.plot {
        plot::mirror_map(
            p,
            &layout,
            &r.per_segment_shear_error_unobservable,
            "Shear error from gap-unobservable motion (per unit in-plane rms)",
            "m/m",
        )
        .map_err(|e| e.to_string())?;
    }
    if a.mirror.json {
        println!("{}", json!({"layout": layout.name, "calibration": r}));
    } else {
        println!(
            "Shear estimated from gaps (y_s = A_sw A_gw^+ y_g), {}:",
            layout.name
        );
        println!(
            "  A_gw: {} of {} in-plane coordinates inverted (singular values above {:.0e} of the \
             largest; smallest kept {:.2e})",
            r.gap_rank, r.in_plane_dofs, r.rank_tolerance, r.smallest_kept_relative
        );
        if r.weakly_observable > 0 {
            println!(
                "  {} weakly observable in-plane modes not inverted (largest {:.2e} of the \
                 largest singular value)",
                r.weakly_observable, r.largest_dropped_relative
            );
        }
        println!(
            "  shear error from gap-unobservable motion: {:.4} m per m rms in-plane motion \
             (Monte Carlo, {} samples: {:.4})",
            r.shear_error_unobservable,
            r.monte_carlo.samples,
            r.monte_carlo.shear_error_unobservable
        );
        println!(
            "  shear error per unit rms gap noise:       {:.4} m/m (Monte Carlo: {:.4})",
            r.shear_error_per_gap_noise, r.monte_carlo.shear_error_per_gap_noise
        );
    }
    Ok(())
}

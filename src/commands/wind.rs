//! `m1cs wind`: the mirror's response to wind versus wind speed and global-loop bandwidth,
//! without and with control (the seed paper's Figure 12), by the included master on the
//! standard wind system.

use std::path::PathBuf;
use std::sync::LazyLock;

use clap::Args;
use serde_json::json;

use m1::analysis::defaults::wind as wind_study;
use m1::aperture::layout::Layout;

use super::cosim::{
    Cell, Scenario, SystemArgs, Variant, run_one, segment_rms_map, settled_rms, split_off_z,
    standard_system,
};
use super::defaults::list;
use crate::plot;

/// `--help`'s form of the default sweeps.
static SPEEDS: LazyLock<String> = LazyLock::new(|| list(&wind_study::SPEEDS));
static BANDWIDTHS: LazyLock<String> = LazyLock::new(|| list(&wind_study::BANDWIDTHS));

/// Arguments of `m1cs wind`.
#[derive(Args, Debug)]
pub struct WindArgs {
    /// Mirror layout (keck, tmt, elt): FMUs are taken from FMU_DIR/LAYOUT/.
    #[arg(long, default_value = m1::aperture::layout::DEFAULT_LAYOUT)]
    pub layout: String,
    /// Actuator variant.
    #[arg(long, value_enum, default_value_t = Variant::Voicecoil)]
    pub actuator: Variant,
    /// Where the packaged FMUs are (`cargo xtask package` writes them).
    #[arg(long, default_value = super::FMU_DIR)]
    pub fmu_dir: PathBuf,
    /// Mean wind speeds (m/s), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = SPEEDS.as_str())]
    pub speeds: Vec<f64>,
    /// Global-loop bandwidths on the modes of radial degrees >= 5 (Hz), comma-separated; radial
    /// degrees 3-4 and 2 get the baseline's ratios of each (1 / 1.5 and 0.75 / 1.5, from m1's
    /// default bandwidths), focus-mode --focus-bandwidth.
    #[arg(long, value_delimiter = ',', default_value = BANDWIDTHS.as_str())]
    pub bandwidths: Vec<f64>,
    /// Global-loop bandwidth on focus-mode (Hz).
    #[arg(long, default_value_t = m1::control::controller::DEFAULT_BANDWIDTH_FOCUS)]
    pub focus_bandwidth: f64,
    /// Mirror cell: `coupled` (the mirror FMU), `quasi-static` (its quasi-static plant) or
    /// `rigid` (no structure).
    #[arg(long, value_enum, default_value_t = Cell::Coupled)]
    pub cell: Cell,
    /// Structure modes retained.
    #[arg(long, default_value_t = super::cosim::STRUCTURE_MODES)]
    pub structure_modes: i32,
    #[arg(long, default_value = m1::plant::structure::DEFAULT_STRUCTURE, help = super::STRUCTURE_HELP)]
    pub structure: String,
    /// Simulated duration of each run (s); statistics over its second half.
    #[arg(long, default_value_t = super::cosim::DURATION)]
    pub duration: f64,
    /// Base communication step (s).
    #[arg(long, default_value_t = super::cosim::STEP)]
    pub step: f64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Write rms_vs_speed.png and the M1 maps (open and closed loop at the highest speed and
    /// the highest bandwidth) into this directory.
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// One run's settled statistics (second half), in metres.
struct Stats {
    rms: f64,
    /// Focus-mode coefficient (unit-norm actuator vector).
    focus: f64,
    without_focus: f64,
    /// rms of the last quarter over the second quarter: above 1.5 the loop is growing.
    growth: f64,
    /// Per-segment rms residual (nm) for the maps.
    map: Vec<f64>,
}

fn stats(
    layout: &m1::aperture::layout::Layout,
    o: &mut super::cosim::Outcome,
) -> Result<Stats, String> {
    let z = split_off_z(&mut o.results);
    let col = |n: &str| o.results.column(n).unwrap_or_else(|| vec![f64::NAN]);
    let rms = col("optics.rms_surface");
    let q = rms.len() / 4;
    let window = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let growth = if q > 0 {
        window(&rms[3 * q..]) / window(&rms[q..2 * q]).max(1e-300)
    } else {
        f64::NAN
    };
    Ok(Stats {
        rms: settled_rms(&rms),
        focus: settled_rms(&col("optics.focus_mode")),
        without_focus: settled_rms(&col("optics.rms_surface_without_focus")),
        growth,
        map: if z.is_empty() {
            Vec::new()
        } else {
            segment_rms_map(layout, &z)?
        },
    })
}

/// The bandwidths of radial degrees 3-4 and 2 for the bandwidth `bw` of radial degrees >= 5 in a
/// sweep: the baseline's ratios to it ([`m1::control::controller::DEFAULT_BANDWIDTH_RADIAL34`] and
/// [`m1::control::controller::DEFAULT_BANDWIDTH_RADIAL2`] over [`m1::control::controller::DEFAULT_BANDWIDTH`]), so
/// the sweep scales the whole loop but focus-mode.
fn group_bandwidths(bw: f64) -> (f64, f64) {
    use m1::control::controller::{
        DEFAULT_BANDWIDTH, DEFAULT_BANDWIDTH_RADIAL2, DEFAULT_BANDWIDTH_RADIAL34,
    };
    (
        bw * DEFAULT_BANDWIDTH_RADIAL34 / DEFAULT_BANDWIDTH,
        bw * DEFAULT_BANDWIDTH_RADIAL2 / DEFAULT_BANDWIDTH,
    )
}

/// Share of the residual's variance that is focus-mode: 1 - (rms without focus / rms)^2.
fn focus_share(s: &Stats) -> f64 {
    (1.0 - (s.without_focus / s.rms).powi(2)).max(0.0)
}

/// A run's growth (last quarter over second quarter) above this is a growing, unstable loop.
const GROWING: f64 = 1.5;

fn growing(g: f64) -> bool {
    g.is_finite() && g > GROWING
}

/// One closed-loop run of the sweep: wind speed, bandwidth, the open loop's rms at that speed
/// (m) and the closed loop's statistics.
type Row = (f64, f64, f64, Stats);

/// What the sweep found: the rows, and the maps (open and closed loop at the highest speed
/// and the highest bandwidth).
struct Sweep {
    rows: Vec<Row>,
    maps: Vec<(String, Vec<f64>)>,
}

fn check_wind_args(a: &WindArgs) -> Result<(), String> {
    if a.speeds.is_empty() || a.speeds.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(format!(
            "--speeds {:?}: give positive wind speeds (m/s)",
            a.speeds
        ));
    }
    if a.bandwidths.is_empty() || a.bandwidths.iter().any(|b| !(b.is_finite() && *b > 0.0)) {
        return Err(format!(
            "--bandwidths {:?}: give positive bandwidths (Hz)",
            a.bandwidths
        ));
    }
    if a.cell == Cell::Split {
        return Err("--cell split needs a 0.2 ms step: use coupled or rigid here".into());
    }
    Ok(())
}

/// The standard wind system of the first speed and bandwidth, the base of every run.
fn base_system(a: &WindArgs) -> SystemArgs {
    SystemArgs {
        layout: a.layout.clone(),
        actuator: a.actuator,
        scenario: Scenario::Wind,
        fmu_dir: a.fmu_dir.clone(),
        wind_speed: a.speeds[0],
        bandwidth: a.bandwidths[0],
        bandwidth_radial34: group_bandwidths(a.bandwidths[0]).0,
        bandwidth_radial2: group_bandwidths(a.bandwidths[0]).1,
        focus_bandwidth: a.focus_bandwidth,
        cell: a.cell,
        structure_modes: a.structure_modes,
        structure: a.structure.clone(),
        solver_threads: 0,
        uniform: false,
        optical: false,
        zenith: None,
        temperature: 0.0,
        duration: Some(a.duration),
        step: Some(a.step),
    }
}

/// Every speed open loop, and closed loop at every bandwidth.
fn sweep(a: &WindArgs, layout: &Layout) -> Result<Sweep, String> {
    let base = base_system(a);
    let metrics = [
        "optics.rms_surface",
        "optics.focus_mode",
        "optics.rms_surface_without_focus",
    ];
    let mirror = if matches!(a.cell, Cell::Coupled | Cell::QuasiStatic) {
        "mirror.z"
    } else {
        "segments.z"
    };
    let record: Vec<&str> = metrics.iter().copied().chain([mirror]).collect();
    // Every FMU opened once for all the runs (shared unpacked files, library and caches).
    let first = standard_system(&base, false)?;
    let paths: Vec<&std::path::Path> = first.components.iter().map(|c| c.fmu.as_path()).collect();
    let _open = cosim::Fmu::open_all(&paths).map_err(|e| e.to_string())?;
    let mut rows = Vec::new();
    let mut maps: Vec<(String, Vec<f64>)> = Vec::new();
    for (i, &speed) in a.speeds.iter().enumerate() {
        let args = SystemArgs {
            wind_speed: speed,
            ..base.clone()
        };
        let mut open = run_one(
            &format!("{speed} m/s open"),
            &standard_system(&args, false)?,
            1,
            &record,
            None,
        )?;
        let open_stats = stats(layout, &mut open)?;
        let last_speed = i + 1 == a.speeds.len();
        if last_speed {
            maps.push((format!("open loop, {speed} m/s"), open_stats.map.clone()));
        }
        for (j, &bw) in a.bandwidths.iter().enumerate() {
            let (bw34, bw2) = group_bandwidths(bw);
            let args = SystemArgs {
                wind_speed: speed,
                bandwidth: bw,
                bandwidth_radial34: bw34,
                bandwidth_radial2: bw2,
                ..base.clone()
            };
            let mut closed = run_one(
                &format!("{speed} m/s {bw} Hz"),
                &standard_system(&args, true)?,
                1,
                &record,
                None,
            )?;
            let s = stats(layout, &mut closed)?;
            if last_speed && j + 1 == a.bandwidths.len() {
                maps.push((format!("closed loop {bw} Hz, {speed} m/s"), s.map.clone()));
            }
            rows.push((speed, bw, open_stats.rms, s));
        }
    }
    Ok(Sweep { rows, maps })
}

fn nm(x: f64) -> f64 {
    x * 1e9
}

fn wind_json(a: &WindArgs, rows: &[Row]) -> serde_json::Value {
    json!({
        "layout": a.layout,
        "actuator": format!("{:?}", a.actuator).to_lowercase(),
        "cell": format!("{:?}", a.cell).to_lowercase(),
        "structure_modes": a.structure_modes,
        "structure": a.structure,
        "duration_s": a.duration,
        "focus_bandwidth_hz": a.focus_bandwidth,
        "statistics": "rms over the second half of each run",
        "runs": rows.iter().map(|(speed, bw, open, s)| json!({
            "wind_speed_m_per_s": speed,
            "bandwidth_hz": bw,
            "bandwidth_radial34_hz": group_bandwidths(*bw).0,
            "bandwidth_radial2_hz": group_bandwidths(*bw).1,
            "open_loop_rms_surface_nm": nm(*open),
            "closed_loop_rms_surface_nm": nm(s.rms),
            "closed_loop_focus_mode_nm": nm(s.focus),
            "closed_loop_rms_without_focus_nm": nm(s.without_focus),
            "focus_share_of_residual_variance": focus_share(s),
            "rejection_ratio": s.rms / open,
            "growth_last_over_second_quarter": s.growth,
            "growing": growing(s.growth),
        })).collect::<Vec<_>>(),
    })
}

fn print_wind(a: &WindArgs, rows: &[Row]) {
    let (r34, r2) = group_bandwidths(1.0);
    println!(
        "{} {:?} actuators, {:?} cell, {} s per run (statistics over the second half); bw on \
         radial degrees >= 5, {r34:.3} of it on 3-4, {r2:.3} on 2, focus-mode {} Hz:",
        a.layout, a.actuator, a.cell, a.duration, a.focus_bandwidth
    );
    println!(
        "{:>10} {:>10} {:>12} {:>12} {:>11} {:>14} {:>10} {:>8}",
        "wind (m/s)",
        "bw (Hz)",
        "open (nm)",
        "closed (nm)",
        "focus share",
        "w/o focus (nm)",
        "closed/open",
        "growing"
    );
    for (speed, bw, open, s) in rows {
        println!(
            "{:>10.2} {:>10.3} {:>12.2} {:>12.2} {:>11.3} {:>14.2} {:>10.3} {:>8}",
            speed,
            bw,
            nm(*open),
            nm(s.rms),
            focus_share(s),
            nm(s.without_focus),
            s.rms / open,
            if growing(s.growth) { "yes" } else { "no" }
        );
    }
    if rows.iter().any(|r| growing(r.3.growth)) {
        println!(
            "growing: the residual's last quarter is over 1.5x its second quarter, an \
             unstable global loop (see README, the TMT closed loop)"
        );
    }
}

/// `--plot DIR`: rms_vs_speed.png and the open and closed-loop maps.
fn plot_wind(
    dir: &std::path::Path,
    a: &WindArgs,
    layout: &Layout,
    sweep: &Sweep,
) -> Result<(), String> {
    let rows = &sweep.rows;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    let open: Vec<(f64, f64)> = a
        .speeds
        .iter()
        .filter_map(|sp| rows.iter().find(|r| r.0 == *sp).map(|r| (*sp, nm(r.2))))
        .collect();
    series.push(("open loop".into(), open));
    for &bw in &a.bandwidths {
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.1 == bw)
            .map(|r| (r.0, nm(r.3.rms)))
            .collect();
        series.push((format!("closed loop, {bw} Hz"), pts));
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.1 == bw)
            .map(|r| (r.0, nm(r.3.without_focus)))
            .collect();
        series.push((format!("closed {bw} Hz without focus-mode"), pts));
    }
    let refs: Vec<(&str, &[(f64, f64)])> = series
        .iter()
        .map(|(l, p)| (l.as_str(), p.as_slice()))
        .collect();
    plot::lines(
        dir.join("rms_vs_speed.png"),
        &refs,
        &format!(
            "{}: M1 rms surface under wind (second half of each run)",
            a.layout
        ),
        "wind speed (m/s)",
        "rms surface (nm)",
        a.speeds.len() > 1,
        true,
    )
    .map_err(|e| e.to_string())?;
    for (k, (label, map)) in sweep.maps.iter().enumerate() {
        if map.is_empty() {
            continue;
        }
        let file = if k == 0 {
            "map_open_loop.png"
        } else {
            "map_closed_loop.png"
        };
        plot::mirror_map(
            dir.join(file),
            layout,
            map,
            &format!("{}, {label}: rms residual surface per segment", a.layout),
            "nm",
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// Runs `m1cs wind`.
pub fn wind(a: &WindArgs) -> Result<(), String> {
    let layout = super::load_layout(&a.layout)?;
    check_wind_args(a)?;
    let sweep = sweep(a, &layout)?;
    if a.json {
        println!("{}", wind_json(a, &sweep.rows));
    } else {
        print_wind(a, &sweep.rows);
    }
    if let Some(dir) = &a.plot {
        plot_wind(dir, a, &layout, &sweep)?;
    }
    Ok(())
}

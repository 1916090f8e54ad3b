//! `m1cs`: the command-line tool of the segmented-mirror control-system toolset. This file
//! parses the command line and dispatches; each subcommand lives in [`commands`], the figures
//! in [`plot`], the physics in the `m1` crate.

use clap::{Parser, Subcommand};
use std::process::ExitCode;

mod commands;
mod plot;

#[derive(Parser)]
#[command(
    name = "m1cs",
    version,
    about = "Segmented primary-mirror control-system modelling: FMI components and analyses"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Runs the segments FMUs' model on a layout: command step response and static stiffness of
    /// each actuator variant.
    Demo(commands::demo::DemoArgs),
    /// SVD of the A-matrix: rank, near-null global piston/tip/tilt, focus-mode and the next
    /// least observable modes (with their dominant Zernike), optional full-matrix ranks.
    Amatrix(commands::quasistatic::AmatrixArgs),
    /// Robustness to A-matrix errors (the seed paper's Table 1): rho(Q - I), sigma(Q),
    /// sigma(Gamma Psi Q Psi^T) and the risk of instability over seeded realizations.
    Robustness(commands::quasistatic::RobustnessArgs),
    /// Propagation of white sensor noise to the mirror, with and without focus-mode.
    Noise(commands::quasistatic::NoiseArgs),
    /// Out-of-plane error the control introduces for in-plane clocking of one segment (eq. 3).
    Clocking(commands::quasistatic::ClockingArgs),
    /// Shear estimated from gap readings (eq. 2): the unobservable torsion mode and gap noise.
    Calibration(commands::quasistatic::CalibrationArgs),
    /// The overall quasi-static simulation: a month of nights with gravity and thermal
    /// deformation, installed sensors, calibration, APS and optical feedback (four variants).
    Overall(commands::overall::OverallArgs),
    /// Zernike basis on the segmented aperture and its segment piston/tip/tilt projection.
    Zernike(commands::optics::ZernikeArgs),
    /// PSSN of a seeded random segment piston/tip/tilt state.
    Pssn(commands::optics::PssnArgs),
    /// Runs the closed-loop scenario (default: TMT, wind, voice coils, open and closed loop) or a
    /// user's .ssp with the included master; CSV, plots and a summary in --out.
    Run(commands::cosim::RunCmd),
    /// Segments and structure as two co-simulation components against the coupled solver: the
    /// largest communication step each actuator variant tolerates, and why one mirror FMU.
    Coupling(commands::dynamics::CouplingArgs),
    /// Control-structure interaction of the actuator servo loop: sensitivity in Zernike and
    /// segment bases and with all segments, and the highest servo gain meeting the criterion.
    Csi(commands::csi::CsiArgs),
    /// M1 rms surface under wind versus wind speed and global-loop bandwidth, open and closed
    /// loop, with the focus-mode share and M1 maps (the master on the standard wind system).
    Wind(commands::wind::WindArgs),
    /// M1 rms surface and PSSN versus pier frequency for the three actuator variants, from the
    /// monolithic frequency model; the hard/soft and undamped/damped ratios at 29.6 Hz.
    Vibration(commands::dynamics::VibrationArgs),
    /// Runs every analysis with its defaults into DIR: one Markdown page (index.md) with the
    /// figures and the key numbers of each.
    Report(commands::report::ReportArgs),
    /// Writes a standard closed-loop system (layout x actuator x scenario) as an SSP archive.
    System(commands::cosim::SystemCmd),
    /// The on-disk cache of computed arrays (the structure's modes, the wind's tables): where
    /// it is, what it holds; `--clear` empties it.
    Cache(commands::cache::CacheArgs),
    /// Reports a layout: segments, actuators, edges, sensors and the neighbour histogram.
    #[command(alias = "layout")]
    Geometry(commands::geometry::GeometryArgs),
}

fn main() -> ExitCode {
    // Like other Unix tools, end quietly when the reader of our output goes away
    // (`m1cs run | head`) instead of failing on the broken pipe.
    #[cfg(unix)]
    // SAFETY: called first in main, before any other thread exists; SIG_DFL is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Keep freed large blocks in the allocator instead of unmapping them at every free and
    // faulting them in again at the next allocation: `m1cs csi` builds and factorises several
    // 16 MB complex matrices per frequency point (1000 modes), and glibc serves blocks above
    // its threshold from fresh mappings (4 % of that command's time in page faults and
    // zeroing). 32 MB is the largest threshold glibc accepts on 64-bit targets.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: called in main before any other thread exists; it only tunes the allocator.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 << 20);
    }
    let r = match Cli::parse().command {
        Cmd::Demo(a) => commands::demo::demo(&a),
        Cmd::Geometry(a) => commands::geometry::geometry(&a),
        Cmd::Amatrix(a) => commands::quasistatic::amatrix(&a),
        Cmd::Run(a) => commands::cosim::run_cmd(&a),
        Cmd::System(a) => commands::cosim::system(&a),
        Cmd::Cache(a) => commands::cache::cache(&a),
        Cmd::Coupling(a) => commands::dynamics::coupling(&a),
        Cmd::Csi(a) => commands::csi::csi(&a),
        Cmd::Wind(a) => commands::wind::wind(&a),
        Cmd::Vibration(a) => commands::dynamics::vibration(&a),
        Cmd::Report(a) => commands::report::report(&a),
        Cmd::Robustness(a) => commands::quasistatic::robustness(&a),
        Cmd::Noise(a) => commands::quasistatic::noise(&a),
        Cmd::Clocking(a) => commands::quasistatic::clocking(&a),
        Cmd::Calibration(a) => commands::quasistatic::calibration(&a),
        Cmd::Overall(a) => commands::overall::overall(&a),
        Cmd::Zernike(a) => commands::optics::run_zernike(&a),
        Cmd::Pssn(a) => commands::optics::run_pssn(&a),
    };
    if commands::cosim::interrupted() {
        // Stopped by Ctrl-C or SIGTERM: the rows until then are written (said on stderr), the
        // temporary folders removed; the shell's convention for an interrupted command.
        if let Err(e) = r {
            eprintln!("error: {e}");
        }
        return ExitCode::from(130);
    }
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

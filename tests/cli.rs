//! End-to-end tests of the `m1cs` analysis commands on Keck: JSON output that parses, with the
//! physics identities the analyses must show, and clear errors for bad input.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // tests panic on failure by design

use std::process::Command;

fn m1cs(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_m1cs"))
        .args(args)
        .output()
        .expect("run m1cs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn json(args: &[&str]) -> serde_json::Value {
    let (ok, out, err) = m1cs(args);
    assert!(ok, "m1cs {args:?} failed: {err}");
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("not one JSON object ({e}): {out}"))
}

#[test]
fn geometry_counts() {
    let v = json(&["geometry", "--layout", "keck", "--json"]);
    assert_eq!(v["segments"], 36);
    assert_eq!(v["actuators"], 108);
    assert_eq!(v["sensors"], 168);
    let v = json(&["geometry", "--layout", "tmt", "--json"]);
    assert_eq!(
        (v["segments"].as_u64(), v["sensors"].as_u64()),
        (Some(492), Some(2772))
    );
}

/// `m1cs pssn` reports how the OTF was computed: on Keck's default grid 30 lag rows carry
/// weight, so the rows' spectra are correlated, with row FFTs of at least N + 30 points and
/// fewer than the padded grid's; the state's PSSN is below each of its parts'.
#[test]
fn pssn_reports_its_otf_method() {
    let v = json(&["pssn", "--layout", "keck", "--json"]);
    assert_eq!(v["otf_method"], "correlation");
    let (samples, rows) = (
        v["samples"].as_u64().unwrap(),
        v["otf_lag_rows"].as_u64().unwrap(),
    );
    let (p, m) = (
        v["row_fft_size"].as_u64().unwrap(),
        v["fft_size"].as_u64().unwrap(),
    );
    assert_eq!((samples, rows), (256, 30));
    assert!(
        p >= samples + rows && p < m,
        "row FFTs of {p}, padded grid {m}"
    );
    let part = |k: &str| v["pssn"][k].as_f64().unwrap();
    let combined = part("combined");
    assert!(
        combined > 0.5 && combined < part("piston_only").min(part("tilt_only")),
        "{v}"
    );
}

#[test]
fn amatrix_structure_on_keck() {
    let v = json(&["amatrix", "--layout", "keck", "--full", "--json"]);
    // Global piston/tip/tilt projected out: na - 3 observable modes.
    assert_eq!(v["observable_rank"], 105);
    assert!(v["focus_z4_correlation"].as_f64().unwrap() > 0.99);
    // The next least observable modes are astigmatism (n = 2, |m| = 2).
    let next = v["next_modes"].as_array().unwrap();
    for m in &next[..2] {
        assert_eq!(m["dominant_zernike"]["n"], 2, "{m}");
    }
    assert_eq!(v["full"]["full_rank"], v["full"]["full_expected_rank"]);
    // Flat mirror with Leff = 0: focus-mode becomes unobservable too.
    let v = json(&[
        "amatrix", "--layout", "keck", "--flat", "--leff", "0", "--json",
    ]);
    assert_eq!(v["observable_rank"], 104);
}

#[test]
fn robustness_sensor_gains_never_destabilise() {
    let v = json(&[
        "robustness",
        "--layout",
        "keck",
        "--realizations",
        "5",
        "--risk-realizations",
        "20",
        "--json",
    ]);
    for case in v["cases"].as_array().unwrap() {
        let name = case["case"]["name"].as_str().unwrap();
        if name.starts_with("sensor gain") {
            assert_eq!(case["unstable_fraction"], 0.0, "{name}");
            // Reducing focus-mode's gain can only help.
            let s = case["sigma_q"]["worst"].as_f64().unwrap();
            let sg = case["sigma_gamma_q"]["worst"].as_f64().unwrap();
            assert!(sg <= s + 1e-9, "{name}: {sg} > {s}");
        }
    }
}

#[test]
fn clocking_is_an_effect_of_curvature() {
    let flat = json(&[
        "clocking",
        "--layout",
        "keck",
        "--flat",
        "--segment",
        "1",
        "--json",
    ]);
    assert!(flat["clocking"]["rms_per_mrad"].as_f64().unwrap() < 1e-15);
    let curved = json(&["clocking", "--layout", "keck", "--segment", "1", "--json"]);
    assert!(curved["clocking"]["rms_per_mrad"].as_f64().unwrap() > 1e-12);
}

#[test]
fn noise_is_dominated_by_focus_mode() {
    let v = json(&["noise", "--layout", "keck", "--json"]);
    let total = v["noise"]["rms_per_noise"].as_f64().unwrap();
    let rest = v["noise"]["rms_per_noise_without_focus"].as_f64().unwrap();
    assert!(rest < total && total > 1.0);
    // The per-segment distribution has the same mean square as the whole.
    let per: Vec<f64> = v["noise"]["per_segment_rms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!(per.len(), 36);
    let ms = per.iter().map(|x| x * x).sum::<f64>() / 36.0;
    assert!(
        (ms.sqrt() - total).abs() < 1e-9 * total,
        "{} vs {total}",
        ms.sqrt()
    );
}

#[test]
fn calibration_reports_the_gap_rank() {
    let v = json(&["calibration", "--layout", "keck", "--flat", "--json"]);
    assert_eq!(v["calibration"]["gap_rank"], 104);
    let (ok, _, err) = m1cs(&["calibration", "--layout", "keck", "--rank-tolerance", "2"]);
    assert!(!ok && err.contains("--rank-tolerance"), "{err}");
}

/// Every `--plot` writes a PNG.
#[test]
fn plots_are_written() {
    let dir = std::env::temp_dir().join(format!("m1cs-cli-plots-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = |name: &str| dir.join(name).to_string_lossy().into_owned();
    let cases: Vec<(Vec<&str>, String)> = vec![
        (vec!["geometry", "--layout", "keck"], file("geometry.png")),
        (vec!["noise", "--layout", "keck"], file("noise.png")),
        (
            vec!["calibration", "--layout", "keck", "--samples", "5"],
            file("calibration.png"),
        ),
        (vec!["clocking", "--layout", "keck"], file("clocking.png")),
        (vec!["amatrix", "--layout", "keck"], file("amatrix.png")),
    ];
    for (args, png) in &cases {
        let mut a = args.clone();
        a.extend(["--plot", png.as_str()]);
        let (ok, _, err) = m1cs(&a);
        assert!(ok, "m1cs {a:?}: {err}");
        let bytes = std::fs::read(png).unwrap_or_else(|e| panic!("{png}: {e}"));
        assert!(bytes.starts_with(b"\x89PNG") && bytes.len() > 5000, "{png}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_input_is_named() {
    let (ok, _, err) = m1cs(&["amatrix", "--layout", "nosuch"]);
    assert!(!ok && err.contains("nosuch"), "{err}");
    let (ok, _, err) = m1cs(&["robustness", "--layout", "keck", "--realizations", "0"]);
    assert!(!ok && err.contains("--realizations"), "{err}");
    let (ok, _, err) = m1cs(&["clocking", "--layout", "keck", "--segment", "Z99"]);
    assert!(!ok && err.contains("Z99"), "{err}");
    let (ok, _, err) = m1cs(&["amatrix", "--layout", "keck", "--leff=-1"]);
    assert!(!ok && err.contains("--leff"), "{err}");
}

fn fmu_dir() -> String {
    std::env::var("M1CS_FMU_DIR")
        .unwrap_or_else(|_| concat!(env!("CARGO_MANIFEST_DIR"), "/target/fmu").to_string())
}

/// Issue 6: the wind residual with zero controller gains equals the open-loop response. The
/// standard Keck wind system run closed loop with every bandwidth at 0 (the controller FMU
/// enabled, sampling the sensors and integrating with zero gain) records exactly the open
/// loop's rows: nothing but the gains separates the two runs.
#[test]
fn zero_gain_wind_run_is_the_open_loop() {
    let dir = std::env::temp_dir().join(format!("m1cs-cli-zero-gain-{}", std::process::id()));
    let out = dir.to_string_lossy().into_owned();
    let fmus = fmu_dir();
    let v = json(&[
        "run",
        "--layout",
        "keck",
        "--duration",
        "1",
        "--bandwidth",
        "0",
        "--bandwidth-radial34",
        "0",
        "--bandwidth-radial2",
        "0",
        "--focus-bandwidth",
        "0",
        "--fmu-dir",
        &fmus,
        "--out",
        &out,
        "--json",
    ]);
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    assert_eq!(runs[0]["rms_surface_m"], runs[1]["rms_surface_m"], "{v}");
    let open = std::fs::read_to_string(dir.join("open_loop.csv")).unwrap();
    let closed = std::fs::read_to_string(dir.join("closed_loop.csv")).unwrap();
    assert!(open.lines().count() > 900, "{} rows", open.lines().count());
    assert_eq!(
        open, closed,
        "closed loop with zero gains differs from the open loop"
    );
    // And with the default gains it does not.
    let v = json(&[
        "run",
        "--layout",
        "keck",
        "--duration",
        "1",
        "--fmu-dir",
        &fmus,
        "--out",
        &out,
        "--json",
    ]);
    let runs = v["runs"].as_array().unwrap();
    assert_ne!(runs[0]["rms_surface_m"], runs[1]["rms_surface_m"], "{v}");
    std::fs::remove_dir_all(&dir).ok();
}

/// The standard Keck wind system through the included master: runs open and closed loop
/// (rigid cell and coupled mirror at the default 1 ms; the split segments/structure pair at 0.2 ms in Gauss-Seidel order), writes CSV, plots and a summary whose figures are
/// finite and physical; the same system written as .ssp runs from the file.
#[test]
fn run_and_system_on_keck() {
    let dir = std::env::temp_dir().join(format!("m1cs-cli-run-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("results").to_string_lossy().into_owned();
    let fmus = fmu_dir();
    for extra in [
        vec!["--cell", "rigid"],
        vec!["--cell", "coupled"],
        vec![
            "--cell",
            "split",
            "--step",
            "2e-4",
            "--order",
            "gauss-seidel",
        ],
    ] {
        let mut args = vec![
            "run",
            "--layout",
            "keck",
            "--duration",
            "1",
            "--fmu-dir",
            &fmus,
            "--out",
            &out,
            "--json",
        ];
        args.extend(extra.iter().copied());
        let v = json(&args);
        let runs = v["runs"].as_array().unwrap();
        assert_eq!(runs.len(), 2);
        for r in runs {
            let rms = r["rms_surface_m"].as_f64().unwrap();
            let pssn = r["pssn"].as_f64().unwrap();
            assert!(rms > 1e-10 && rms < 1e-6, "{extra:?}: rms {rms}");
            assert!(pssn > 0.1 && pssn <= 1.0, "{extra:?}: pssn {pssn}");
        }
        for f in [
            "open_loop.csv",
            "closed_loop.csv",
            "rms_surface.png",
            "summary.json",
        ] {
            assert!(dir.join("results").join(f).is_file(), "{f}");
        }
        let csv = std::fs::read_to_string(dir.join("results/closed_loop.csv")).unwrap();
        assert!(
            csv.starts_with("time,optics.rms_surface,"),
            "{}",
            &csv[..80]
        );
    }
    // The vibration scenario compares the three actuator variants, with a map per variant and
    // the spectra overlaid; the 29.6 Hz pier tone dominates every spectrum's band above 20 Hz.
    let v = json(&[
        "run",
        "--layout",
        "keck",
        "--scenario",
        "vibration",
        "--duration",
        "1",
        "--fmu-dir",
        &fmus,
        "--out",
        &out,
        "--json",
    ]);
    let runs = v["runs"].as_array().unwrap();
    let labels: Vec<&str> = runs.iter().map(|r| r["run"].as_str().unwrap()).collect();
    assert_eq!(labels, ["voicecoil", "piezo", "piezo damped"]);
    for r in runs {
        let rms = r["rms_surface_m"].as_f64().unwrap();
        assert!(rms > 1e-11 && rms < 1e-7, "{rms}");
    }
    for f in [
        "map_voicecoil.png",
        "map_piezo.png",
        "map_piezo_damped.png",
        "spectrum.png",
        "piezo_damped.csv",
    ] {
        assert!(dir.join("results").join(f).is_file(), "{f}");
    }
    let ssp = dir.join("keck.ssp").to_string_lossy().into_owned();
    let (ok, _, err) = m1cs(&[
        "system",
        "--layout",
        "keck",
        "--cell",
        "rigid",
        "--step",
        "1e-3",
        "--duration",
        "0.5",
        "--fmu-dir",
        &fmus,
        "-o",
        &ssp,
    ]);
    assert!(ok, "{err}");
    let (ok, stdout, err) = m1cs(&["run", "--ssp", &ssp, "--out", &out, "--json"]);
    assert!(ok && !err.contains("overrides"), "{err}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    // The file says gauss-seidel (the standard systems' order); --order overrides it, saying so.
    let (ok, _, err) = m1cs(&[
        "run", "--ssp", &ssp, "--out", &out, "--json", "--order", "jacobi",
    ]);
    assert!(
        ok && err.contains("--order jacobi overrides the order") && err.contains("(gauss-seidel)"),
        "{err}"
    );
    assert_eq!(v["runs"].as_array().unwrap().len(), 1);
    assert!(v["runs"][0]["rms_surface_m"].as_f64().unwrap() > 0.0);
    assert!(
        (v["duration_s"].as_f64().unwrap() - 0.5).abs() < 1e-9,
        "{v}"
    );
    // --stop-time overrides the file's stop time.
    let v = json(&[
        "run",
        "--ssp",
        &ssp,
        "--stop-time",
        "0.2",
        "--out",
        &out,
        "--json",
    ]);
    assert!(
        (v["duration_s"].as_f64().unwrap() - 0.2).abs() < 1e-9,
        "{v}"
    );
    // Missing FMUs are named with the fix.
    let (ok, _, err) = m1cs(&["run", "--layout", "keck", "--fmu-dir", "/nonexistent"]);
    assert!(!ok && err.contains("cargo xtask package"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// `m1cs coupling`: the split voice coil is bounded at the servo period and diverges at two
/// periods; the split piezo (4.3 N/um stacks) stays bounded but is far off (over 15 %); only
/// Gauss-Seidel at the servo period is accurate to 1 %; a step that is not a multiple of the
/// servo period is an error naming it; the plot is written.
#[test]
fn coupling_needs_the_servo_period() {
    let dir = std::env::temp_dir().join(format!("m1cs_coupling_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join("coupling.png");
    let v = json(&[
        "coupling",
        "--structure",
        "soft-cell",
        "--steps",
        "0.0002,0.0004",
        "--duration",
        "1",
        "--json",
        "--plot",
        png.to_str().unwrap(),
    ]);
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 3 * 2 * 2);
    let find = |variant: &str, order: &str, step: f64| {
        runs.iter()
            .find(|r| r["variant"] == variant && r["order"] == order && r["step_s"] == step)
            .unwrap_or_else(|| panic!("{variant} {order} {step}"))
    };
    for order in ["gauss-seidel", "jacobi"] {
        assert_eq!(find("voicecoil", order, 0.0002)["stable"], true);
        assert_eq!(find("voicecoil", order, 0.0004)["stable"], false);
        let piezo = find("piezo", order, 0.0002);
        assert_eq!(piezo["stable"], true);
        assert!(piezo["relative_error"].as_f64().unwrap() > 0.15, "{piezo}");
    }
    // Gauss-Seidel at the servo period follows the coupled solver (0.1 % apart); Jacobi's
    // lagged cell displacement is 2 % off; nothing else is accurate to 1 %.
    let best = v["largest_accurate_step_s"].as_object().unwrap();
    assert_eq!(best["voicecoil/GaussSeidel"], 0.0002, "{v}");
    let gs = find("voicecoil", "gauss-seidel", 0.0002)["relative_error"]
        .as_f64()
        .unwrap();
    assert!(gs < 0.005, "{v}");
    assert!(
        best.iter()
            .filter(|(k, _)| *k != "voicecoil/GaussSeidel")
            .all(|(_, s)| s.is_null()),
        "{v}"
    );
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    let (ok, _, err) = m1cs(&["coupling", "--steps", "0.0003"]);
    assert!(!ok && err.contains("communicationStepSize"), "{err}");
    let (ok, _, err) = m1cs(&["coupling", "--modes", "0"]);
    assert!(!ok && err.contains("--modes"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// `m1cs wind` on Keck: the open-loop response grows as the dynamic pressure (U^2), the loop
/// reduces it, and the table's shares are fractions; bad speeds are named.
#[test]
fn wind_sweep_on_keck() {
    let dir = fmu_dir();
    let v = json(&[
        "wind",
        "--layout",
        "keck",
        "--fmu-dir",
        &dir,
        "--structure-modes",
        "30",
        "--speeds",
        "2,4",
        "--bandwidths",
        "0.5",
        "--duration",
        "2",
        "--json",
    ]);
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    let open: Vec<f64> = runs
        .iter()
        .map(|r| r["open_loop_rms_surface_nm"].as_f64().unwrap())
        .collect();
    let ratio = open[1] / open[0];
    assert!(
        (2.5..6.5).contains(&ratio),
        "open loop 4 m/s / 2 m/s = {ratio}"
    );
    for r in runs {
        let closed = r["closed_loop_rms_surface_nm"].as_f64().unwrap();
        let open = r["open_loop_rms_surface_nm"].as_f64().unwrap();
        assert!(closed > 0.0 && closed < open, "{r}");
        let share = r["focus_share_of_residual_variance"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&share), "{r}");
        assert_eq!(r["growing"], false, "{r}");
    }
    let (ok, _, err) = m1cs(&["wind", "--layout", "keck", "--speeds=-1", "--fmu-dir", &dir]);
    assert!(!ok && err.contains("--speeds"), "{err}");
}

/// `m1cs vibration` on Keck: three variants with finite, positive curves, the soft actuator's
/// main resonance among the cell modes, the hard actuator responding more at 29.6 Hz, the PSSN
/// a fraction below 1; bad ranges are named.
#[test]
fn vibration_curves_on_keck() {
    // On the soft-cell preset, whose cell modes the assertions describe.
    let v = json(&[
        "vibration",
        "--layout",
        "keck",
        "--structure",
        "soft-cell",
        "--modes",
        "30",
        "--step",
        "1",
        "--json",
    ]);
    let variants = v["variants"].as_array().unwrap();
    assert_eq!(variants.len(), 3);
    for c in variants {
        let curve = c["rms_surface_nm_per_nm"].as_array().unwrap();
        assert!(curve.len() >= 60, "{}", curve.len());
        assert!(curve.iter().all(|x| x.as_f64().unwrap() > 0.0), "{c}");
        let p = c["pssn_at_29_6_hz"].as_f64().unwrap();
        assert!(p > 0.9 && p < 1.0, "{c}");
    }
    let soft = &variants[0];
    assert_eq!(soft["actuator"], "voicecoil");
    let fpeak = soft["peak_frequency_hz"].as_f64().unwrap();
    assert!((2.0..20.0).contains(&fpeak), "{fpeak}");
    assert!(
        v["ratio_hard_over_soft_at_29_6_hz"].as_f64().unwrap() > 1.0,
        "{v}"
    );
    let (ok, _, err) = m1cs(&[
        "vibration",
        "--layout",
        "keck",
        "--fmin",
        "5",
        "--fmax",
        "2",
    ]);
    assert!(!ok && err.contains("--fmin"), "{err}");
}

/// rms of a CSV column over `[from, to)` s.
fn window_rms(csv: &str, column: &str, from: f64, to: f64) -> f64 {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let c = header.iter().position(|h| *h == column).unwrap();
    let (mut sum, mut n) = (0.0, 0usize);
    for l in lines {
        let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
        if (from..to).contains(&v[0]) {
            sum += v[c] * v[c];
            n += 1;
        }
    }
    (sum / n as f64).sqrt()
}

/// Issue 14 item 4: `--cell quasi-static` (the mirror FMU's quasi-static plant, seed paper
/// section 4.1) gives the coupled plant's open-loop wind response on Keck within 1 % (measured
/// 0.03 %), the closed loop within 15 % (5 %: what it drops lies above a few Hz), and refuses
/// the vibration scenario.
#[test]
fn quasi_static_cell_follows_the_coupled_one_in_wind() {
    let run = |cell: &str| {
        let dir = std::env::temp_dir().join(format!("m1cs-qs-{cell}-{}", std::process::id()));
        let v = json(&[
            "run",
            "--layout",
            "keck",
            "--cell",
            cell,
            "--fmu-dir",
            &fmu_dir(),
            "--out",
            dir.to_str().unwrap(),
            "--json",
        ]);
        std::fs::remove_dir_all(&dir).ok();
        let r = v["runs"].as_array().unwrap().clone();
        (
            r[0]["rms_surface_m"].as_f64().unwrap(),
            r[1]["rms_surface_m"].as_f64().unwrap(),
        )
    };
    let (qo, qc) = run("quasi-static");
    let (co, cc) = run("coupled");
    eprintln!("keck open {co:.3e} / {qo:.3e}, closed {cc:.3e} / {qc:.3e}");
    assert!((qo / co - 1.0).abs() < 0.01, "open loop {qo} vs {co}");
    assert!((qc / cc - 1.0).abs() < 0.15, "closed loop {qc} vs {cc}");
    let (ok, _, err) = m1cs(&[
        "run",
        "--layout",
        "keck",
        "--cell",
        "quasi-static",
        "--scenario",
        "vibration",
        "--fmu-dir",
        &fmu_dir(),
    ]);
    assert!(!ok && err.contains("--cell coupled"), "{err}");
}

/// Issue 14 acceptance, the main job on its defaults (TMT, 1 m/s wind, the seed paper's
/// Figure 12 case) over 20 s: the closed loop at most half the open loop's rms surface and at
/// most a quarter without focus-mode (paper: 39 -> 15 nm, 6 nm without focus-mode), and no
/// growth (the last quarter's rms of the rms surface at most 1.2x the quarter before).
#[test]
fn issue_14_main_job_rejects_the_wind_without_growth() {
    let dir = std::env::temp_dir().join(format!("m1cs-main-job-{}", std::process::id()));
    let v = json(&[
        "run",
        "--duration",
        "20",
        "--fmu-dir",
        &fmu_dir(),
        "--out",
        dir.to_str().unwrap(),
        "--json",
    ]);
    let runs = v["runs"].as_array().unwrap();
    let get = |i: usize, k: &str| runs[i][k].as_f64().unwrap_or_else(|| panic!("{k}: {v}"));
    assert_eq!(runs[0]["run"], "open loop");
    let (open, closed) = (get(0, "rms_surface_m"), get(1, "rms_surface_m"));
    assert!(closed <= 0.5 * open, "{closed} vs {open}");
    let (open, closed) = (
        get(0, "rms_surface_without_focus_m"),
        get(1, "rms_surface_without_focus_m"),
    );
    assert!(closed <= 0.25 * open, "{closed} vs {open}");
    let csv = std::fs::read_to_string(dir.join("closed_loop.csv")).unwrap();
    let (third, last) = (
        window_rms(&csv, "optics.rms_surface", 10.0, 15.0),
        window_rms(&csv, "optics.rms_surface", 15.0, 20.1),
    );
    assert!(last <= 1.2 * third, "{last} vs {third}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Issue 14 acceptance, the loops on the defaults with 300 structure modes (`m1cs csi --layout
/// tmt --modes 300`): the servo criterion (sigma_max(S) < 2 below 15 Hz, all segments) met at
/// the nominal gains; the global loop at the baseline bandwidths with peak sensitivity under 2
/// and principal loop gain at most 1/4 from 8 Hz up, all segments; the highest bandwidth at
/// least the nominal 1.5 Hz; the Zernike bases converge (degrees 7 and 8 within 1 %) and more
/// segments never lower the peak.
#[test]
fn issue_14_csi_on_tmt_with_300_modes_meets_the_criteria() {
    let v = json(&["csi", "--layout", "tmt", "--modes", "300", "--json"]);
    let f = |x: &serde_json::Value| x.as_f64().unwrap_or_else(|| panic!("{x}: {v}"));
    let servo = &v["highest_gain"];
    assert_eq!(servo["meets_criterion"], true, "{servo}");
    assert!(f(&servo["gain_factor"]) >= 1.0, "{servo}");
    assert!(f(&v["sweep"]["all_segments"]["peak_sensitivity"]) < 2.0);
    let g = &v["global"];
    assert_eq!(g["meets_sensitivity"], true);
    assert_eq!(g["meets_loop_gain"], true);
    let all = &g["all_segments"];
    assert!(f(&all["peak_sensitivity"]) < 2.0, "{all}");
    assert!(f(&all["high_frequency_loop_gain"]) <= 0.25, "{all}");
    assert!(f(&all["high_frequency_loop_gain_hz"]) >= 8.0, "{all}");
    assert!(f(&g["highest_bandwidth"]["bandwidth_hz"]) >= 1.5, "{g}");
    let peaks = |k: &str| -> Vec<f64> {
        v["sweep"][k]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| f(&c["peak_sensitivity"]))
            .collect()
    };
    let z = peaks("zernike");
    assert!(z.len() >= 9, "{z:?}");
    assert!((z[8] / z[7] - 1.0).abs() < 0.01, "{z:?}");
    let seg = peaks("segments");
    assert!(seg.windows(2).all(|w| w[1] >= w[0] - 1e-9), "{seg:?}");
}

/// Issue 14 acceptance, seed paper Figure 13 on the defaults (`m1cs vibration --layout tmt`):
/// the hard actuator responds at least 2.5x the soft one and the undamped hard one at least 3x
/// the damped one somewhere in 29.4-29.8 Hz; the three variants are within 20 % below 3 Hz.
#[test]
fn issue_14_vibration_on_tmt_reproduces_figure_13() {
    let v = json(&[
        "vibration",
        "--layout",
        "tmt",
        "--fmin",
        "1",
        "--fmax",
        "32",
        "--step",
        "0.25",
        "--pssn-every",
        "1000",
        "--json",
    ]);
    let r = |k: &str| v[k].as_f64().unwrap_or_else(|| panic!("{k}: {v}"));
    assert!(r("ratio_hard_over_soft_max_29_4_to_29_8_hz") >= 2.5, "{v}");
    assert!(
        r("ratio_undamped_over_damped_max_29_4_to_29_8_hz") >= 3.0,
        "{v}"
    );
    let spread = r("variant_spread_below_3_hz");
    assert!((0.0..0.2).contains(&spread), "{spread}");
}

/// `m1cs report` on Keck (without the co-simulation runs): one page with a section, numbers
/// and figures per analysis, every linked figure written; a bad layout is named.
#[test]
fn report_on_keck() {
    let dir = std::env::temp_dir().join(format!("m1cs-report-{}", std::process::id()));
    let (ok, out, err) = m1cs(&[
        "report",
        dir.to_str().unwrap(),
        "--layout",
        "keck",
        "--no-cosim",
    ]);
    assert!(ok, "{out}\n{err}");
    let md = std::fs::read_to_string(dir.join("index.md")).unwrap();
    for title in [
        "## Interaction matrix",
        "## Robustness to interaction-matrix errors",
        "## Vibration",
        "## Coupling delay",
        "## Control-structure interaction",
    ] {
        assert!(md.contains(title), "{title} missing");
    }
    // The CSI section shows its selected numbers and its three figures.
    assert!(
        md.contains("| `global.highest_bandwidth.bandwidth_hz` |"),
        "{md}"
    );
    assert!(md.contains("| `highest_gain.gain_factor` |"), "{md}");
    // Labelled peaks are one row each; the output directory is written DIR, not its path.
    assert!(
        md.contains("| `global.all_segment_peaks[0]` | frequency_hz "),
        "{md}"
    );
    assert!(!md.contains(dir.to_str().unwrap()), "{md}");
    for f in [
        "csi/sensitivity.png",
        "csi/convergence.png",
        "csi/global.png",
        "csi/global_band.png",
    ] {
        assert!(md.contains(&format!("![{f}]")), "{f} not shown");
    }
    assert!(!md.contains("**Failed"), "{md}");
    let mut figures = 0;
    for line in md.lines().filter(|l| l.starts_with("![")) {
        let rel = line.split("](").nth(1).unwrap().trim_end_matches(')');
        assert!(dir.join(rel).is_file(), "{rel} missing");
        figures += 1;
    }
    assert!(figures >= 10, "{figures} figures");
    assert!(md.contains("| `condition_number` |"), "no numbers");
    let (ok, _, err) = m1cs(&["report", dir.to_str().unwrap(), "--layout", "nosuch"]);
    assert!(!ok && err.contains("nosuch"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `m1cs csi` on Keck: one JSON object with finite peaks, the all-segment peak and the gain
/// search of the servo loop, the global loop against its criteria with the interaction-matrix
/// allowance, the plots.
#[test]
fn csi_on_keck() {
    let dir = std::env::temp_dir().join(format!("m1cs_csi_{}", std::process::id()));
    let dir_s = dir.to_str().expect("utf-8 temp dir").to_string();
    // On the soft-cell preset, whose cell modes put loop-gain peaks in the band.
    let args = [
        "csi",
        "--layout",
        "keck",
        "--structure",
        "soft-cell",
        "--modes",
        "30",
        "--max-degree",
        "4",
        "--frequencies",
        "60",
        "--q-realizations",
        "4",
        "--json",
        "--plot",
        &dir_s,
    ];
    let (ok, out, err) = m1cs(&args);
    assert!(ok, "m1cs {args:?} failed: {err}");
    let v: serde_json::Value =
        serde_json::from_str(&out).unwrap_or_else(|e| panic!("not one JSON object ({e}): {out}"));
    let sw = &v["sweep"];
    let zernike = sw["zernike"].as_array().expect("zernike curves");
    assert_eq!(zernike.len(), 5);
    let peak = |c: &serde_json::Value| c["peak_sensitivity"].as_f64().expect("peak");
    for c in zernike
        .iter()
        .chain(sw["segments"].as_array().expect("segments"))
    {
        let p = peak(c);
        assert!(p.is_finite() && p >= 1.0, "{c}");
    }
    let all = peak(&sw["all_segments"]);
    assert!(all.is_finite() && all >= 1.0, "{all}");
    assert_eq!(sw["all_segments"]["n_vectors"], 108);
    assert_eq!(v["lanczos_steps"], 60);
    // The largest degree is closer to the all-segment peak than global piston alone.
    let rel = |c: &serde_json::Value| (peak(c) - all).abs() / all;
    assert!(rel(&zernike[4]) < rel(&zernike[0]), "{zernike:?}");
    let g = &v["highest_gain"];
    assert!(g["gain_factor"].as_f64().expect("factor") > 0.0, "{g}");
    assert!(g["limited_by"].is_string(), "{g}");
    assert!(g["meets_criterion"].is_boolean(), "{g}");
    assert!(
        g["nominal_bandwidth_hz"].as_f64().expect("bandwidth") > 1.0,
        "{g}"
    );
    // The global loop: Zernike degrees 0..=4 and all segments; global piston/tip/tilt (degrees
    // 0 and 1) are projected out, so their loop gain is nil; the highest bandwidth found meets
    // the loop-gain limit (1/2 over the allowance 2) with all segments.
    let gl = &v["global"];
    let gz = gl["zernike"].as_array().expect("global zernike");
    assert_eq!(gz.len(), 5);
    let hf = |c: &serde_json::Value| c["high_frequency_loop_gain"].as_f64().expect("hf gain");
    assert!(hf(&gz[0]) < 1e-2 && hf(&gz[1]) < 1e-2, "{gz:?}");
    let all_hf = hf(&gl["all_segments"]);
    assert!(all_hf > hf(&gz[1]), "{gl}");
    assert_eq!(gl["loop_gain_limit"], 0.25);
    let hb = &gl["highest_bandwidth"];
    if hb["meets_criteria"] == true {
        assert!(
            hb["high_frequency_loop_gain"].as_f64().expect("gain") < 0.25,
            "{hb}"
        );
        assert!(hb["peak_sensitivity"].as_f64().expect("peak") < 2.0, "{hb}");
    }
    assert_eq!(
        gl["meets_loop_gain"],
        all_hf < 0.25,
        "the verdict follows the curve: {gl}"
    );
    // Every peak carries its Zernike family: the all-segment curves' maxima (the structure's
    // resonances from 8 Hz up exceed half the limit in loop gain on Keck), each above its
    // threshold.
    let families = |l: &str| matches!(l, "P" | "TT" | "FA") || l.starts_with('Z');
    for c in gz.iter().chain(std::iter::once(&gl["all_segments"])) {
        for key in ["peak_sensitivity_label", "high_frequency_loop_gain_label"] {
            let l = c[key].as_str().unwrap_or_else(|| panic!("{key}: {c}"));
            assert!(families(l), "{key} {l}");
        }
    }
    let peaks = gl["all_segment_peaks"].as_array().expect("global peaks");
    assert!(
        peaks.iter().any(|p| p["quantity"] == "loop_gain"),
        "{peaks:?}"
    );
    for p in peaks {
        assert!(families(p["label"].as_str().expect("label")), "{p}");
        let from = if p["quantity"] == "sensitivity" {
            1.2
        } else {
            0.125
        };
        assert!(p["value"].as_f64().expect("value") > from, "{p}");
    }
    let q = v["q_allowance"]["worst_sigma_gamma_q"].as_f64().expect("Q");
    assert!(q > 1.0 && q < 2.0, "{q}");
    for png in [
        "sensitivity.png",
        "convergence.png",
        "global.png",
        "global_band.png",
    ] {
        let len = std::fs::metadata(dir.join(png))
            .map(|m| m.len())
            .unwrap_or(0);
        assert!(len > 1000, "{png}: {len} bytes");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `m1cs csi`: bad input is named, never a panic.
#[test]
fn csi_rejects_bad_input() {
    for (args, name) in [
        (vec!["csi", "--layout", "keck", "--fmin", "0"], "--fmin"),
        (vec!["csi", "--layout", "keck", "--fmax", "0.5"], "--fmax"),
        (
            vec!["csi", "--layout", "keck", "--frequencies", "1"],
            "--frequencies",
        ),
        (
            vec!["csi", "--layout", "keck", "--gain-range", "2,1"],
            "--gain-range",
        ),
        (vec!["csi", "--layout", "keck", "--modes", "0"], "--modes"),
        (
            vec!["csi", "--layout", "keck", "--max-degree", "20"],
            "--max-degree",
        ),
        (
            vec!["csi", "--layout", "keck", "--bandwidth", "12"],
            "--bandwidth",
        ),
        (
            vec!["csi", "--layout", "keck", "--bandwidth-radial34", "12"],
            "--bandwidth-radial34",
        ),
        (
            vec!["csi", "--layout", "keck", "--allowance", "0.5"],
            "--allowance",
        ),
        (
            vec!["csi", "--layout", "keck", "--global-band-step", "0"],
            "--global-band-step",
        ),
        (
            vec!["csi", "--layout", "keck", "--lanczos-steps", "5"],
            "--lanczos-steps",
        ),
    ] {
        let (ok, _, err) = m1cs(&args);
        assert!(!ok, "{args:?} should fail");
        assert!(err.contains(name), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

/// `m1cs system --structure`: the mirror FMU's `structure` is bound only off the default (a
/// default system has no String binding), a preset by name and a `.npz` path made absolute;
/// an unknown name is refused naming the presets.
#[test]
fn system_binds_the_structure_off_the_default() {
    let dir = std::env::temp_dir().join(format!("m1cs-cli-structure-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fmus = fmu_dir();
    let bound = |extra: &[&str]| -> Option<String> {
        let ssp = dir.join("s.ssp");
        let ssp_s = ssp.to_str().unwrap();
        let mut args = vec![
            "system",
            "--layout",
            "keck",
            "--fmu-dir",
            &fmus,
            "-o",
            ssp_s,
        ];
        args.extend_from_slice(extra);
        let (ok, _, err) = m1cs(&args);
        assert!(ok, "{args:?}: {err}");
        let s = cosim::ssp::read(&ssp).unwrap();
        let mirror = s
            .system
            .components
            .iter()
            .find(|c| c.name == "mirror")
            .unwrap();
        mirror
            .parameters
            .iter()
            .find(|(n, _)| n == "structure")
            .map(|(_, v)| match v {
                cosim::system::Value::String(x) => x.clone(),
                other => panic!("structure bound as {other:?}"),
            })
    };
    assert_eq!(bound(&[]), None);
    assert_eq!(bound(&["--structure", "tmt"]), None);
    assert_eq!(
        bound(&["--structure", "soft-cell"]).as_deref(),
        Some("soft-cell")
    );
    let npz = dir.join("modes.npz");
    std::fs::write(&npz, b"not checked here").unwrap();
    let got = bound(&["--structure", npz.to_str().unwrap()]).unwrap();
    assert!(
        std::path::Path::new(&got).is_absolute() && got.ends_with("modes.npz"),
        "{got}"
    );
    let (ok, _, err) = m1cs(&[
        "system",
        "--layout",
        "keck",
        "--structure",
        "stiff",
        "-o",
        "x.ssp",
    ]);
    assert!(
        !ok && err.contains("stiff") && err.contains("soft-cell"),
        "{err}"
    );
}

/// `--help` shows the library's defaults (the flags take them from `m1`, so they cannot
/// drift), in the forms it always showed.
#[test]
fn help_shows_the_library_defaults() {
    let help = |cmd: &str| {
        let (ok, out, err) = m1cs(&[cmd, "--help"]);
        assert!(ok, "m1cs {cmd} --help: {err}");
        out
    };
    // The flag's entry: its line and, in the long form, the lines up to the next flag.
    let shows = |text: &str, flag: &str, default: String| {
        let lines: Vec<&str> = text.lines().collect();
        let start = lines
            .iter()
            .position(|l| l.trim_start().starts_with(&format!("--{flag} ")))
            .unwrap_or_else(|| panic!("no --{flag} in\n{text}"));
        let entry: Vec<&str> = lines[start..]
            .iter()
            .enumerate()
            .take_while(|(k, l)| *k == 0 || !l.trim_start().starts_with('-'))
            .map(|(_, l)| *l)
            .collect();
        let shown = entry
            .iter()
            .find_map(|l| l.split("[default: ").nth(1))
            .map(|d| d.trim_end().trim_end_matches(']'));
        assert_eq!(shown, Some(default.as_str()), "--{flag}: {entry:?}");
    };
    use m1::control::controller as ctl;
    let run = help("run");
    shows(&run, "bandwidth", ctl::DEFAULT_BANDWIDTH.to_string());
    shows(
        &run,
        "bandwidth-radial2",
        ctl::DEFAULT_BANDWIDTH_RADIAL2.to_string(),
    );
    shows(
        &run,
        "focus-bandwidth",
        ctl::DEFAULT_BANDWIDTH_FOCUS.to_string(),
    );
    shows(
        &run,
        "layout",
        m1::aperture::layout::DEFAULT_LAYOUT.to_string(),
    );
    shows(
        &run,
        "wind-speed",
        m1::loads::wind::WindParams::default().speed.to_string(),
    );
    let csi = help("csi");
    shows(&csi, "loop-rate", ctl::DEFAULT_RATE.to_string());
    shows(
        &csi,
        "damping",
        m1::analysis::defaults::DAMPING_RATIO.to_string(),
    );
    shows(
        &csi,
        "max-sensitivity",
        m1::analysis::defaults::csi::MAX_SENSITIVITY.to_string(),
    );
    let robustness = help("robustness");
    let params = m1::analysis::quasistatic::RobustnessParams::default();
    shows(&robustness, "realizations", params.realizations.to_string());
    shows(&robustness, "krylov", params.krylov_dim.to_string());
    // Engineering notation and lists, as before the defaults came from the library.
    let pssn = help("pssn");
    assert_eq!(m1::optics::pssn::PssnParams::default().wavelength, 500e-9);
    shows(&pssn, "wavelength", "500e-9".into());
    shows(&pssn, "piston-rms", "10e-9".into());
    shows(
        &help("coupling"),
        "steps",
        "0.0002,0.0004,0.0006,0.001".into(),
    );
    shows(&help("wind"), "speeds", "0.5,1,2".into());
}

//! End-to-end test of `m1cs csi` on Keck: one JSON object with finite peaks, the all-segment
//! peak and the gain search of the servo loop, the global loop against its criteria with the
//! interaction-matrix allowance, the plots; a clear error for bad input.
#![allow(clippy::unwrap_used, clippy::expect_used)]

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

#[test]
fn csi_on_keck() {
    let dir = std::env::temp_dir().join(format!("m1cs_csi_{}", std::process::id()));
    let dir_s = dir.to_str().expect("utf-8 temp dir").to_string();
    let args = [
        "csi",
        "--layout",
        "keck",
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
    let q = v["q_allowance"]["worst_sigma_gamma_q"].as_f64().expect("Q");
    assert!(q > 1.0 && q < 2.0, "{q}");
    for png in ["sensitivity.png", "convergence.png", "global.png"] {
        let len = std::fs::metadata(dir.join(png))
            .map(|m| m.len())
            .unwrap_or(0);
        assert!(len > 1000, "{png}: {len} bytes");
    }
    std::fs::remove_dir_all(&dir).ok();
}

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
            vec!["csi", "--layout", "keck", "--allowance", "0.5"],
            "--allowance",
        ),
        (
            vec!["csi", "--layout", "keck", "--global-band-step", "0"],
            "--global-band-step",
        ),
    ] {
        let (ok, _, err) = m1cs(&args);
        assert!(!ok, "{args:?} should fail");
        assert!(err.contains(name), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

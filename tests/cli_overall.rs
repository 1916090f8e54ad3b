//! End-to-end tests of `m1cs overall` and of Table 1's deformation and installation rows in
//! `m1cs robustness`, on Keck.
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

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn overall_calibration_and_optical_feedback_keep_the_mirror_phased() {
    let dir = std::env::temp_dir().join(format!("m1cs-overall-{}", std::process::id()));
    let v = json(&[
        "overall",
        "--layout",
        "keck",
        "--days",
        "16",
        "--step-minutes",
        "30",
        "--pssn-every-minutes",
        "240",
        "--json",
        "--plot",
        dir.to_str().unwrap(),
    ]);
    let r = &v["result"];
    let variants = r["variants"].as_array().unwrap();
    assert_eq!(variants.len(), 4);
    let rms = |k: usize| f(&variants[k]["summary"][0]["rms"]);
    let focus = |k: usize| f(&variants[k]["summary"][2]["rms"]);
    let cal_residual = |k: usize| f(&variants[k]["summary"][3]["rms"]);
    // APS at nights 0 and 14.
    assert_eq!(r["aps_days"].as_array().unwrap().len(), 2);
    // Without calibration the desired readings drift with the gaps; the fit tracks them.
    assert!(cal_residual(1) < 0.5 * cal_residual(0));
    // Optical feedback takes focus-mode out; both together give the best mirror.
    assert!(focus(2) < 0.2 * focus(0) && focus(3) < 0.2 * focus(1));
    assert!((0..3).all(|k| rms(3) < rms(k)), "{variants:?}");
    // PSSN: 1 is perfect; the best variant is the closest.
    let pssn_min = |k: usize| f(&variants[k]["pssn_min"]);
    assert!(pssn_min(3) > pssn_min(0) && pssn_min(3) <= 1.0);
    // Gap and shear predict the phased readings best.
    let fits = r["calibration_fits"].as_array().unwrap();
    assert_eq!(fits[2]["function"], "gap_shear");
    assert!(f(&fits[2]["leave_one_out_rms"]) < f(&fits[0]["leave_one_out_rms"]));
    for name in [
        "overall_rms.png",
        "overall_focus.png",
        "overall_calibration.png",
        "overall_pssn.png",
        "overall_map_APS_only.png",
    ] {
        assert!(dir.join(name).is_file(), "{name} missing");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn overall_refuses_bad_input_by_name() {
    let (ok, _, err) = m1cs(&["overall", "--layout", "keck", "--fit", "cubic"]);
    assert!(
        !ok && err.contains("--fit cubic") && err.contains("gap_shear"),
        "{err}"
    );
    let (ok, _, err) = m1cs(&["overall", "--layout", "keck", "--days", "0"]);
    assert!(!ok && err.contains("days"), "{err}");
    let (ok, _, err) = m1cs(&["overall", "--layout", "keck", "--fea", "/nonexistent.npz"]);
    assert!(
        !ok && err.contains("--fea") && err.contains("/nonexistent.npz"),
        "{err}"
    );
}

#[test]
fn robustness_has_the_deformation_and_installation_rows() {
    let v = json(&[
        "robustness",
        "--layout",
        "keck",
        "--realizations",
        "10",
        "--risk-realizations",
        "40",
        "--json",
    ]);
    let cases = v["cases"].as_array().unwrap();
    let case = |name: &str| {
        cases
            .iter()
            .find(|c| c["case"]["name"] == name)
            .unwrap_or_else(|| panic!("no case {name}"))
    };
    // Deterministic rows run once; the risk rows run the risk realizations.
    assert_eq!(case("zenith 65 deg")["realizations"], 1);
    assert_eq!(case("A elements 2%")["realizations"], 40);
    assert_eq!(case("A(ptt) elements 2%")["realizations"], 40);
    assert_eq!(
        case("A elements 2%")["sigma_q"]["values"]
            .as_array()
            .unwrap()
            .len(),
        10
    );
    // The farther from the 30 deg baseline, the larger the change of the interaction matrix.
    let rho = |n: &str| f(&case(n)["rho_q_minus_i"]["worst"]);
    assert!(rho("zenith 25 deg") < rho("zenith 15 deg"));
    assert!(rho("zenith 15 deg") < rho("zenith 0 deg"));
    // A uniform temperature change scales every sensor alike: rho is of the order of the gain
    // change gamma_h x alpha x 5 K x pitch.
    let gamma = m1::sensing::installed::DEFAULT_HEIGHT_GAIN_PER_GAP.abs();
    let alpha = m1::loads::deformation::DeformationParams::default().thermal_expansion;
    let keck = m1::aperture::layout::Layout::preset("keck").unwrap();
    let pitch = 3f64.sqrt() * keck.circumradius + keck.gap;
    let expected = gamma * alpha * 5.0 * pitch;
    let t = rho("temperature +5 C");
    assert!(
        t > 0.5 * expected && t < 2.0 * expected,
        "{t} vs {expected}"
    );
    // Knowing the gaps (gap correction) can only help the sensor installation row.
    let sigma = |n: &str| f(&case(n)["sigma_q"]["worst"]);
    assert!(sigma("sensor install, gap corr.") < sigma("sensor install"));
    // The paper's values travel with the rows.
    assert_eq!(
        case("segment install")["case"]["published"]["metrics"][1],
        3.81
    );
}

fn fmu_dir() -> String {
    std::env::var("M1CS_FMU_DIR")
        .unwrap_or_else(|_| concat!(env!("CARGO_MANIFEST_DIR"), "/target/fmu").to_string())
}

/// The deformation, APS and optical-feedback FMUs plug into the standard closed-loop system:
/// the deformation at the baseline zenith angle changes nothing; away from it, its in-plane
/// motion reaches the sensors; the optical FMUs run in the loop through `y_ref` and `u_lo`.
#[test]
fn deformation_and_optical_fmus_run_in_the_standard_system() {
    let dir = std::env::temp_dir().join(format!("m1cs-cli-optical-{}", std::process::id()));
    let out = dir.to_string_lossy().into_owned();
    let fmus = fmu_dir();
    let closed_rms = |extra: &[&str]| {
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
        args.extend_from_slice(extra);
        let v = json(&args);
        f(&v["runs"][1]["rms_surface_m"])
    };
    let plain = closed_rms(&[]);
    assert_eq!(closed_rms(&["--zenith", "30"]), plain);
    let tilted = closed_rms(&["--zenith", "60", "--temperature", "5"]);
    assert!(tilted != plain && tilted.is_finite());
    let optical = closed_rms(&["--optical"]);
    assert!(
        optical.is_finite() && (optical / plain - 1.0).abs() < 0.5,
        "{optical} vs {plain}"
    );
    let (ok, _, err) = m1cs(&[
        "run",
        "--layout",
        "keck",
        "--zenith",
        "95",
        "--fmu-dir",
        &fmus,
    ]);
    assert!(!ok && err.contains("--zenith 95"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

use super::robustness::metrics;
use super::*;

#[test]
fn sensor_gain_errors_never_destabilise_and_scale_with_the_error() {
    let g = default_geometry(&Layout::keck(), false, None).expect("geometry");
    let nominal = Nominal::new(g).expect("nominal");
    let params = RobustnessParams {
        realizations: 4,
        ..Default::default()
    };
    let cases = vec![
        Case {
            name: "0.1%".into(),
            perturbation: Perturbation::SensorGain { rms: 1e-3 },
            published: None,
        },
        Case {
            name: "1%".into(),
            perturbation: Perturbation::SensorGain { rms: 1e-2 },
            published: None,
        },
    ];
    let r = robustness(&nominal, &cases, &params, &|_, _| {}).expect("robustness");
    // Q - I is similar to the symmetric U^T dS U: with the same draws, rho scales exactly
    // with the gain error (to the Krylov estimate's accuracy).
    for k in 0..4 {
        let ratio = r[1].rho_q_minus_i.values[k] / r[0].rho_q_minus_i.values[k];
        assert!((ratio - 10.0).abs() < 1e-3, "{ratio}");
    }
    for c in &r {
        assert_eq!(c.unstable_fraction, 0.0);
        assert!(c.sigma_q.worst >= 1.0 - 1e-6);
        // Reducing focus-mode's gain can only lower the worst singular value.
        assert!(c.sigma_gamma_q.worst <= c.sigma_q.worst + 1e-9);
    }
}

#[test]
fn no_error_gives_the_identity() {
    let g = default_geometry(&Layout::keck(), false, None).expect("geometry");
    let nominal = Nominal::new(g).expect("nominal");
    let gains = vec![1.0; nominal.a.nrows()];
    let gamma = nominal.with_focus_gain(0.25).expect("gamma");
    let m = metrics(&nominal.b0, &gamma, &nominal.a, &gains, 40, 3, false);
    assert!(m[0] < 1e-9, "rho(Q - I) = {}", m[0]);
    assert!((m[1] - 1.0).abs() < 1e-9, "sigma(Q) = {}", m[1]);
    assert!((m[2] - 1.0).abs() < 1e-9, "sigma(GQ) = {}", m[2]);
}

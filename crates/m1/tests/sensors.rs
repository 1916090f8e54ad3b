//! Edge-sensor readings: exact A z + A_hw w without errors, gain errors as S, seeded noise of the
//! right rms and independent of the sample order, installation errors that perturb A slightly
//! and reproducibly, gap readings nominal + A_gz z + A_gw w.

#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use faer::sparse::SparseColMat;
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::reconstructor::sparse_mul;
use m1::sensing::interaction::interaction_matrices;
use m1::sensing::sensors::{EdgeSensors, SensorErrors, install_sensors};

fn geometry(name: &str) -> Geometry {
    let layout = Layout::preset(name).expect("layout");
    Geometry::new(&layout, GeometryParams::for_layout(&layout)).expect("geometry")
}

/// A deterministic pseudo-random vector of amplitude `scale`.
fn pattern(n: usize, scale: f64, phase: f64) -> Vec<f64> {
    (0..n)
        .map(|i| scale * ((i as f64 * 0.731 + phase).sin() + 0.3 * (i as f64 * 2.17).cos()))
        .collect()
}

fn mul(a: &SparseColMat<usize, f64>, x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; a.nrows()];
    sparse_mul(a, x, &mut y);
    y
}

fn read(s: &EdgeSensors, z: &[f64], w: &[f64], sample: u64) -> (Vec<f64>, Vec<f64>) {
    let ns = s.n_sensors();
    let (mut y, mut gap) = (vec![0.0; ns], vec![0.0; ns]);
    s.read_into(z, w, sample, &mut y, &mut gap).expect("read");
    (y, gap)
}

fn max_abs(x: &[f64]) -> f64 {
    x.iter().fold(0.0, |m, v| m.max(v.abs()))
}

#[test]
fn ideal_readings_are_a_z_plus_a_hw_w_and_gaps_nominal_plus_a_gw_w() {
    for name in ["keck", "tmt"] {
        let g = geometry(name);
        let m = interaction_matrices(&g);
        let s = EdgeSensors::new(&g, &SensorErrors::default()).expect("sensors");
        let na = g.n_actuators();
        let z = pattern(na, 1e-6, 0.1);
        let w = pattern(na, 1e-5, 1.3);
        let (y, gap) = read(&s, &z, &w, 7);
        let (hz, hw) = (mul(&m.a_hz, &z), mul(&m.a_hw, &w));
        let (gz, gw) = (mul(&m.a_gz, &z), mul(&m.a_gw, &w));
        let scale = max_abs(&y);
        assert!(scale > 1e-7, "{name}: readings too small to test ({scale})");
        for n in 0..g.n_sensors() {
            // Same products, summed in another order: round-off only.
            assert!(
                (y[n] - hz[n] - hw[n]).abs() <= 1e-14 * scale,
                "{name} y[{n}]"
            );
            let expected = g.layout.gap + gz[n] + gw[n];
            assert!((gap[n] - expected).abs() <= 1e-15, "{name} gap[{n}]");
        }
        // In-plane motion alone: the gap is exactly nominal + A_gw w (z = 0).
        let zero = vec![0.0; na];
        let (_, gap_w) = read(&s, &zero, &w, 0);
        for n in 0..g.n_sensors() {
            assert!((gap_w[n] - g.layout.gap - gw[n]).abs() <= 1e-15);
        }
        // The curved prescription couples z into the gap; the model keeps that block.
        assert!(
            max_abs(&gz) > 0.0,
            "{name}: A_gz z vanished on a curved mirror"
        );
        assert_eq!(s.install_change(), 0.0);
    }
}

#[test]
fn gain_errors_scale_the_height_readings_by_s() {
    let g = geometry("keck");
    let errors = SensorErrors {
        gain_rms: 0.01,
        seed: 42,
        ..Default::default()
    };
    let ideal = EdgeSensors::new(&g, &SensorErrors::default()).expect("ideal");
    let s = EdgeSensors::new(&g, &errors).expect("with gains");
    let na = g.n_actuators();
    let (z, w) = (pattern(na, 1e-6, 0.4), pattern(na, 1e-5, 2.0));
    let (y0, gap0) = read(&ideal, &z, &w, 3);
    let (y1, gap1) = read(&s, &z, &w, 3);
    let gains = s.gains();
    for n in 0..g.n_sensors() {
        assert!(
            (y1[n] - gains[n] * y0[n]).abs() <= 1e-14 * max_abs(&y0),
            "y[{n}]"
        );
        assert_eq!(gap1[n], gap0[n], "gains leave the gap alone");
    }
    // The gains have the requested spread (168 draws: within 20 %), and are reproducible.
    let rms = (gains.iter().map(|s| (s - 1.0).powi(2)).sum::<f64>() / gains.len() as f64).sqrt();
    assert!((rms / 0.01 - 1.0).abs() < 0.2, "gain rms {rms}");
    let again = EdgeSensors::new(&g, &errors).expect("again");
    assert_eq!(again.gains(), gains);
    let other = EdgeSensors::new(&g, &SensorErrors { seed: 43, ..errors }).expect("other");
    assert_ne!(other.gains(), gains);
}

#[test]
fn noise_has_its_rms_and_is_seeded_per_sample() {
    let g = geometry("tmt");
    let errors = SensorErrors {
        noise_rms: 5e-9,
        gap_noise_rms: 2e-8,
        seed: 7,
        ..Default::default()
    };
    let s = EdgeSensors::new(&g, &errors).expect("sensors");
    let na = g.n_actuators();
    let ns = g.n_sensors();
    let zero = vec![0.0; na];
    // 20 samples x 2772 sensors = 55440 draws: the rms is within 2 % (4 sigma is 1.2 %).
    let (mut sum_y, mut sum_g, mut mean_y) = (0.0, 0.0, 0.0);
    let samples = 20;
    for k in 0..samples {
        let (y, gap) = read(&s, &zero, &zero, k);
        sum_y += y.iter().map(|v| v * v).sum::<f64>();
        mean_y += y.iter().sum::<f64>();
        sum_g += gap.iter().map(|v| (v - g.layout.gap).powi(2)).sum::<f64>();
    }
    let count = (samples as usize * ns) as f64;
    let (rms_y, rms_g) = ((sum_y / count).sqrt(), (sum_g / count).sqrt());
    assert!(
        (rms_y / 5e-9 - 1.0).abs() < 0.02,
        "height noise rms {rms_y}"
    );
    assert!((rms_g / 2e-8 - 1.0).abs() < 0.02, "gap noise rms {rms_g}");
    assert!(
        (mean_y / count).abs() < 4.0 * 5e-9 / count.sqrt(),
        "noise mean"
    );
    // Deterministic: the same sample reads the same, in any order and from another instance;
    // samples differ from each other; another seed differs.
    let (a5, _) = read(&s, &zero, &zero, 5);
    let (_, _) = read(&s, &zero, &zero, 9);
    let twin = EdgeSensors::new(&g, &errors).expect("twin");
    let (b5, _) = read(&twin, &zero, &zero, 5);
    assert_eq!(a5, b5);
    let (a6, _) = read(&s, &zero, &zero, 6);
    assert_ne!(a5, a6);
    let other = EdgeSensors::new(&g, &SensorErrors { seed: 8, ..errors }).expect("other");
    assert_ne!(read(&other, &zero, &zero, 5).0, a5);
    // Noise adds to the signal: (signal + noise) - noise = signal exactly enough.
    let z = pattern(na, 1e-6, 0.9);
    let (yz, _) = read(&s, &z, &zero, 5);
    let ideal = EdgeSensors::new(&g, &SensorErrors::default()).expect("ideal");
    let (y0, _) = read(&ideal, &z, &zero, 5);
    for n in 0..ns {
        assert!((yz[n] - a5[n] - y0[n]).abs() <= 1e-14 * max_abs(&y0));
    }
}

#[test]
fn installation_errors_change_a_slightly_and_reproducibly() {
    let g = geometry("keck");
    let errors = SensorErrors {
        position_rms: 1e-3,
        tilt_rms: 1e-3,
        seed: 11,
        ..Default::default()
    };
    let s = EdgeSensors::new(&g, &errors).expect("installed");
    let change = s.install_change();
    // mm-sized position errors on a 1.8 m segment and mrad tilts: a change of order 1e-3.
    assert!(
        change > 1e-4 && change < 1e-2,
        "relative change of A {change}"
    );
    // Scales linearly with the errors (first order).
    let half = EdgeSensors::new(
        &g,
        &SensorErrors {
            position_rms: 0.5e-3,
            tilt_rms: 0.5e-3,
            ..errors
        },
    )
    .expect("half");
    let ratio = half.install_change() / change;
    assert!((ratio - 0.5).abs() < 0.02, "ratio {ratio}");
    // Reproducible from the seed; another seed gives another A.
    let twin = EdgeSensors::new(&g, &errors).expect("twin");
    assert_eq!(twin.height_matrix().val(), s.height_matrix().val());
    let other = EdgeSensors::new(&g, &SensorErrors { seed: 12, ..errors }).expect("other");
    assert_ne!(other.install_change(), change);
    // The readings use the installed A.
    let na = g.n_actuators();
    let z = pattern(na, 1e-6, 0.2);
    let zero = vec![0.0; na];
    let (y, _) = read(&s, &z, &zero, 0);
    let installed = install_sensors(&g, 1e-3, 1e-3, 11);
    let a = interaction_matrices(&installed).a_hz;
    let expected = mul(&a, &z);
    for n in 0..g.n_sensors() {
        assert!((y[n] - expected[n]).abs() <= 1e-14 * max_abs(&expected));
    }
    // The installed sensor frames stay orthonormal and right-handed.
    for sensor in &installed.sensors {
        let (h, gp, sh) = (sensor.height, sensor.gap, sensor.shear);
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        assert!((dot(h, h) - 1.0).abs() < 1e-12 && dot(h, gp).abs() < 1e-12);
        let cross = [
            h[1] * gp[2] - h[2] * gp[1],
            h[2] * gp[0] - h[0] * gp[2],
            h[0] * gp[1] - h[1] * gp[0],
        ];
        assert!((dot(cross, sh) - 1.0).abs() < 1e-12);
    }
}

#[test]
fn a_single_segment_piston_reads_on_its_own_edges_only() {
    let g = geometry("keck");
    let s = EdgeSensors::new(&g, &SensorErrors::default()).expect("sensors");
    let na = g.n_actuators();
    let seg = 5;
    let mut z = vec![0.0; na];
    z[3 * seg..3 * seg + 3].fill(1e-6);
    let (y, _) = read(&s, &z, &vec![0.0; na], 0);
    for (n, sensor) in g.sensors.iter().enumerate() {
        if sensor.i == seg {
            assert!(y[n] > 0.5e-6, "sensor {n}: {}", y[n]);
        } else if sensor.j == seg {
            assert!(y[n] < -0.5e-6, "sensor {n}: {}", y[n]);
        } else {
            assert_eq!(y[n], 0.0, "sensor {n} off the segment");
        }
    }
}

#[test]
fn bad_error_values_name_the_parameter() {
    let g = geometry("keck");
    let e = EdgeSensors::new(
        &g,
        &SensorErrors {
            noise_rms: -1.0,
            ..Default::default()
        },
    )
    .expect_err("negative noise");
    assert!(e.to_string().contains("noise_rms"), "{e}");
    let s = EdgeSensors::new(&g, &SensorErrors::default()).expect("sensors");
    let mut y = vec![0.0; 3];
    let mut gap = vec![0.0; g.n_sensors()];
    let z = vec![0.0; g.n_actuators()];
    assert!(s.read_into(&z, &z, 0, &mut y, &mut gap).is_err());
}

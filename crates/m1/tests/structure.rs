//! The structure model: finite-element identities, modal solution and static correction, exact
//! discretisation, and the NPZ import. Run in release (`cargo test --release -p m1 --test
//! structure`): the TMT eigensolve is a 1477 x 1477 dense problem.
#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use std::f64::consts::TAU;
use std::io::Write;
use std::path::{Path, PathBuf};

use m1::M1Error;
use m1::aperture::layout::Layout;
use m1::linalg::npy::{Npz, parse_npy};
use m1::linalg::skyline::Skyline;
use m1::plant::structure::{CellModel, CellParams, Flexibility, ModalModel, ModalSolver, zoh_mode};

fn keck() -> CellModel {
    let layout = Layout::preset("keck").expect("keck layout");
    CellModel::new(&layout, &CellParams::default()).expect("keck cell model")
}

/// A deterministic pseudo-random vector (fixed seed, no clock).
fn pseudo_random(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        })
        .collect()
}

fn rel_err(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}

#[test]
fn stiffness_and_mass_are_symmetric_positive_definite() {
    let m = keck();
    let n = m.ndof;
    assert_eq!(n, 3 * 36 + 1);
    for i in 0..n {
        for j in 0..i {
            let (a, b) = (m.stiffness[i * n + j], m.stiffness[j * n + i]);
            assert!((a - b).abs() <= 1e-12 * a.abs().max(1.0), "K[{i},{j}]");
        }
    }
    assert!(m.mass.iter().all(|x| *x > 0.0));
    // Positive definite: the Cholesky factorisation succeeds, and x^T K x > 0 for random x.
    Skyline::factor(n, &m.stiffness).expect("K is positive definite");
    for seed in 0..5 {
        let x = pseudo_random(n, seed);
        let e: f64 = (0..n)
            .map(|i| x[i] * (0..n).map(|j| m.stiffness[i * n + j] * x[j]).sum::<f64>())
            .sum();
        assert!(e > 0.0);
    }
    // A singular matrix is refused.
    let err = Skyline::factor(2, &[1.0, 1.0, 1.0, 1.0]).expect_err("singular");
    assert!(matches!(err, M1Error::Numerical(_)), "{err}");
}

#[test]
fn rigid_motion_of_the_grillage_strains_no_beam() {
    // A rigid plane w = a + b x + c y (theta_x = c, theta_y = -b) of the cell, mount held: the
    // only forces are the support springs' vertical forces at the support nodes.
    let layout = Layout::preset("keck").expect("keck");
    let m = keck();
    let n = m.ndof;
    let (a, b, c) = (1e-3, 2e-4, -3e-4);
    let mut x = vec![0.0; n];
    // Recover each node's position from its attachments (centre = mean of the 3 points).
    for (i, seg) in layout.segments.iter().enumerate() {
        let d = m.attachments[3 * i].dof;
        let [cx, cy] = seg.center;
        x[d] = a + b * cx + c * cy;
        x[d + 1] = c;
        x[d + 2] = -b;
    }
    let kx: Vec<f64> = (0..n)
        .map(|i| (0..n).map(|j| m.stiffness[i * n + j] * x[j]).sum())
        .collect();
    let scale = m.k_support * a;
    let support_dofs: Vec<usize> = m
        .support_nodes
        .iter()
        .map(|&s| m.attachments[3 * s].dof)
        .collect();
    for (i, f) in kx.iter().enumerate() {
        if i == m.pier_dof || support_dofs.contains(&i) {
            continue;
        }
        assert!(f.abs() < 1e-9 * scale, "dof {i}: force {f:e}");
    }
    // And the attachments follow the plane exactly.
    let mut z = vec![0.0; m.n_actuators()];
    m.attach(&x, &mut z);
    let geo = m1::aperture::geometry::Geometry::new(
        &layout,
        m1::aperture::geometry::GeometryParams::for_layout(&layout),
    )
    .expect("geometry");
    for (k, zk) in z.iter().enumerate() {
        let p = geo.segments[k / 3].actuators[k % 3];
        let expect = a + b * p[0] + c * p[1];
        assert!((zk - expect).abs() < 1e-15, "actuator {k}");
    }
}

#[test]
fn all_modes_reproduce_the_static_deflection() {
    let m = keck();
    let modal = m.modes().expect("modes");
    let n = modal.n_modes();
    assert_eq!(n, m.ndof);
    let na = m.n_actuators();
    let f = pseudo_random(na, 7);
    let pier = 2e-6;
    let exact = m.static_deflection(&f, pier).expect("static");
    // sum_j phi_j (phi_j^T f + k_p phi_p,j p) / w_j^2
    let mut z = vec![0.0; na];
    for j in 0..n {
        let w2 = (TAU * modal.frequencies[j]).powi(2);
        let u: f64 = (0..na)
            .map(|r| modal.phi_cell[r * n + j] * f[r])
            .sum::<f64>()
            + modal.k_pier * modal.phi_pier[j] * pier;
        for (r, zr) in z.iter_mut().enumerate() {
            *zr += modal.phi_cell[r * n + j] * u / w2;
        }
    }
    let e = rel_err(&z, &exact);
    assert!(e < 1e-9, "modal static deflection off by {e:e}");
    // At DC the structure follows the pier rigidly: a pure pier input moves every attachment by
    // the same amount.
    let zp = m.static_deflection(&vec![0.0; na], 1e-3).expect("pier");
    assert!(
        zp.iter().all(|x| (x - 1e-3).abs() < 1e-12),
        "{:?}",
        &zp[..3]
    );
}

#[test]
fn truncated_modes_with_static_correction_are_exact_at_dc() {
    let m = keck();
    let na = m.n_actuators();
    let modal = m.modes().expect("modes");
    let f = pseudo_random(na, 11);
    let pier = -5e-6;
    let exact = m.static_deflection(&f, pier).expect("static");
    for n_modes in [1, 10, 40] {
        let mut s = ModalSolver::new(modal.clone(), n_modes, 0.02).expect("solver");
        assert_eq!(s.n_modes(), n_modes);
        // Exact ZOH: long steps reach the steady state (e^{-zeta w h} ~ 0).
        for _ in 0..3 {
            s.step(2000.0, &f, pier).expect("step");
        }
        let e = rel_err(s.output(), &exact);
        assert!(e < 1e-9, "{n_modes} modes: DC error {e:e}");
        // Without the static correction the truncated sum misses the residual flexibility.
        let mut bare = modal.clone();
        bare.flexibility = Flexibility::None;
        let mut s = ModalSolver::new(bare, n_modes, 0.02).expect("solver");
        for _ in 0..3 {
            s.step(2000.0, &f, pier).expect("step");
        }
        let bare_err = rel_err(s.output(), &exact);
        assert!(
            bare_err > 1e-6,
            "{n_modes} modes without correction: {bare_err:e}"
        );
    }
}

#[test]
fn output_has_no_direct_feedthrough() {
    // z_cell after a step depends on the inputs held over that step, not on later ones: the
    // static correction lags by one step.
    let m = keck();
    let na = m.n_actuators();
    let modal = m.modes().expect("modes");
    let mut s = ModalSolver::new(modal, 20, 0.02).expect("solver");
    assert!(s.output().iter().all(|x| *x == 0.0), "starts at rest");
    let mut f = vec![0.0; na];
    f[5] = 100.0;
    s.step(1e-3, &f, 0.0).expect("step");
    let before = s.output().to_vec();
    assert!(before.iter().any(|x| *x != 0.0));
    // A new input changes nothing until the next step.
    assert_eq!(s.output(), before.as_slice());
}

#[test]
fn first_modes_are_between_5_and_20_hz() {
    for name in ["keck", "tmt"] {
        let layout = Layout::preset(name).expect("layout");
        let t0 = std::time::Instant::now();
        let m = CellModel::new(&layout, &CellParams::soft_cell()).expect("model");
        let modal = m.modes().expect("modes");
        let dt = t0.elapsed().as_secs_f64();
        let f = &modal.frequencies;
        println!(
            "{name}: {} dof, first modes {:.2?} Hz, build + eigensolve {dt:.2} s",
            m.ndof,
            &f[..6]
        );
        assert!(
            (5.0..20.0).contains(&f[0]),
            "{name}: first mode {} Hz",
            f[0]
        );
        assert!(f.windows(2).all(|w| w[0] <= w[1]));
        // Modal density: the number of modes per octave grows with frequency (from the second
        // octave above the first mode on; the first octave holds the mount and cell
        // fundamentals).
        let band = |lo: f64, hi: f64| f.iter().filter(|x| (lo..hi).contains(*x)).count();
        let f1 = f[0];
        let counts: Vec<usize> = (0..4)
            .map(|k| band(f1 * 2f64.powi(k), f1 * 2f64.powi(k + 1)))
            .collect();
        println!("{name}: modes per octave from the first mode: {counts:?}");
        assert!(
            counts[1..].windows(2).all(|w| w[0] < w[1]) && counts[0] < counts[3],
            "{name}: modes per octave {counts:?}"
        );
    }
}

/// Analytic step response of q'' + 2 zeta w q' + w^2 q = F from rest.
fn step_response(w: f64, zeta: f64, force: f64, t: f64) -> f64 {
    let s = zeta * w;
    let shape = if zeta < 1.0 {
        let wd = w * (1.0 - zeta * zeta).sqrt();
        (wd * t).cos() + s / wd * (wd * t).sin()
    } else if zeta > 1.0 {
        let mu = w * (zeta * zeta - 1.0).sqrt();
        (mu * t).cosh() + s / mu * (mu * t).sinh()
    } else {
        1.0 + w * t
    };
    force / (w * w) * (1.0 - (-s * t).exp() * shape)
}

#[test]
fn zoh_step_of_one_mode_matches_the_damped_oscillator() {
    let f0 = 7.3;
    let w = TAU * f0;
    for zeta in [0.0, 0.02, 0.7, 1.0, 1.8] {
        let model = ModalModel {
            na: 1,
            frequencies: vec![f0],
            damping_ratios: Some(vec![zeta]),
            phi_cell: vec![1.0],
            phi_pier: vec![0.0],
            k_pier: 1.0,
            flexibility: Flexibility::None,
        };
        let mut s = ModalSolver::new(model, 5, 0.5).expect("solver");
        assert_eq!(s.n_modes(), 1);
        assert_eq!(s.damping_ratios(), &[zeta]);
        let force = 3.0;
        let h = 1.3e-3;
        let scale = force / (w * w);
        let mut worst: f64 = 0.0;
        for k in 1..=800 {
            s.step(h, &[force], 0.0).expect("step");
            let t = k as f64 * h;
            worst = worst.max((s.output()[0] - step_response(w, zeta, force, t)).abs() / scale);
        }
        assert!(worst < 1e-9, "zeta {zeta}: worst relative error {worst:e}");
    }
    // The discrete map at DC: B_d -> [1/w^2, 0] as h grows.
    let (ad, bd) = zoh_mode(w, 0.05, 100.0);
    assert!(ad.iter().all(|a| a.abs() < 1e-9));
    assert!((bd[0] * w * w - 1.0).abs() < 1e-9 && bd[1].abs() < 1e-9);
}

// ---------------------------------------------------------------------------------------
// NPZ
// ---------------------------------------------------------------------------------------

/// NPY bytes for a float64 array, written independently of the reader.
fn npy(shape: &[usize], data_c_order: &[f64], version: u8, fortran: bool, descr: &str) -> Vec<u8> {
    let shape_txt = match shape.len() {
        0 => "()".to_string(),
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!(
        "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape_txt}, }}",
        if fortran { "True" } else { "False" }
    );
    let pre = if version == 1 { 10 } else { 12 };
    while (pre + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY".to_vec();
    out.push(version);
    out.push(0);
    if version == 1 {
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    }
    out.extend_from_slice(header.as_bytes());
    let data: Vec<f64> = if fortran && shape.len() == 2 {
        let (r, c) = (shape[0], shape[1]);
        (0..r * c)
            .map(|k| data_c_order[(k % r) * c + k / r])
            .collect()
    } else {
        data_c_order.to_vec()
    };
    for x in data {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out
}

fn write_npz(path: &Path, entries: &[(&str, Vec<u8>)], deflate: bool) {
    let file = std::fs::File::create(path).expect("create npz");
    let mut zw = zip::ZipWriter::new(file);
    let method = if deflate {
        zip::CompressionMethod::Deflated
    } else {
        zip::CompressionMethod::Stored
    };
    let opts = zip::write::SimpleFileOptions::default().compression_method(method);
    for (name, bytes) in entries {
        zw.start_file(format!("{name}.npy"), opts).expect("entry");
        zw.write_all(bytes).expect("write");
    }
    zw.finish().expect("finish");
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("m1-structure-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp dir");
    dir.join(name)
}

#[test]
fn npz_round_trip() {
    let a2 = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]; // 2 x 3, C order
    let v = [0.5, -1.25, 1e-300];
    for deflate in [false, true] {
        let path = tmp(&format!("roundtrip-{deflate}.npz"));
        write_npz(
            &path,
            &[
                ("c2", npy(&[2, 3], &a2, 1, false, "<f8")),
                ("f2", npy(&[2, 3], &a2, 1, true, "<f8")),
                ("v2", npy(&[3], &v, 2, false, "<f8")),
                ("s", npy(&[], &[42.0], 1, false, "<f8")),
            ],
            deflate,
        );
        let mut npz = Npz::open(&path).expect("open");
        let mut names = npz.names();
        names.sort();
        assert_eq!(names, ["c2", "f2", "s", "v2"]);
        for name in ["c2", "f2"] {
            let a = npz.require(name).expect(name);
            assert_eq!(a.shape, [2, 3]);
            assert_eq!(a.data, a2);
        }
        let b = npz.require("v2").expect("v2");
        assert_eq!((b.shape.as_slice(), b.data.as_slice()), (&[3][..], &v[..]));
        let s = npz.require("s").expect("s");
        assert!(s.shape.is_empty() && s.data == [42.0]);
        assert!(npz.optional("absent").expect("absent").is_none());
    }
}

fn two_mode_arrays(na: usize) -> Vec<(&'static str, Vec<u8>)> {
    let n = 2;
    let phi: Vec<f64> = (0..na * n).map(|k| 0.01 * (k as f64 + 1.0)).collect();
    vec![
        ("frequencies", npy(&[n], &[9.0, 21.0], 1, false, "<f8")),
        ("phi_cell", npy(&[na, n], &phi, 1, true, "<f8")),
        ("phi_pier", npy(&[n], &[0.001, -0.002], 1, false, "<f8")),
        ("k_pier", npy(&[], &[1e9], 1, false, "<f8")),
    ]
}

#[test]
fn modal_model_reads_from_npz() {
    let na = 3;
    let path = tmp("two-modes.npz");
    let mut arrays = two_mode_arrays(na);
    let g: Vec<f64> = (0..9)
        .map(|k| if k % 4 == 0 { 1e-8 } else { 2e-9 })
        .collect();
    arrays.push(("flexibility", npy(&[3, 3], &g, 1, false, "<f8")));
    arrays.push(("damping_ratios", npy(&[2], &[0.01, 0.03], 1, false, "<f8")));
    write_npz(&path, &arrays, true);
    let m = ModalModel::from_npz(&path, na).expect("valid file");
    assert_eq!(m.frequencies, [9.0, 21.0]);
    assert_eq!(m.phi_cell[1], 0.02); // row 0, column 1 (C order)
    assert_eq!(m.k_pier, 1e9);
    assert_eq!(m.damping_ratios.as_deref(), Some(&[0.01, 0.03][..]));
    assert!(matches!(
        m.flexibility,
        Flexibility::Dense {
            cell: Some(_),
            pier: None
        }
    ));
    let s = ModalSolver::new(m, 1, 0.02).expect("solver");
    assert_eq!((s.n_modes(), s.frequencies()), (1, vec![9.0]));
}

fn npz_error(name: &str, arrays: &[(&'static str, Vec<u8>)], na: usize) -> String {
    let path = tmp(name);
    write_npz(&path, arrays, false);
    ModalModel::from_npz(&path, na)
        .expect_err("malformed file")
        .to_string()
}

#[test]
fn malformed_npz_files_give_clear_errors() {
    let na = 3;
    // Missing file.
    let e = ModalModel::from_npz(Path::new("/nonexistent/modes.npz"), na).expect_err("missing");
    assert!(e.to_string().contains("/nonexistent/modes.npz"), "{e}");
    // Not a zip.
    let path = tmp("not-a-zip.npz");
    std::fs::write(&path, b"hello").expect("write");
    let e = ModalModel::from_npz(&path, na)
        .expect_err("not zip")
        .to_string();
    assert!(e.contains("not-a-zip.npz") && e.contains("zip"), "{e}");
    // A missing array is named, with what the file has.
    let mut a = two_mode_arrays(na);
    a.retain(|(n, _)| *n != "phi_pier");
    let e = npz_error("no-pier.npz", &a, na);
    assert!(
        e.contains("'phi_pier' is missing") && e.contains("frequencies"),
        "{e}"
    );
    // Wrong dtype.
    let mut a = two_mode_arrays(na);
    a[0].1 = npy(&[2], &[9.0, 21.0], 1, false, "<f4");
    let e = npz_error("f4.npz", &a, na);
    assert!(e.contains("'frequencies'") && e.contains("<f4"), "{e}");
    // Wrong shape for the layout.
    let e = npz_error("shape.npz", &two_mode_arrays(4), na);
    assert!(e.contains("'phi_cell'") && e.contains("[4, 2]"), "{e}");
    // Truncated data.
    let mut a = two_mode_arrays(na);
    let len = a[2].1.len();
    a[2].1.truncate(len - 3);
    let e = npz_error("short.npz", &a, na);
    assert!(e.contains("'phi_pier'") && e.contains("data bytes"), "{e}");
    // Not an NPY entry.
    let mut a = two_mode_arrays(na);
    a[3].1 = b"garbage".to_vec();
    let e = npz_error("garbage.npz", &a, na);
    assert!(e.contains("'k_pier'") && e.contains("NPY"), "{e}");
    // A zero frequency (rigid-body mode).
    let mut a = two_mode_arrays(na);
    a[0].1 = npy(&[2], &[0.0, 21.0], 1, false, "<f8");
    let e = npz_error("rigid.npz", &a, na);
    assert!(e.contains("'frequencies'") && e.contains("> 0"), "{e}");
    // Non-symmetric flexibility.
    let mut a = two_mode_arrays(na);
    let g = [1.0, 2.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    a.push(("flexibility", npy(&[3, 3], &g, 1, false, "<f8")));
    let e = npz_error("asym.npz", &a, na);
    assert!(
        e.contains("'flexibility'") && e.contains("symmetric"),
        "{e}"
    );
    // Direct parser checks.
    assert!(parse_npy(b"\x93NUMPY\x09\x00xxxx").is_err());
    let big_endian = npy(&[1], &[1.0], 1, false, ">f8");
    assert!(
        parse_npy(&big_endian)
            .expect_err("big endian")
            .contains(">f8")
    );
}

/// The retained modes solved alone (block Lanczos on the envelope factor; TMT's default 60 and
/// the 300 of the dynamic studies) are the dense solve's lowest, to the dense solve's own
/// accuracy: the frequencies to 1e-7 (2e-8 seen), and the retained modes' compliance at the
/// attachments `sum_j phi_j phi_j^T / w_j^2` (independent of the basis chosen within a repeated
/// frequency) to 5e-6. faer's dense eigenvectors of this problem are the looser of the two:
/// their residual `|K x - lambda M x|` is up to 4e-4 of `lambda |M x|` for the lowest mode
/// where block Lanczos reaches 1e-14, and the two differ by 1e-7 to 1e-6 per mode; the Keck
/// test below checks the Lanczos modes against nalgebra's (backward-stable) dense solve to
/// 1e-9. With the static correction the truncated model is exact at DC. The cache keeps the
/// lowest modes apart from the full set.
#[test]
fn lowest_modes_alone_match_the_dense_solve_on_tmt() {
    let layout = Layout::tmt();
    let cell = CellModel::new(&layout, &CellParams::default()).expect("tmt cell");
    let dense = cell
        .modes_in(&m1::linalg::cache::Store::off())
        .expect("every mode");
    let na = cell.n_actuators();
    // The retained modes' compliance at the attachments, sum_j phi_j phi_j^T / w_j^2 over the
    // first r.
    let compliance = |m: &ModalModel, r: usize| {
        let n = m.n_modes();
        let mut g = vec![0.0; na * na];
        for j in 0..r {
            let w2 = (TAU * m.frequencies[j]).powi(2);
            for a in 0..na {
                let pa = m.phi_cell[a * n + j] / w2;
                for (gb, row) in g[a * na..(a + 1) * na].iter_mut().zip(m.phi_cell.chunks(n)) {
                    *gb += pa * row[j];
                }
            }
        }
        g
    };
    // The default 60 and the 300 of the dynamic studies, both solved alone (at most a quarter
    // of the degrees of freedom).
    for r in [300, 60] {
        let lowest = cell
            .lowest_modes_in(r, &m1::linalg::cache::Store::off())
            .expect("lowest modes");
        assert_eq!(lowest.n_modes(), r, "only the retained modes are solved");
        assert!(dense.n_modes() > 4 * r);
        for j in 0..r {
            let (a, b) = (lowest.frequencies[j], dense.frequencies[j]);
            assert!(
                (a - b).abs() < 1e-7 * b,
                "mode {j} of {r}: {a} Hz against {b} Hz"
            );
        }
        // The cut falls between two frequencies, not inside a degenerate pair.
        let (fa, fb) = (dense.frequencies[r - 1], dense.frequencies[r]);
        assert!(fb - fa > 1e-3 * fa, "{fa} Hz, {fb} Hz");
        let e = rel_err(&compliance(&lowest, r), &compliance(&dense, r));
        assert!(
            e < 5e-6,
            "retained compliance of {r} modes differs by {e:e}"
        );
    }
    let r = 60;
    let lowest = cell
        .lowest_modes_in(r, &m1::linalg::cache::Store::off())
        .expect("lowest modes");
    let pier: Vec<f64> = (0..r)
        .map(|j| (lowest.phi_pier[j] / lowest.frequencies[j]).powi(2))
        .collect();
    let pier_dense: Vec<f64> = (0..r)
        .map(|j| (dense.phi_pier[j] / dense.frequencies[j]).powi(2))
        .collect();
    let (sp, sd): (f64, f64) = (pier.iter().sum(), pier_dense.iter().sum());
    assert!(
        (sp - sd).abs() < 1e-7 * sd,
        "pier participation {sp:e} against {sd:e}"
    );
    // Exact at DC with the static correction.
    let f = pseudo_random(na, 5);
    let exact = cell.static_deflection(&f, 2e-6).expect("static");
    let mut s = ModalSolver::new(lowest.clone(), r, 0.02).expect("solver");
    for _ in 0..3 {
        s.step(2000.0, &f, 2e-6).expect("step");
    }
    let e = rel_err(s.output(), &exact);
    assert!(e < 1e-9, "DC error {e:e}");
    // Cached under their own key, bit for bit.
    let dir = std::env::temp_dir().join(format!("m1-lowest-modes-{}", std::process::id()));
    let store = m1::linalg::cache::Store::at(&dir);
    let first = cell.lowest_modes_in(r, &store).expect("first");
    let again = cell.lowest_modes_in(r, &store).expect("cached");
    assert_eq!(store.entries().len(), 1);
    assert_eq!(first.frequencies, lowest.frequencies);
    assert_eq!(again.phi_cell, lowest.phi_cell);
    assert_eq!(again.phi_pier, lowest.phi_pier);
    let _ = std::fs::remove_dir_all(&dir);
    // Past a quarter of the degrees of freedom, the dense solve's lowest (every mode).
    let many = cell
        .lowest_modes_in(cell.ndof / 3, &m1::linalg::cache::Store::off())
        .expect("many");
    assert_eq!(many.frequencies, dense.frequencies);
}

/// Block Lanczos against nalgebra's dense symmetric eigensolve (Householder tridiagonalisation
/// and implicit QR: backward stable) on the Keck cell: the 12 lowest eigenvalues to 1e-12, and
/// the projector onto the lowest 7 modes (two degenerate pairs among them; the cut between
/// two distinct frequencies) to 1e-9.
#[test]
fn block_lanczos_matches_a_backward_stable_dense_solve_on_keck() {
    let cell = keck();
    let n = cell.ndof;
    let chol = Skyline::factor(n, &cell.stiffness).expect("factor");
    let pairs = m1::linalg::lanczos::lowest_eigenpairs(&chol, &cell.mass, 12)
        .expect("valid input")
        .expect("converged");
    let d: Vec<f64> = cell.mass.iter().map(|m| 1.0 / m.sqrt()).collect();
    let kt = nalgebra::DMatrix::<f64>::from_fn(n, n, |i, j| {
        0.5 * (cell.stiffness[i * n + j] + cell.stiffness[j * n + i]) * d[i] * d[j]
    });
    let eig = nalgebra::SymmetricEigen::new(kt);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    for (j, (&o, &got)) in order.iter().zip(&pairs.values).enumerate() {
        let want = eig.eigenvalues[o];
        assert!(
            (got - want).abs() < 1e-12 * want,
            "mode {j}: {got:e} against {want:e}"
        );
    }
    let r = 7;
    let (l8, l9) = (eig.eigenvalues[order[r - 1]], eig.eigenvalues[order[r]]);
    assert!(
        l9 - l8 > 1e-3 * l8,
        "the cut at {r} is between distinct frequencies"
    );
    // Projectors onto the span, in the mass-scaled coordinates y = M^1/2 x.
    let mut worst: f64 = 0.0;
    for a in 0..n {
        for b in 0..n {
            let lanczos: f64 = (0..r)
                .map(|j| pairs.vectors[j * n + a] * pairs.vectors[j * n + b] / (d[a] * d[b]))
                .sum();
            let dense: f64 = (0..r)
                .map(|j| eig.eigenvectors[(a, order[j])] * eig.eigenvectors[(b, order[j])])
                .sum();
            worst = worst.max((lanczos - dense).abs());
        }
    }
    assert!(worst < 1e-9, "projectors differ by {worst:e}");
}

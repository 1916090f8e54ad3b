//! Sensor calibration (eq. 2 of the seed paper): shear estimated from gaps through the truncated
//! pseudo-inverse of A_gw.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use faer::Mat;
use m1::M1Error;
use m1::analysis::quasistatic::{SHEAR_RANK_TOLERANCE, ShearEstimator, calibration};
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::sensing::interaction::interaction_matrices;

fn keck(flat: bool) -> Geometry {
    let layout = Layout::keck();
    let mut p = GeometryParams::for_layout(&layout);
    p.flat = flat;
    Geometry::new(&layout, p).expect("geometry")
}

/// On a flat mirror the gaps see every in-plane motion except the three rigid ones (x, y,
/// rotation) and torsion: rank 3N - 4; the curved prescription makes three of those weakly
/// observable, which the default threshold does not invert.
#[test]
fn gap_rank_is_3n_minus_4() {
    for flat in [true, false] {
        let g = keck(flat);
        let r = calibration(&g, 10, 1, SHEAR_RANK_TOLERANCE).expect("calibration");
        assert_eq!(r.in_plane_dofs, 3 * 36);
        assert_eq!(r.gap_rank, 3 * 36 - 4, "flat = {flat}");
        assert_eq!(
            r.weakly_observable,
            if flat { 0 } else { 3 },
            "flat = {flat}"
        );
        // A clear spectral gap around the threshold.
        assert!(r.smallest_kept_relative > 1e-2 && r.largest_dropped_relative < 1e-5);
    }
}

/// Motion that the gaps observe (on the flat mirror: anything in the row space of A_gw) is
/// estimated exactly, so its shear too.
#[test]
fn observable_motion_is_estimated_exactly() {
    let g = keck(true);
    let im = interaction_matrices(&g);
    let est = ShearEstimator::new(&g, SHEAR_RANK_TOLERANCE).expect("estimator");
    let agw = im.a_gw.to_dense();
    let asw = im.a_sw.to_dense();
    let gvec = Mat::<f64>::from_fn(agw.nrows(), 2, |i, c| ((i * (c + 3)) as f64 * 0.37).sin());
    let w = agw.transpose() * &gvec;
    let shear = &asw * &w;
    let err = &shear - est.shear((&agw * &w).as_ref());
    let rel = err.norm_l2() / shear.norm_l2();
    assert!(rel < 1e-10, "relative shear error {rel:e}");
}

/// The exact figures (row norms of A_sw (I - V_r V_r^T) and A_sw V_r S_r^-1) agree with their
/// seeded Monte Carlo estimates; noise and unobservable motion both matter at these sizes.
#[test]
fn exact_errors_match_monte_carlo() {
    let g = keck(false);
    let r = calibration(&g, 400, 7, SHEAR_RANK_TOLERANCE).expect("calibration");
    let close = |exact: f64, mc: f64, what: &str| {
        assert!(
            (exact - mc).abs() < 0.05 * exact,
            "{what}: exact {exact} vs Monte Carlo {mc}"
        );
    };
    close(
        r.shear_error_unobservable,
        r.monte_carlo.shear_error_unobservable,
        "unobservable",
    );
    close(
        r.shear_error_per_gap_noise,
        r.monte_carlo.shear_error_per_gap_noise,
        "gap noise",
    );
    assert!(r.shear_error_unobservable > 0.05 && r.shear_error_per_gap_noise > 0.5);
    assert_eq!(r.per_segment_shear_error_unobservable.len(), 36);
    // Inverting the weakly observable modes too trades the unobservable error for a
    // noise gain larger by orders of magnitude.
    let loose = calibration(&g, 10, 7, 1e-8).expect("calibration");
    assert!(loose.gap_rank > r.gap_rank);
    assert!(loose.shear_error_per_gap_noise > 100.0 * r.shear_error_per_gap_noise);
}

#[test]
fn bad_threshold_is_refused() {
    let g = keck(false);
    for t in [0.0, -1.0, 1.0, f64::NAN] {
        assert!(matches!(
            ShearEstimator::new(&g, t),
            Err(M1Error::InvalidParameter {
                name: "rank_tolerance",
                ..
            })
        ));
    }
}

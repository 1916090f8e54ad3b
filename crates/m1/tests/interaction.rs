//! Geometry and edge-sensor interaction matrices: sizes and sparsity, null spaces (global
//! piston/tip/tilt, the six rigid-body modes), ranks, flat/curved coupling blocks and their 1/R
//! scaling, the focus mode's dependence on L_eff, single-segment responses, the piston/tip/tilt
//! matrices, and the in-plane kinematics.
//!
//! Anything needing an SVD uses Keck (168 x 108) so debug builds stay fast; TMT is used for cheap
//! checks. The `tmt_report` test (ignored; run with `--release -- --ignored --nocapture`) prints
//! the singular values of both mirrors.

#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use faer::Mat;
use faer::sparse::SparseColMat;
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::{KECK_CONIC, KECK_RADIUS_OF_CURVATURE, Layout};
use m1::sensing::interaction::{
    RigidMotion, a_matrix, global_ptt, global_rigid_modes, in_plane_motion, interaction_matrices,
    out_of_plane_motion, segment_coordinates, sensor_reading, to_dense,
};
use nalgebra::Vector3;

/// Relative threshold on singular values for the exact (flat-mirror, full-matrix) ranks.
const RANK_TOL: f64 = 1e-9;

fn geometry(layout: &Layout, flat: bool, leff: f64) -> Geometry {
    let mut params = GeometryParams::for_layout(layout);
    params.flat = flat;
    params.leff = leff;
    Geometry::new(layout, params).unwrap()
}

fn keck(flat: bool, leff: f64) -> Geometry {
    geometry(&Layout::keck(), flat, leff)
}

fn keck_with_radius(radius: f64) -> Geometry {
    let layout = Layout::keck().with_optics(radius, KECK_CONIC).unwrap();
    geometry(&layout, false, 0.1)
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

/// Singular values, non-increasing.
fn singular_values(m: &SparseColMat<usize, f64>) -> Vec<f64> {
    to_dense(m).singular_values().unwrap()
}

/// Number of singular values above `tol` times the largest.
fn rank(sv: &[f64], tol: f64) -> usize {
    sv.iter().filter(|&&s| s > tol * sv[0]).count()
}

/// Frobenius norm of a sparse matrix.
fn frobenius(m: &SparseColMat<usize, f64>) -> f64 {
    m.triplet_iter().map(|t| t.val * t.val).sum::<f64>().sqrt()
}

/// `||M X|| / (||M|| ||X||)`, Frobenius norms.
fn relative_residual(m: &SparseColMat<usize, f64>, x: &Mat<f64>) -> f64 {
    (m * x).norm_l2() / (frobenius(m) * x.norm_l2())
}

/// Deterministic pseudo-random numbers in [-1, 1].
fn pseudo_random(n: usize, seed: f64) -> Vec<f64> {
    (0..n)
        .map(|k| (seed * (k as f64 + 1.0) * 12.9898).sin())
        .collect()
}

#[test]
fn sizes_and_sparsity() {
    for (layout, ns, na) in [(Layout::keck(), 168, 108), (Layout::tmt(), 2772, 1476)] {
        let g = geometry(&layout, false, 0.1);
        assert_eq!(
            (g.n_sensors(), g.n_actuators(), g.n_segments()),
            (ns, na, na / 3)
        );
        let m = interaction_matrices(&g);
        let a = a_matrix(&g);
        assert_eq!((a.nrows(), a.ncols()), (ns, na));
        for block in [&m.a_hz, &m.a_hw, &m.a_gz, &m.a_gw, &m.a_sz, &m.a_sw] {
            assert_eq!((block.nrows(), block.ncols()), (ns, na));
        }
        let full = m.full();
        assert_eq!((full.nrows(), full.ncols()), (3 * ns, 2 * na));
        assert_eq!(
            full.compute_nnz(),
            [&m.a_hz, &m.a_hw, &m.a_gz, &m.a_gw, &m.a_sz, &m.a_sw]
                .iter()
                .map(|b| b.compute_nnz())
                .sum::<usize>()
        );
        // Each row of A: exactly 6 non-zeros, the 3 actuators of each of the sensor's segments.
        let mut columns = vec![Vec::new(); ns];
        for t in a.triplet_iter() {
            assert!(*t.val != 0.0);
            columns[t.row].push(t.col);
        }
        for (n, cols) in columns.iter_mut().enumerate() {
            let s = &g.sensors[n];
            cols.sort_unstable();
            let expected: Vec<usize> = (3 * s.i..3 * s.i + 3).chain(3 * s.j..3 * s.j + 3).collect();
            assert_eq!(*cols, expected, "row {n} of A");
        }
    }
}

#[test]
fn global_ptt_annihilated_exactly_on_flat_mirror() {
    for layout in [Layout::keck(), Layout::tmt()] {
        for leff in [0.0, 0.1] {
            let g = geometry(&layout, true, leff);
            let ptt = global_ptt(&g);
            assert_eq!((ptt.nrows(), ptt.ncols()), (g.n_actuators(), 3));
            for c in 0..3 {
                let rms = (ptt.col(c).squared_norm_l2() / g.n_actuators() as f64).sqrt();
                assert!((rms - 1.0).abs() < 1e-12, "column {c} rms {rms}");
            }
            let r = relative_residual(&a_matrix(&g), &ptt);
            assert!(
                r < 1e-12,
                "{} leff {leff}: ||A g|| / ||A|| ||g|| = {r:e}",
                layout.name
            );
        }
    }
}

/// On a curved mirror no rigid motion is purely out-of-plane: the z part of global
/// piston/tip/tilt leaves small readings. With the curvature-consistent dihedral term (a motion
/// along the sphere changes no dihedral) what remains falls as 1/R^4 (measured ratio 15.96
/// between R = 70 m and 140 m).
#[test]
fn global_ptt_nearly_annihilated_on_curved_mirror() {
    let residual = |g: &Geometry| relative_residual(&a_matrix(g), &global_ptt(g));
    let tmt = geometry(&Layout::tmt(), false, 0.1);
    let r_tmt = residual(&tmt);
    assert!(r_tmt < 1e-5, "TMT: {r_tmt:e}");
    let r35 = residual(&keck(false, 0.1));
    assert!(r35 < 1e-5, "Keck: {r35:e}");
    let r70 = residual(&keck_with_radius(70.0));
    let r140 = residual(&keck_with_radius(140.0));
    // 1/R^4 to within 5 %.
    let ratio = r70 / r140;
    assert!((ratio - 16.0).abs() < 0.8, "residual ratio {ratio}");
}

#[test]
fn full_matrix_annihilates_global_rigid_modes() {
    for layout in [Layout::keck(), Layout::tmt()] {
        for flat in [true, false] {
            let g = geometry(&layout, flat, 0.1);
            let full = interaction_matrices(&g).full();
            let modes = global_rigid_modes(&g);
            assert_eq!((modes.nrows(), modes.ncols()), (6 * g.n_segments(), 6));
            for c in 0..6 {
                let col = modes.col(c).to_owned();
                let r = (&full * &col).norm_l2() / (frobenius(&full) * col.norm_l2());
                assert!(r < 1e-12, "{} flat {flat} mode {c}: {r:e}", layout.name);
            }
        }
    }
}

#[test]
fn global_ptt_is_z_part_of_rigid_modes() {
    // On a flat mirror the rigid z translation and x/y rotations have no in-plane part.
    let g = keck(true, 0.1);
    let modes = global_rigid_modes(&g);
    let na = g.n_actuators();
    for c in 2..5 {
        let w_norm = (na..2 * na)
            .map(|r| modes[(r, c)].powi(2))
            .sum::<f64>()
            .sqrt();
        assert_eq!(w_norm, 0.0, "mode {c}");
    }
    // Global piston moves every actuator by the same amount.
    let ptt = global_ptt(&g);
    for r in 0..na {
        assert!((ptt[(r, 0)] - 1.0).abs() < 1e-12);
    }
}

#[test]
fn ranks_of_a_on_flat_keck() {
    let na = 108;
    let sv = singular_values(&a_matrix(&keck(true, 0.1)));
    assert_eq!(rank(&sv, RANK_TOL), na - 3, "Leff > 0: {:?}", &sv[na - 5..]);
    let sv = singular_values(&a_matrix(&keck(true, 0.0)));
    assert_eq!(rank(&sv, RANK_TOL), na - 4, "Leff = 0: {:?}", &sv[na - 6..]);
}

/// On the curved mirror A has no exact null space (see the residual test above), but global
/// piston/tip/tilt remain clearly separated: relative singular values ~1e-5 against ~3.6e-3 for
/// focus mode. The numerical rank at 1e-4 relative is na - 3 (Leff > 0) and na - 4 (Leff = 0).
#[test]
fn ranks_of_a_on_curved_keck() {
    let na = 108;
    let sv = singular_values(&a_matrix(&keck(false, 0.1)));
    assert_eq!(rank(&sv, 1e-4), na - 3, "Leff > 0: {:?}", &sv[na - 5..]);
    assert!(
        sv[na - 4] > 1e-3 * sv[0],
        "focus mode {:e}",
        sv[na - 4] / sv[0]
    );
    let sv = singular_values(&a_matrix(&keck(false, 0.0)));
    assert_eq!(rank(&sv, 1e-4), na - 4, "Leff = 0: {:?}", &sv[na - 6..]);
    assert!(sv[na - 5] > 1e-3 * sv[0]);
}

#[test]
fn ranks_of_full_matrix_and_gap_block() {
    let (n, na) = (36, 108);
    for flat in [true, false] {
        let g = keck(flat, 0.1);
        let m = interaction_matrices(&g);
        let sv = singular_values(&m.full());
        assert_eq!(
            rank(&sv, RANK_TOL),
            6 * n - 6,
            "flat {flat}: {:?}",
            &sv[6 * n - 8..]
        );
    }
    // In-plane rigid motions (3) and torsion mode unobservable from gaps (flat mirror).
    let sv = singular_values(&interaction_matrices(&keck(true, 0.1)).a_gw);
    assert_eq!(rank(&sv, RANK_TOL), na - 4, "{:?}", &sv[na - 6..]);
}

#[test]
fn flat_mirror_decouples_in_plane_and_out_of_plane() {
    for layout in [Layout::keck(), Layout::tmt()] {
        let m = interaction_matrices(&geometry(&layout, true, 0.1));
        for (name, block) in [("hw", &m.a_hw), ("gz", &m.a_gz), ("sz", &m.a_sz)] {
            assert!(
                block.triplet_iter().all(|t| *t.val == 0.0),
                "{} A_{name} not zero",
                layout.name
            );
        }
        assert!(frobenius(&m.a_gw) > 0.0 && frobenius(&m.a_sw) > 0.0);
    }
}

/// Curved: the coupling blocks are non-zero. Gap and shear versus out-of-plane motion scale as
/// 1/R (ratio 2 between R and 2R, to within 2 %). Height versus in-plane motion cancels to first
/// order on a sphere (sliding or clocking along the prescription changes neither height nor
/// dihedral): what remains scales as 1/R^3 (ratio 8 to within 5 %; measured 7.94).
#[test]
fn curved_coupling_blocks_scale_as_inverse_radius() {
    let m1 = interaction_matrices(&keck_with_radius(KECK_RADIUS_OF_CURVATURE));
    let m2 = interaction_matrices(&keck_with_radius(2.0 * KECK_RADIUS_OF_CURVATURE));
    for (name, b1, b2) in [
        ("hw", &m1.a_hw, &m2.a_hw),
        ("gz", &m1.a_gz, &m2.a_gz),
        ("sz", &m1.a_sz, &m2.a_sz),
    ] {
        let (n1, n2) = (frobenius(b1), frobenius(b2));
        assert!(n1 > 1e-6, "A_{name} = {n1:e}");
        let ratio = n1 / n2;
        let expected = if name == "hw" { 8.0 } else { 2.0 };
        assert!(
            (ratio - expected).abs() < 0.05 * expected,
            "A_{name}: ratio {ratio}, expected {expected}"
        );
    }
}

/// Focus mode (the smallest non-zero singular value of A, flat Keck) is proportional to Leff:
/// halving Leff halves it, to within 1 % for small Leff (0.02 -> 0.01 m; measured ratio 2.011)
/// and 3 % at the default (0.1 -> 0.05 m; measured 2.041), while the largest singular value
/// changes by less than 5 %.
#[test]
fn focus_mode_proportional_to_leff() {
    let na = 108;
    let focus = na - 4; // index of the smallest non-zero singular value (rank na - 3)
    for (leff, tol) in [(0.1, 0.03), (0.02, 0.01)] {
        let s1 = singular_values(&a_matrix(&keck(true, leff)));
        let s2 = singular_values(&a_matrix(&keck(true, leff / 2.0)));
        assert_eq!(rank(&s1, RANK_TOL), na - 3);
        let ratio = s2[focus] / s1[focus];
        assert!(
            (ratio - 0.5).abs() < 0.5 * tol,
            "Leff {leff}: ratio {ratio}"
        );
        assert!((s2[0] / s1[0] - 1.0).abs() < 0.05);
        // Focus mode is the least observable mode by far (next one 3.6x larger at Leff 0.1).
        assert!(s1[focus] < s1[focus - 1]);
    }
}

#[test]
fn single_segment_piston_reads_plus_minus_one_micron() {
    let piston = 1e-6;
    for layout in [Layout::keck(), Layout::tmt()] {
        for flat in [true, false] {
            let g = geometry(&layout, flat, 0.1);
            let m = interaction_matrices(&g);
            for seg in [0, g.n_segments() / 2] {
                let mut z = Mat::<f64>::zeros(g.n_actuators(), 1);
                for k in 0..3 {
                    z[(3 * seg + k, 0)] = piston;
                }
                let (h, gap, shear) = (&m.a_hz * &z, &m.a_gz * &z, &m.a_sz * &z);
                // Flat: exact to rounding. Curved: the normals of the segment and of the sensor
                // point differ by ~ pitch / R, so the height reading differs at second order
                // (< 1e-3 relative) and the gap and shear at first order (< 5 %).
                let (h_tol, gs_tol) = if flat { (1e-15, 0.0) } else { (1e-9, 0.05e-6) };
                let mut touched = 0;
                for (n, s) in g.sensors.iter().enumerate() {
                    let expected = if s.i == seg {
                        piston
                    } else if s.j == seg {
                        -piston
                    } else {
                        0.0
                    };
                    touched += usize::from(expected != 0.0);
                    assert!(
                        (h[(n, 0)] - expected).abs() <= h_tol,
                        "sensor {n}: {}",
                        h[(n, 0)]
                    );
                    assert!(gap[(n, 0)].abs() <= gs_tol && shear[(n, 0)].abs() <= gs_tol);
                }
                assert_eq!(touched, 2 * g.layout.neighbours(seg).len());
            }
        }
    }
}

#[test]
fn ptt_matrix_and_actuator_points() {
    for layout in [Layout::keck(), Layout::tmt()] {
        let g = geometry(&layout, false, 0.1);
        let r_act = g.params.actuator_radius;
        for (i, f) in g.segments.iter().enumerate() {
            let (p, q) = (g.ptt_matrix(i), g.ptt_inverse(i));
            for r in 0..3 {
                for c in 0..3 {
                    let pq: f64 = (0..3).map(|k| p[r][k] * q[k][c]).sum();
                    let qp: f64 = (0..3).map(|k| q[r][k] * p[k][c]).sum();
                    let id = if r == c { 1.0 } else { 0.0 };
                    assert!((pq - id).abs() < 1e-12 && (qp - id).abs() < 1e-12);
                }
            }
            let (c, n, rad, az) = (v3(f.centre), v3(f.normal), v3(f.radial), v3(f.azimuthal));
            // Orthonormal, right-handed frame; radial points away from the axis.
            assert!((rad.cross(&az) - n).norm() < 1e-12);
            assert!((n.norm() - 1.0).abs() < 1e-12 && (rad.norm() - 1.0).abs() < 1e-12);
            assert!(rad.dot(&n).abs() < 1e-12 && n.z > 0.0);
            assert!(rad.x * c.x + rad.y * c.y > 0.0);
            for (k, (actuator, p_row)) in f.actuators.iter().zip(p).enumerate() {
                let d = v3(*actuator) - c;
                assert!((d.norm() - r_act).abs() < 1e-12 * r_act, "distance");
                assert!(d.dot(&n).abs() < 1e-12 * r_act, "tangent plane");
                let angle = 2.0 * std::f64::consts::PI * k as f64 / 3.0;
                assert!((d.dot(&rad) - r_act * angle.cos()).abs() < 1e-12);
                // Row k of P is [1, r sin phi, -r cos phi].
                let row = [1.0, r_act * angle.sin(), -r_act * angle.cos()];
                for (value, expected) in p_row.into_iter().zip(row) {
                    assert!((value - expected).abs() < 1e-12);
                }
            }
            // Centre and corners on the prescription.
            let pr = &g.prescription;
            assert!((f.centre[2] - pr.sag(c.x.hypot(c.y))).abs() < 1e-15);
            for v in f.vertices {
                assert_eq!(v, pr.surface_point(v[0], v[1]));
            }
        }
    }
}

#[test]
fn sensor_points_and_directions() {
    let layout = Layout::tmt();
    let g = geometry(&layout, false, 0.1);
    let e = g.params.sensor_offset;
    for (n, s) in g.sensors.iter().enumerate() {
        let edge = &layout.edges[n / 2];
        assert_eq!((s.edge, s.i, s.j), (n / 2, edge.i, edge.j));
        let (h, gap, sh) = (v3(s.height), v3(s.gap), v3(s.shear));
        assert!((h.norm() - 1.0).abs() < 1e-12 && (gap.norm() - 1.0).abs() < 1e-12);
        assert!(h.dot(&gap).abs() < 1e-12 && (h.cross(&gap) - sh).norm() < 1e-15);
        // The surface slope reaches ~0.25 at the TMT rim, so the gap direction leaves the
        // aperture plane by up to ~14 degrees.
        assert!(gap.x * edge.normal[0] + gap.y * edge.normal[1] > 0.96);
        assert_eq!(s.height, g.prescription.normal(s.point[0], s.point[1]));
        assert_eq!(s.point[2], g.prescription.sag(s.point[0].hypot(s.point[1])));
        // In 2-D: on the gap centre line (equidistant from both centres) at e from an edge end,
        // i.e. at (a/2 - e) from the edge midpoint.
        let (ci, cj) = (layout.segments[s.i].center, layout.segments[s.j].center);
        let di = (s.point[0] - ci[0]).hypot(s.point[1] - ci[1]);
        let dj = (s.point[0] - cj[0]).hypot(s.point[1] - cj[1]);
        assert!((di - dj).abs() < 1e-12);
        let mid = [(ci[0] + cj[0]) / 2.0, (ci[1] + cj[1]) / 2.0];
        let along = (s.point[0] - mid[0]).hypot(s.point[1] - mid[1]);
        assert!((along - (layout.circumradius / 2.0 - e)).abs() < 1e-12);
    }
    // The two sensors of an edge are on opposite sides of its midpoint (2-D distance a - 2e).
    for pair in g.sensors.chunks(2) {
        let d = (pair[0].point[0] - pair[1].point[0]).hypot(pair[0].point[1] - pair[1].point[1]);
        assert!((d - (layout.circumradius - 2.0 * e)).abs() < 1e-12);
    }
}

/// An in-plane radial or azimuthal move keeps the segment tangent to the sphere of radius R
/// through its centre: after a move by 1 um the normal still points at the centre of curvature
/// C = c + R n, to second order (< 1e-12; a wrong sign would leave 2 d / R ~ 6e-8).
#[test]
fn in_plane_motion_follows_the_sphere() {
    let g = keck(false, 0.1);
    let radius = g.prescription.radius_of_curvature;
    let delta = 1e-6;
    for (i, f) in g.segments.iter().enumerate() {
        let (c, n) = (v3(f.centre), v3(f.normal));
        let centre_of_curvature = c + radius * n;
        for w in [[delta, 0.0, 0.0], [0.0, delta, 0.0], [delta, -delta, 0.0]] {
            let m = in_plane_motion(&g, i, w);
            let moved = c + v3(m.translation);
            let new_normal = (n + v3(m.rotation).cross(&n)).normalize();
            let towards = (centre_of_curvature - moved).normalize();
            assert!((new_normal - towards).norm() < 1e-12, "segment {i} {w:?}");
            // The centre stays on the sphere to second order as well.
            assert!(((centre_of_curvature - moved).norm() - radius).abs() < 1e-9);
        }
        // Clocking turns about the normal only.
        let m = in_plane_motion(&g, i, [0.0, 0.0, 1.0]);
        assert_eq!(m.translation, [0.0; 3]);
        assert!((v3(m.rotation) - n).norm() < 1e-15);
    }
}

#[test]
fn coordinates_round_trip_and_matrix_matches_direct_readings() {
    let g = keck(false, 0.1);
    let (nseg, na) = (g.n_segments(), g.n_actuators());
    let z = pseudo_random(na, 0.37);
    let w = pseudo_random(na, 0.91);
    let motions: Vec<RigidMotion> = (0..nseg)
        .map(|i| {
            let zi = [z[3 * i], z[3 * i + 1], z[3 * i + 2]];
            let wi = [w[3 * i], w[3 * i + 1], w[3 * i + 2]];
            let m = out_of_plane_motion(&g, i, zi).add(&in_plane_motion(&g, i, wi));
            let (zb, wb) = segment_coordinates(&g, i, &m);
            for k in 0..3 {
                assert!((zb[k] - zi[k]).abs() < 1e-12 && (wb[k] - wi[k]).abs() < 1e-12);
            }
            m
        })
        .collect();
    let full = interaction_matrices(&g).full();
    let x = Mat::<f64>::from_fn(2 * na, 1, |r, _| if r < na { z[r] } else { w[r - na] });
    let y = &full * &x;
    let ns = g.n_sensors();
    for (n, s) in g.sensors.iter().enumerate() {
        let direct = sensor_reading(&g, n, &motions[s.i], &motions[s.j]);
        for (k, value) in direct.into_iter().enumerate() {
            assert!(
                (y[(k * ns + n, 0)] - value).abs() < 1e-12,
                "sensor {n} reading {k}"
            );
        }
    }
}

#[test]
fn invalid_parameters_are_rejected() {
    let layout = Layout::keck();
    let good = GeometryParams::for_layout(&layout);
    assert_eq!(good.actuator_radius, 0.45);
    assert!((good.sensor_offset - 0.125).abs() < 1e-15);
    let tmt = GeometryParams::for_layout(&Layout::tmt());
    assert_eq!(
        (tmt.actuator_radius, tmt.sensor_offset, tmt.leff),
        (0.36, 0.10, 0.1)
    );
    let cases = [
        GeometryParams {
            actuator_radius: 0.0,
            ..good
        },
        GeometryParams {
            actuator_radius: f64::NAN,
            ..good
        },
        GeometryParams {
            actuator_radius: 1.0,
            ..good
        },
        GeometryParams {
            sensor_offset: -0.01,
            ..good
        },
        GeometryParams {
            sensor_offset: 0.45,
            ..good
        },
        GeometryParams { leff: -0.1, ..good },
        GeometryParams {
            leff: f64::INFINITY,
            ..good
        },
    ];
    for params in cases {
        assert!(Geometry::new(&layout, params).is_err(), "{params:?}");
    }
    // A conic that is not defined over the whole aperture.
    let steep = layout.clone().with_optics(5.0, 0.0).unwrap();
    assert!(Geometry::new(&steep, good).is_err());
    // flat = true ignores R; a flat layout gives a flat prescription too.
    let flat = Geometry::new(&steep, GeometryParams { flat: true, ..good }).unwrap();
    assert!(flat.prescription.is_flat());
    let flat_layout = layout.with_optics(f64::INFINITY, 0.0).unwrap();
    assert!(
        Geometry::new(&flat_layout, good)
            .unwrap()
            .prescription
            .is_flat()
    );
}

/// Prints the singular values of A for Keck and TMT (ignored: slow in debug builds).
#[test]
#[ignore]
fn tmt_report() {
    for layout in [Layout::keck(), Layout::tmt()] {
        for (flat, leff) in [(true, 0.1), (false, 0.1), (true, 0.0), (false, 0.0)] {
            let g = geometry(&layout, flat, leff);
            let sv = singular_values(&a_matrix(&g));
            let na = g.n_actuators();
            let nz = rank(&sv, 1e-4);
            println!(
                "{} flat {flat} leff {leff}: max {:.6e}, rank(1e-9) {}, rank(1e-4) {nz}, \
                 smallest kept {:.6e}, cond {:.4e}, smallest 6 {:?}",
                layout.name,
                sv[0],
                rank(&sv, RANK_TOL),
                sv[nz - 1],
                sv[0] / sv[nz - 1],
                &sv[na - 6..]
            );
        }
    }
}

/// The reconstructor on a real A (Keck, curved): the sparse path equals the dense (A P)^+ to
/// 1e-9 relative, with and without a focus-mode gain, and B0 A P = P on observable patterns.
#[test]
fn reconstructor_paths_agree_on_keck() {
    reconstructor_paths_agree(&Layout::keck());
}

/// The same on TMT (the size the sparse path is for; release mode: a 2772 x 1476 SVD).
#[test]
fn reconstructor_paths_agree_on_tmt() {
    reconstructor_paths_agree(&Layout::tmt());
}

fn reconstructor_paths_agree(layout: &Layout) {
    use m1::control::reconstructor::{
        DenseReconstructor, ModalGain, SparseReconstructor, orthonormalize,
    };
    let g = geometry(layout, false, 0.1);
    let a = a_matrix(&g);
    let null = global_ptt(&g);
    let n = orthonormalize(null.as_ref());
    let na = a.ncols();
    // Focus-mode-like pattern for the modal gain: any unit vector orthogonal to N will do.
    let mut mode: Vec<f64> = (0..na).map(|i| ((i * 13) % 7) as f64 - 3.0).collect();
    for c in 0..3 {
        let d: f64 = (0..na).map(|i| n[(i, c)] * mode[i]).sum();
        for (i, m) in mode.iter_mut().enumerate() {
            *m -= d * n[(i, c)];
        }
    }
    let norm = mode.iter().map(|x| x * x).sum::<f64>().sqrt();
    mode.iter_mut().for_each(|x| *x /= norm);
    for gain in [1.0, 0.25] {
        let modes = vec![ModalGain {
            mode: mode.clone(),
            gain,
        }];
        let sp = SparseReconstructor::new(&a, null.as_ref(), modes.clone()).expect("sparse");
        let de = DenseReconstructor::new(a.to_dense().as_ref(), null.as_ref(), 1e-12, &modes)
            .expect("dense");
        let y: Vec<f64> = (0..a.nrows()).map(|i| (i as f64 * 0.61).sin()).collect();
        let (zs, zd) = (sp.apply(&y), de.apply(&y));
        let scale = zd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let err = zs
            .iter()
            .zip(&zd)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(err <= 1e-9 * scale, "gain {gain}: {err:e} vs {scale:e}");
        // The transpose (used by the robustness estimates) against the dense B^T.
        let x: Vec<f64> = (0..na).map(|i| (i as f64 * 0.29).cos()).collect();
        let ys = sp.apply_transpose(&x);
        let yd: Vec<f64> = (0..a.nrows())
            .map(|c| (0..na).map(|r| de.b[(r, c)] * x[r]).sum())
            .collect();
        let scale = yd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let err = ys
            .iter()
            .zip(&yd)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            err <= 1e-9 * scale,
            "transpose, gain {gain}: {err:e} vs {scale:e}"
        );
    }
    // B0 A P = P.
    let sp = SparseReconstructor::new(&a, null.as_ref(), vec![]).expect("sparse");
    let mut x: Vec<f64> = (0..na).map(|i| (i as f64 * 0.37).cos()).collect();
    for c in 0..3 {
        let d: f64 = (0..na).map(|i| n[(i, c)] * x[i]).sum();
        for (i, v) in x.iter_mut().enumerate() {
            *v -= d * n[(i, c)];
        }
    }
    let ad = a.to_dense();
    let ax: Vec<f64> = (0..a.nrows())
        .map(|r| (0..na).map(|c| ad[(r, c)] * x[c]).sum())
        .collect();
    let back = sp.apply(&ax);
    let err = back
        .iter()
        .zip(&x)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(err < 1e-9, "B0 A P - P: {err:e}");
}

/// With Leff = 0 on a flat mirror, A has a fourth unobservable mode (focus-mode) besides global
/// piston/tip/tilt: the sparse reconstructor refuses to factorise rather than return noise.
#[test]
fn reconstructor_refuses_extra_unobservable_modes() {
    use m1::M1Error;
    use m1::control::reconstructor::SparseReconstructor;
    let g = keck(true, 0.0);
    let a = a_matrix(&g);
    match SparseReconstructor::new(&a, global_ptt(&g).as_ref(), vec![]) {
        Err(M1Error::Numerical(msg)) => assert!(msg.contains("unobservable"), "{msg}"),
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("factorised a singular normal matrix"),
    }
    // With Leff > 0 the same flat mirror factorises.
    let g = keck(true, 0.1);
    assert!(SparseReconstructor::new(&a_matrix(&g), global_ptt(&g).as_ref(), vec![]).is_ok());
}

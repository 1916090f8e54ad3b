//! Mirror layouts: segment, actuator, edge and sensor counts of the presets, TMT numbering and
//! symmetry, geometric edge finding, JSON round trips and error cases.

#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use m1::aperture::layout::{Edge, Layout, LayoutError, Segment, TMT_SECTOR_SIZE, TMT_SECTORS, hex};

/// Positions computed from integer grid coordinates agree to a few ulps of ~20 m.
const POS_TOL: f64 = 1e-9;

fn radius(c: [f64; 2]) -> f64 {
    c[0].hypot(c[1])
}

/// `c` rotated by `deg` degrees counter-clockwise.
fn rotate(c: [f64; 2], deg: f64) -> [f64; 2] {
    let (s, co) = deg.to_radians().sin_cos();
    [co * c[0] - s * c[1], s * c[0] + co * c[1]]
}

fn close(a: [f64; 2], b: [f64; 2], tol: f64) -> bool {
    (a[0] - b[0]).hypot(a[1] - b[1]) <= tol
}

/// Polar angle in degrees, in [0, 360).
fn angle_deg(c: [f64; 2]) -> f64 {
    c[1].atan2(c[0]).to_degrees().rem_euclid(360.0)
}

/// Checks shared by every layout: edges sorted, i < j, unique, unit normals from i to j at one
/// pitch; neighbour lists symmetric; histogram consistent with the edges.
fn check_invariants(layout: &Layout) {
    let p = layout.pitch();
    let pairs: Vec<(usize, usize)> = layout.edges.iter().map(|e| (e.i, e.j)).collect();
    let mut sorted = pairs.clone();
    sorted.sort_unstable();
    sorted.dedup();
    assert_eq!(
        pairs, sorted,
        "{}: edges sorted by (i, j), no duplicates",
        layout.name
    );
    for &Edge { i, j, normal } in &layout.edges {
        assert!(i < j && j < layout.n_segments());
        let (ci, cj) = (layout.segments[i].center, layout.segments[j].center);
        let d = [cj[0] - ci[0], cj[1] - ci[1]];
        let dist = radius(d);
        assert!((radius(normal) - 1.0).abs() < 1e-12, "unit normal");
        assert!(
            (normal[0] * d[0] + normal[1] * d[1] - dist).abs() < 1e-12,
            "normal points from {i} towards {j}"
        );
        assert!((dist - p).abs() <= 0.01 * p, "edge at one pitch");
        // The normal is one of the six side normals 0, 60, ..., 300 degrees (grid layouts).
        let a = angle_deg(normal) / 60.0;
        assert!((a - a.round()).abs() < 1e-9, "normal along a side normal");
    }
    let hist = layout.neighbour_histogram();
    assert_eq!(hist.values().sum::<usize>(), layout.n_segments());
    assert_eq!(
        hist.iter().map(|(k, v)| k * v).sum::<usize>(),
        2 * layout.n_edges(),
        "sum of degrees = 2 x edges"
    );
    for i in 0..layout.n_segments() {
        for j in layout.neighbours(i) {
            assert!(layout.neighbours(j).contains(&i), "neighbours symmetric");
        }
    }
    assert_eq!(layout.n_actuators(), 3 * layout.n_segments());
    assert_eq!(layout.n_sensors(), 2 * layout.n_edges());
}

/// Every centre rotated by 60 degrees lands on a centre.
fn assert_six_fold(layout: &Layout) {
    let centers: Vec<[f64; 2]> = layout.segments.iter().map(|s| s.center).collect();
    for &c in &centers {
        let r = rotate(c, 60.0);
        assert!(
            centers.iter().any(|&o| close(o, r, POS_TOL)),
            "{}: ({}, {}) rotated by 60 degrees is not a segment centre",
            layout.name,
            c[0],
            c[1]
        );
    }
}

fn names(layout: &Layout, idx: &[usize]) -> BTreeSet<String> {
    idx.iter()
        .map(|&i| layout.segments[i].name.clone())
        .collect()
}

fn set(names: &[&str]) -> BTreeSet<String> {
    names.iter().map(|s| s.to_string()).collect()
}

#[test]
fn tmt_counts() {
    let tmt = Layout::tmt();
    assert_eq!(tmt.name, "tmt");
    assert_eq!(tmt.n_segments(), 492);
    assert_eq!(tmt.n_actuators(), 1476);
    assert_eq!(tmt.n_edges(), 1386);
    assert_eq!(tmt.n_sensors(), 2772);
    let expected: BTreeMap<usize, usize> = [(3, 24), (4, 42), (5, 24), (6, 402)].into();
    assert_eq!(tmt.neighbour_histogram(), expected);
    assert!(
        (tmt.pitch() - 1.24958).abs() < 5e-6,
        "pitch {}",
        tmt.pitch()
    );
    assert_eq!(tmt.circumradius, 0.72);
    assert_eq!(tmt.gap, 0.0025);
    assert_eq!(tmt.radius_of_curvature, 60.0);
    assert_eq!(tmt.conic, -1.000953);
    check_invariants(&tmt);
}

#[test]
fn tmt_sectors_names_and_radii() {
    let tmt = Layout::tmt();
    for (s, letter) in TMT_SECTORS.iter().enumerate() {
        let in_sector = tmt
            .segments
            .iter()
            .filter(|seg| seg.name.starts_with(*letter))
            .count();
        assert_eq!(in_sector, 82, "sector {letter}");
        for n in 1..=TMT_SECTOR_SIZE {
            let name = format!("{letter}{n}");
            assert_eq!(tmt.find(&name), Some(s * 82 + n - 1), "{name}");
        }
    }
    assert_eq!(tmt.find("A1"), Some(0));
    assert_eq!(tmt.find("F82"), Some(491));
    assert_eq!(tmt.find("G1"), None);
    assert_eq!(tmt.find("A83"), None);

    let radii: Vec<f64> = tmt.segments.iter().map(|s| radius(s.center)).collect();
    let min = radii.iter().copied().fold(f64::INFINITY, f64::min);
    let max = radii.iter().copied().fold(0.0, f64::max);
    assert!((min - 2.16).abs() < 0.01, "min centre radius {min}");
    assert!((max - 14.41).abs() < 0.01, "max centre radius {max}");
    assert!(max < 0.98 * 15.0);
}

#[test]
fn tmt_six_fold_symmetry_maps_sector_to_next() {
    let tmt = Layout::tmt();
    assert_six_fold(&tmt);
    // Segment n of a sector, rotated by +60 degrees, is segment n of the next sector.
    for (k, seg) in tmt.segments.iter().enumerate() {
        let next = (k + TMT_SECTOR_SIZE) % tmt.n_segments();
        let target = tmt.segments[next].center;
        assert!(
            close(rotate(seg.center, 60.0), target, POS_TOL),
            "{} -> {}",
            seg.name,
            tmt.segments[next].name
        );
    }
    // Sector A is the wedge (60, 120] degrees, B (120, 180], ..., F (0, 60].
    for (s, letter) in TMT_SECTORS.iter().enumerate() {
        let lo = 60.0 * (s as f64 + 1.0);
        for seg in tmt
            .segments
            .iter()
            .filter(|seg| seg.name.starts_with(*letter))
        {
            let mut a = angle_deg(seg.center);
            if a <= lo - 1e-9 {
                a += 360.0;
            }
            assert!(
                a > lo + 1e-9 && a <= lo + 60.0 + 1e-9,
                "{} at {a} degrees",
                seg.name
            );
        }
    }
}

#[test]
fn tmt_matches_the_equivalent_radius_rule() {
    // 13-ring hex grid, hex distances 0 and 1 dropped, centres closer than 0.98 x 15 m.
    let rule = Layout::hexagonal("tmt-rule", 13, 1, 0.72, 0.0025, Some(0.98 * 15.0))
        .expect("valid parameters");
    let tmt = Layout::tmt();
    let cells = |l: &Layout| -> BTreeSet<[i32; 3]> {
        l.segments
            .iter()
            .map(|s| s.hex.expect("grid layout"))
            .collect()
    };
    assert_eq!(rule.n_segments(), 492);
    assert_eq!(cells(&rule), cells(&tmt));
    assert_eq!(rule.n_edges(), tmt.n_edges());
}

#[test]
fn tmt_sector_a_rings() {
    let tmt = Layout::tmt();
    let ring_of = |name: &str| -> u32 {
        let i = tmt.find(name).expect("segment exists");
        hex::distance(tmt.segments[i].hex.expect("grid layout"))
    };
    // Rings 1..10: ring k holds k + 1 segments on hex ring k + 1.
    let mut n = 1;
    for k in 1..=10 {
        for _ in 0..=k {
            assert_eq!(ring_of(&format!("A{n}")), k + 1, "A{n}");
            n += 1;
        }
    }
    assert_eq!(n, 66);
    for m in 66..=76 {
        assert_eq!(ring_of(&format!("A{m}")), 12, "A{m}");
    }
    for m in 77..=82 {
        assert_eq!(ring_of(&format!("A{m}")), 13, "A{m}");
    }
    // A1 is the corner of hex ring 2 at 120 degrees; A2 lies on +y.
    let p = tmt.pitch();
    let a1 = tmt.segments[0].center;
    assert!(close(a1, rotate([2.0 * p, 0.0], 120.0), POS_TOL));
    let a2 = tmt.segments[1].center;
    assert!(close(a2, [0.0, 3.0_f64.sqrt() * p], POS_TOL));
}

#[test]
fn tmt_neighbours_match_published_numbering() {
    // TMT's neighbour lists (tmtsoftware/m1cs-neighbors README): A15 borders A10, A16, A21,
    // A22, B20, B27; A1's sensors face A3 and B5.
    let tmt = Layout::tmt();
    let a15 = tmt.find("A15").expect("A15");
    assert_eq!(
        names(&tmt, &tmt.neighbours(a15)),
        set(&["A10", "A16", "A21", "A22", "B20", "B27"])
    );
    let a1 = tmt.find("A1").expect("A1");
    assert_eq!(
        names(&tmt, &tmt.neighbours(a1)),
        set(&["A2", "A3", "A4", "B2", "B5"])
    );
    assert_eq!(tmt.neighbours(10_000), Vec::<usize>::new());
}

#[test]
fn keck_counts_and_numbering() {
    let keck = Layout::keck();
    assert_eq!(keck.n_segments(), 36);
    assert_eq!(keck.n_actuators(), 108);
    assert_eq!(keck.n_edges(), 84);
    assert_eq!(keck.n_sensors(), 168);
    check_invariants(&keck);
    assert_six_fold(&keck);
    let p = keck.pitch();
    assert!((p - (3.0_f64.sqrt() * 0.9 + 0.003)).abs() < 1e-15);
    assert_eq!(keck.radius_of_curvature, 35.0);
    // Names "1".."36", ring by ring: 1..6, 7..18, 19..36, counter-clockwise from +x.
    for (i, s) in keck.segments.iter().enumerate() {
        assert_eq!(s.name, (i + 1).to_string());
        let ring = match i + 1 {
            1..=6 => 1,
            7..=18 => 2,
            _ => 3,
        };
        assert_eq!(
            hex::distance(s.hex.expect("grid")),
            ring,
            "segment {}",
            s.name
        );
    }
    for start in [0, 6, 18] {
        let c = keck.segments[start].center;
        assert!(c[0] > 0.0 && c[1].abs() < POS_TOL, "ring starts on +x");
    }
    for w in keck.segments.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if hex::distance(a.hex.expect("grid")) == hex::distance(b.hex.expect("grid")) {
            assert!(
                angle_deg(b.center) > angle_deg(a.center),
                "counter-clockwise"
            );
        }
    }
    assert!(close(keck.segments[0].center, [p, 0.0], POS_TOL));
}

#[test]
fn elt_has_798_segments_in_six_sectors_of_133() {
    let elt = Layout::elt();
    assert_eq!(elt.n_segments(), 798);
    assert_eq!(elt.n_actuators(), 2394);
    check_invariants(&elt);
    assert_six_fold(&elt);
    let mut per_sector = [0_usize; 6];
    for s in &elt.segments {
        // Half-open wedges (60 k, 60 (k + 1)], shifted off the boundary rays.
        let a = (angle_deg(s.center) - 1e-9).rem_euclid(360.0);
        per_sector[(a / 60.0) as usize % 6] += 1;
    }
    assert_eq!(per_sector, [133; 6]);
    let radii: Vec<f64> = elt.segments.iter().map(|s| radius(s.center)).collect();
    let max = radii.iter().copied().fold(0.0, f64::max);
    let min = radii.iter().copied().fold(f64::INFINITY, f64::min);
    // ~39 m across the outer segment corners; ~9.4 m central hole (across the inner flats).
    assert!((2.0 * (max + 0.7) - 39.0).abs() < 0.5, "outer {max}");
    assert!(
        (2.0 * (min - 0.7 * 0.75_f64.sqrt()) - 9.3).abs() < 0.5,
        "hole {min}"
    );
    assert!((elt.pitch() - (3.0_f64.sqrt() * 0.7 + 0.004)).abs() < 1e-15);
}

#[test]
fn presets_by_name() {
    assert_eq!(Layout::PRESETS, &["keck", "tmt", "elt"]);
    for name in Layout::PRESETS {
        let l = Layout::preset(name).expect("known preset");
        assert_eq!(l.name, *name);
    }
    assert_eq!(
        Layout::preset("TMT")
            .expect("case-insensitive")
            .n_segments(),
        492
    );
    assert_eq!(Layout::preset(" Keck ").expect("trimmed").n_segments(), 36);
    assert_eq!(
        Layout::preset("Elt")
            .expect("case-insensitive")
            .n_segments(),
        798
    );
    match Layout::preset("gmt") {
        Err(LayoutError::UnknownPreset { name, known }) => {
            assert_eq!(name, "gmt");
            assert_eq!(known, Layout::PRESETS);
        }
        other => panic!("expected UnknownPreset, got {other:?}"),
    }
}

#[test]
fn hexagonal_builder_counts() {
    // Full grid of hex distances (h, R]: 3 R (R + 1) - 3 h (h + 1) segments.
    for (rings, hole) in [(1, 0), (3, 0), (5, 2), (8, 1)] {
        let l = Layout::hexagonal("g", rings, hole, 0.5, 0.001, None).expect("valid");
        let (r, h) = (rings as usize, hole as usize);
        assert_eq!(l.n_segments(), 3 * r * (r + 1) - 3 * h * (h + 1));
        check_invariants(&l);
        assert_eq!(l.segments[0].name, "S1");
        assert!(l.radius_of_curvature.is_infinite());
    }
    // A full hexagon with R rings, centre included, has 3 R (3 R + 1) edges; with it removed
    // (R >= 1) six fewer.
    let l = Layout::hexagonal("g", 4, 0, 0.5, 0.0, None).expect("valid");
    assert_eq!(l.n_edges(), 3 * 4 * (3 * 4 + 1) - 6);
}

#[test]
fn vertices_of_neighbours_are_one_gap_apart() {
    let tmt = Layout::tmt();
    for (k, v) in tmt.vertices(0).expect("segment 0").iter().enumerate() {
        let c = tmt.segments[0].center;
        assert!(
            (radius([v[0] - c[0], v[1] - c[1]]) - 0.72).abs() < 1e-12,
            "corner {k}"
        );
    }
    // Across each shared edge the facing sides are parallel and `gap` apart.
    for e in tmt.edges.iter().take(50) {
        let vi = tmt.vertices(e.i).expect("i");
        let vj = tmt.vertices(e.j).expect("j");
        let side_i = vi.iter().map(|v| v[0] * e.normal[0] + v[1] * e.normal[1]);
        let side_j = vj.iter().map(|v| v[0] * e.normal[0] + v[1] * e.normal[1]);
        let front_i = side_i.fold(f64::NEG_INFINITY, f64::max);
        let back_j = side_j.fold(f64::INFINITY, f64::min);
        assert!((back_j - front_i - tmt.gap).abs() < 1e-12);
    }
    assert!(tmt.vertices(492).is_none());
}

#[test]
fn json_round_trip_of_presets() {
    for name in Layout::PRESETS {
        let l = Layout::preset(name).expect("preset");
        let text = l.to_json_string();
        let back = Layout::from_json_str(&text).expect("round trip");
        assert_eq!(back, l, "{name}");
    }
    let flat = Layout::hexagonal("flat", 2, 0, 0.5, 0.002, None).expect("valid");
    let text = flat.to_json_string();
    assert!(text.contains("\"radius_of_curvature\": null"));
    assert_eq!(Layout::from_json_str(&text).expect("round trip"), flat);
}

#[test]
fn json_file_round_trip() {
    let dir = std::env::temp_dir().join(format!("m1-layout-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join("keck.json");
    let keck = Layout::keck();
    keck.write_json_file(&path).expect("write");
    assert_eq!(Layout::from_json_file(&path).expect("read"), keck);
    std::fs::write(&path, "{ not json").expect("write");
    match Layout::from_json_file(&path) {
        Err(LayoutError::Json { path: Some(p), .. }) => assert_eq!(p, path),
        other => panic!("expected Json error, got {other:?}"),
    }
    std::fs::remove_dir_all(&dir).expect("clean up");
    match Layout::from_json_file(Path::new("/nonexistent/dir/layout.json")) {
        Err(e @ LayoutError::Io { .. }) => assert!(e.to_string().contains("layout.json")),
        other => panic!("expected Io error, got {other:?}"),
    }
}

/// Three segments around a common corner, given by coordinates only.
const TRIANGLE: &str = r#"{
  "name": "triangle",
  "circumradius": 1.0,
  "gap": 0.01,
  "radius_of_curvature": 20.0,
  "conic": -1.0,
  "segments": [
    { "name": "S1", "x": 0.0, "y": 0.0 },
    { "name": "S2", "x": 1.74205, "y": 0.0 },
    { "name": "S3", "x": 0.871025, "y": 1.508659 }
  ]
}"#;

#[test]
fn json_user_layout_edges_found_geometrically() {
    let l = Layout::from_json_str(TRIANGLE).expect("valid layout");
    assert_eq!(l.name, "triangle");
    assert_eq!(l.n_segments(), 3);
    assert_eq!(l.n_edges(), 3);
    assert_eq!(l.n_sensors(), 6);
    assert_eq!(
        l.edges.iter().map(|e| (e.i, e.j)).collect::<Vec<_>>(),
        [(0, 1), (0, 2), (1, 2)]
    );
    assert!(l.segments.iter().all(|s| s.hex.is_none()));
    assert_eq!(l.find("S3"), Some(2));
    assert_eq!(l.neighbour_histogram(), [(2, 3)].into());
    let n = l.edges[2].normal;
    assert!((n[0] + 0.5).abs() < 1e-5 && (n[1] - 0.75_f64.sqrt()).abs() < 1e-5);
    assert_eq!(l.radius_of_curvature, 20.0);
    assert_eq!(l.conic, -1.0);

    // Round trip of centres not on a grid: the same segments and edges, centres to 1 ulp
    // (exact with serde_json's `float_roundtrip` feature).
    let back = Layout::from_json_str(&l.to_json_string()).expect("round trip");
    assert_eq!(back.edges.len(), l.edges.len());
    for (a, b) in back.segments.iter().zip(&l.segments) {
        assert_eq!((&a.name, a.hex), (&b.name, b.hex));
        assert!(close(a.center, b.center, 1e-15));
    }

    // Centres more than 1 % of the pitch beyond it share no edge.
    let apart = TRIANGLE.replace("1.74205", "1.8");
    let l = Layout::from_json_str(&apart).expect("valid layout");
    assert_eq!(
        l.edges.iter().map(|e| (e.i, e.j)).collect::<Vec<_>>(),
        [(0, 2)]
    );
}

#[test]
fn json_flat_mirror_and_defaults() {
    let doc = r#"{ "name": "two", "circumradius": 0.5, "gap": 0.0,
        "segments": [ { "name": "a", "x": 0.0, "y": 0.0, "hex": [0, 0, 0] },
                      { "name": "b", "x": 0.8660254037844386, "y": 0.0, "hex": [0, 1, -1] } ] }"#;
    // hex [0, 1, -1] is at 60 degrees, not on +x: rejected.
    assert!(matches!(
        Layout::from_json_str(doc),
        Err(LayoutError::InvalidHex { .. })
    ));
    // Within 1e-6 of the pitch, the grid position wins; beyond, rejected.
    let off = doc.replace("[0, 1, -1]", "[1, 0, -1]");
    let nudged = off.replace("0.8660254037844386", "0.8660257");
    let l = Layout::from_json_str(&nudged).expect("valid");
    assert_eq!(l.segments[1].center, [0.5 * 3.0_f64.sqrt(), 0.0]);
    let moved = off.replace("0.8660254037844386", "0.8661");
    assert!(matches!(
        Layout::from_json_str(&moved),
        Err(LayoutError::InvalidHex { .. })
    ));
    let doc = off;
    let l = Layout::from_json_str(&doc).expect("valid");
    assert!(l.radius_of_curvature.is_infinite());
    assert_eq!(l.conic, 0.0);
    assert_eq!(l.n_edges(), 1);
}

fn segment(name: &str, x: f64, y: f64) -> Segment {
    Segment {
        name: name.into(),
        center: [x, y],
        hex: None,
    }
}

#[test]
fn error_cases() {
    let ok = || vec![segment("a", 0.0, 0.0), segment("b", 2.0, 0.0)];
    assert!(Layout::from_segments("ok", ok(), 1.0, 0.01, 30.0, -1.0).is_ok());

    // Empty list.
    let e = Layout::from_segments("none", vec![], 1.0, 0.01, 30.0, -1.0);
    assert!(matches!(e, Err(LayoutError::Empty { ref name }) if name == "none"));
    let doc = r#"{"name": "e", "circumradius": 1, "gap": 0, "segments": []}"#;
    assert!(matches!(
        Layout::from_json_str(doc),
        Err(LayoutError::Empty { .. })
    ));

    // Overlap: 1.5 m apart along x, flat-to-flat width sqrt(3) = 1.732 m.
    let e = Layout::from_segments(
        "overlap",
        vec![segment("a", 0.0, 0.0), segment("b", 1.5, 0.0)],
        1.0,
        0.01,
        30.0,
        0.0,
    );
    match e {
        Err(LayoutError::Overlap {
            i,
            j,
            first,
            second,
            ..
        }) => {
            assert_eq!((i, j), (0, 1));
            assert_eq!((first.as_str(), second.as_str()), ("a", "b"));
        }
        other => panic!("expected Overlap, got {other:?}"),
    }
    // 1.8 m apart at 30 degrees (towards a corner) still overlaps; same centre too.
    let c = rotate([1.8, 0.0], 30.0);
    let e = Layout::from_segments(
        "corner",
        vec![segment("a", 0.0, 0.0), segment("b", c[0], c[1])],
        1.0,
        0.0,
        30.0,
        0.0,
    );
    assert!(matches!(e, Err(LayoutError::Overlap { .. })));
    let e = Layout::from_segments(
        "same",
        vec![segment("a", 5.0, 5.0), segment("b", 5.0, 5.0)],
        1.0,
        0.0,
        30.0,
        0.0,
    );
    assert!(matches!(e, Err(LayoutError::Overlap { .. })));

    // Non-finite numbers.
    let e = Layout::from_segments(
        "nan",
        vec![segment("a", f64::NAN, 0.0)],
        1.0,
        0.0,
        30.0,
        0.0,
    );
    match e {
        Err(LayoutError::NonFinite { what, value }) => {
            assert!(what.contains("x of segment `a`"), "{what}");
            assert!(value.is_nan());
        }
        other => panic!("expected NonFinite, got {other:?}"),
    }
    for bad in [f64::NAN, f64::INFINITY] {
        assert!(matches!(
            Layout::from_segments("a", ok(), bad, 0.0, 30.0, 0.0),
            Err(LayoutError::NonFinite { .. })
        ));
        assert!(matches!(
            Layout::hexagonal("h", 3, 0, 1.0, bad, None),
            Err(LayoutError::NonFinite { .. })
        ));
        assert!(matches!(
            Layout::hexagonal("h", 3, 0, 1.0, 0.0, Some(bad)),
            Err(LayoutError::NonFinite { .. })
        ));
        assert!(matches!(
            Layout::from_segments("a", ok(), 1.0, 0.0, 30.0, bad),
            Err(LayoutError::NonFinite { .. })
        ));
    }
    assert!(matches!(
        Layout::from_segments("a", ok(), 1.0, 0.0, f64::NAN, 0.0),
        Err(LayoutError::NonFinite { .. })
    ));
    // JSON has no NaN, and numbers too large for f64 are refused by the parser.
    let doc = r#"{"name": "e", "circumradius": 1e400, "gap": 0,
                  "segments": [{"name": "a", "x": 0, "y": 0}]}"#;
    assert!(matches!(
        Layout::from_json_str(doc),
        Err(LayoutError::Json { .. })
    ));

    // Out-of-range values.
    for (a, gap, r) in [
        (0.0, 0.0, 30.0),
        (-1.0, 0.0, 30.0),
        (1.0, -0.1, 30.0),
        (1.0, 0.0, -5.0),
    ] {
        assert!(matches!(
            Layout::from_segments("a", ok(), a, gap, r, 0.0),
            Err(LayoutError::OutOfRange { .. })
        ));
    }

    // Duplicate and empty names.
    let e = Layout::from_segments(
        "dup",
        vec![
            segment("a", 0.0, 0.0),
            segment("b", 2.0, 0.0),
            segment("a", 4.0, 0.0),
        ],
        1.0,
        0.01,
        30.0,
        0.0,
    );
    match e {
        Err(LayoutError::DuplicateName {
            name,
            first,
            second,
        }) => assert_eq!((name.as_str(), first, second), ("a", 0, 2)),
        other => panic!("expected DuplicateName, got {other:?}"),
    }
    let e = Layout::from_segments(
        "blank",
        vec![segment("a", 0.0, 0.0), segment(" ", 2.0, 0.0)],
        1.0,
        0.01,
        30.0,
        0.0,
    );
    assert!(matches!(e, Err(LayoutError::EmptyName { index: 1 })));

    // Invalid cube coordinates.
    let mut bad_hex = ok();
    bad_hex[0].hex = Some([1, 1, 1]);
    assert!(matches!(
        Layout::from_segments("h", bad_hex, 1.0, 0.0, 30.0, 0.0),
        Err(LayoutError::InvalidHex { .. })
    ));

    // Hexagonal builder: rings, hole, radius cut leaving nothing.
    assert!(matches!(
        Layout::hexagonal("h", 2, 2, 1.0, 0.0, None),
        Err(LayoutError::InvalidRings {
            rings: 2,
            hole_rings: 2,
            ..
        })
    ));
    assert!(matches!(
        Layout::hexagonal("h", 5000, 0, 1.0, 0.0, None),
        Err(LayoutError::InvalidRings { .. })
    ));
    assert!(matches!(
        Layout::hexagonal("h", 3, 0, 1.0, 0.0, Some(0.5)),
        Err(LayoutError::Empty { .. })
    ));
    assert!(matches!(
        Layout::hexagonal("h", 3, 0, 1.0, 0.0, Some(-1.0)),
        Err(LayoutError::OutOfRange { .. })
    ));

    // Malformed JSON, missing and unknown fields.
    assert!(matches!(
        Layout::from_json_str("[1, 2"),
        Err(LayoutError::Json { path: None, .. })
    ));
    let missing = r#"{"name": "m", "gap": 0, "segments": [{"name": "a", "x": 0, "y": 0}]}"#;
    let e = Layout::from_json_str(missing).expect_err("circumradius missing");
    assert!(e.to_string().contains("circumradius"), "{e}");
    let typo = TRIANGLE.replace("\"conic\"", "\"konic\"");
    let e = Layout::from_json_str(&typo).expect_err("unknown field");
    assert!(e.to_string().contains("konic"), "{e}");
    let dup = TRIANGLE.replace("\"S3\"", "\"S1\"");
    assert!(matches!(
        Layout::from_json_str(&dup),
        Err(LayoutError::DuplicateName { .. })
    ));
}

#[test]
fn with_optics_validates() {
    let l = Layout::keck().with_optics(40.0, -1.0).expect("valid");
    assert_eq!((l.radius_of_curvature, l.conic), (40.0, -1.0));
    let flat = Layout::keck()
        .with_optics(f64::INFINITY, 0.0)
        .expect("flat");
    assert!(flat.radius_of_curvature.is_infinite());
    assert!(Layout::keck().with_optics(0.0, 0.0).is_err());
    assert!(Layout::keck().with_optics(30.0, f64::NAN).is_err());
}

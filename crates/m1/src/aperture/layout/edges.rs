//! Geometric search for shared edges and overlapping segments.
//!
//! Both searches look only at nearby pairs of centres, found by bucketing the centres on a
//! square grid whose cell is at least the search radius, so their cost grows linearly with the
//! number of segments.

use std::collections::HashMap;

use super::{EDGE_TOLERANCE, Edge, LayoutError, OVERLAP_TOLERANCE, Segment};

/// All pairs `(i, j, distance)`, `i < j`, of centres at most `radius` apart, sorted by `(i, j)`.
/// The centres must be finite and `radius` positive.
fn close_pairs(centers: &[[f64; 2]], radius: f64) -> Vec<(usize, usize, f64)> {
    let cell_of = |c: [f64; 2]| -> (i64, i64) {
        // Float-to-int `as` saturates; finite centres of any real mirror are far from the limits.
        (
            (c[0] / radius).floor() as i64,
            (c[1] / radius).floor() as i64,
        )
    };
    let mut buckets: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (i, &c) in centers.iter().enumerate() {
        buckets.entry(cell_of(c)).or_default().push(i);
    }
    let mut pairs = Vec::new();
    for (i, &ci) in centers.iter().enumerate() {
        let (cx, cy) = cell_of(ci);
        for dx in -1..=1 {
            for dy in -1..=1 {
                let key = (cx.saturating_add(dx), cy.saturating_add(dy));
                let Some(bucket) = buckets.get(&key) else {
                    continue;
                };
                for &j in bucket {
                    if j <= i {
                        continue;
                    }
                    let cj = centers[j];
                    let d = (cj[0] - ci[0]).hypot(cj[1] - ci[1]);
                    if d <= radius {
                        pairs.push((i, j, d));
                    }
                }
            }
        }
    }
    pairs.sort_by_key(|&(i, j, _)| (i, j));
    pairs
}

/// Shared edges: pairs whose centre distance is within [`EDGE_TOLERANCE`] (relative) of
/// `pitch`, sorted by `(i, j)`, with the unit normal from `i` towards `j`.
pub(crate) fn find_edges(centers: &[[f64; 2]], pitch: f64) -> Vec<Edge> {
    let radius = pitch * (1.0 + EDGE_TOLERANCE);
    close_pairs(centers, radius)
        .into_iter()
        .filter(|&(_, _, d)| (d - pitch).abs() <= EDGE_TOLERANCE * pitch)
        .map(|(i, j, d)| {
            let (ci, cj) = (centers[i], centers[j]);
            Edge {
                i,
                j,
                normal: [(cj[0] - ci[0]) / d, (cj[1] - ci[1]) / d],
            }
        })
        .collect()
}

/// Largest projection of `d` on the three edge-normal directions of the segments (0, 60 and
/// 120 degrees from +x). Two segments of circumradius `a` overlap exactly when this is less
/// than their flat-to-flat width `sqrt(3) a`.
fn edge_normal_separation(d: [f64; 2]) -> f64 {
    let h = 0.75_f64.sqrt();
    let p0 = d[0].abs();
    let p60 = (0.5 * d[0] + h * d[1]).abs();
    let p120 = (-0.5 * d[0] + h * d[1]).abs();
    p0.max(p60).max(p120)
}

/// Fails with [`LayoutError::Overlap`] on the first pair (in `(i, j)` order) of segments of
/// circumradius `circumradius` that overlap by more than [`OVERLAP_TOLERANCE`] of their
/// flat-to-flat width.
pub(crate) fn check_overlaps(segments: &[Segment], circumradius: f64) -> Result<(), LayoutError> {
    let width = 3.0_f64.sqrt() * circumradius;
    let limit = width * (1.0 - OVERLAP_TOLERANCE);
    let centers: Vec<[f64; 2]> = segments.iter().map(|s| s.center).collect();
    // Overlapping hexagons have centres closer than 2 a (the circumradius of their Minkowski sum).
    for (i, j, distance) in close_pairs(&centers, 2.0 * circumradius) {
        let d = [centers[j][0] - centers[i][0], centers[j][1] - centers[i][1]];
        let separation = edge_normal_separation(d);
        if separation < limit {
            return Err(LayoutError::Overlap {
                i,
                j,
                first: segments[i].name.clone(),
                second: segments[j].name.clone(),
                distance,
                separation,
                width,
            });
        }
    }
    Ok(())
}

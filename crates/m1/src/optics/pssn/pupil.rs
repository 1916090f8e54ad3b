//! The sampled pupil: which grid sample belongs to which segment.

use super::*;

/// The segmented pupil sampled on a square grid of `N x N` points.
///
/// The grid spans the bounding square of the hexagon corners, `[-h, h]^2` with
/// `h = max(|x|, |y|)` over all corners, cut into `N x N` cells of side `dx = 2 h / N`; sample
/// `(ix, iy)` sits at the cell centre `(x0 + ix dx, x0 + iy dx)`, `x0 = -h + dx / 2`, and has
/// the flat index `iy N + ix` (rows along `x`). A sample belongs to segment `i` when it lies in
/// the hexagon's 6 half-planes (circumradius `a`; samples in the gaps belong to none; on a
/// shared boundary, the lower segment index wins).
#[derive(Debug, Clone, PartialEq)]
pub struct PupilGrid {
    pub(super) samples: usize,
    pub(super) spacing: f64,
    pub(super) origin: f64,
    pub(super) centers: Vec<[f64; 2]>,
    pub(super) segment: Vec<Option<u32>>,
    pub(super) n_inside: usize,
}

impl PupilGrid {
    /// Default number of samples across the aperture.
    pub const DEFAULT_SAMPLES: usize = 256;

    /// Samples the pupil of `layout` with `samples` points across (at least 2).
    pub fn new(layout: &Layout, samples: usize) -> Result<PupilGrid, M1Error> {
        if samples < 2 {
            return Err(M1Error::InvalidParameter {
                name: "samples",
                value: samples as f64,
                reason: "need at least 2 samples across the pupil",
            });
        }
        if layout.n_segments() >= u32::MAX as usize {
            return Err(M1Error::InvalidParameter {
                name: "n_segments",
                value: layout.n_segments() as f64,
                reason: "too many segments",
            });
        }
        let a = layout.circumradius;
        let half = (0..layout.n_segments())
            .filter_map(|i| layout.vertices(i))
            .flatten()
            .map(|v| v[0].abs().max(v[1].abs()))
            .fold(0.0, f64::max);
        let dx = 2.0 * half / samples as f64;
        let origin = -half + 0.5 * dx;
        let apothem = 0.5 * 3.0_f64.sqrt() * a;
        let normals: [[f64; 2]; 3] = std::array::from_fn(|k| {
            let t = (60.0 * k as f64).to_radians();
            [t.cos(), t.sin()]
        });
        let index_range = |c: f64| {
            let lo = ((c - a - origin) / dx).ceil().max(0.0) as usize;
            let hi = (((c + a - origin) / dx).floor().max(-1.0) + 1.0) as usize;
            lo..hi.min(samples)
        };
        let mut segment = vec![None; samples * samples];
        let mut n_inside = 0;
        for (i, s) in layout.segments.iter().enumerate() {
            let [cx, cy] = s.center;
            for iy in index_range(cy) {
                let ry = origin + iy as f64 * dx - cy;
                for ix in index_range(cx) {
                    let rx = origin + ix as f64 * dx - cx;
                    let inside = normals
                        .iter()
                        .all(|n| (rx * n[0] + ry * n[1]).abs() <= apothem);
                    let slot = &mut segment[iy * samples + ix];
                    if inside && slot.is_none() {
                        *slot = Some(i as u32);
                        n_inside += 1;
                    }
                }
            }
        }
        Ok(PupilGrid {
            samples,
            spacing: dx,
            origin,
            centers: layout.segments.iter().map(|s| s.center).collect(),
            segment,
            n_inside,
        })
    }

    /// Samples across, `N`.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// Sample spacing `dx` (m).
    pub fn spacing(&self) -> f64 {
        self.spacing
    }

    /// Coordinate (m) of sample column (or row) `k`: `x0 + k dx`.
    pub fn coordinate(&self, k: usize) -> f64 {
        self.origin + k as f64 * self.spacing
    }

    /// Number of segments of the layout.
    pub fn n_segments(&self) -> usize {
        self.centers.len()
    }

    /// Number of samples inside the segments.
    pub fn n_inside(&self) -> usize {
        self.n_inside
    }

    /// Segment of every sample (flat index `iy N + ix`), `None` outside the segments.
    pub fn segment_map(&self) -> &[Option<u32>] {
        &self.segment
    }

    /// Segment of sample `(ix, iy)`, if any.
    pub fn segment_at(&self, ix: usize, iy: usize) -> Option<usize> {
        if ix >= self.samples || iy >= self.samples {
            return None;
        }
        self.segment[iy * self.samples + ix].map(|i| i as usize)
    }

    /// Pupil mask (flat index `iy N + ix`).
    pub fn mask(&self) -> Vec<bool> {
        self.segment.iter().map(Option::is_some).collect()
    }

    /// Surface (m) on the grid of the segment state `ptt` (`[p, tx, ty]` per segment, see
    /// [`crate::aperture::zernike`]), zero outside the segments.
    pub fn surface_from_ptt(&self, ptt: &[[f64; 3]]) -> Result<Vec<f64>, M1Error> {
        check_ptt(ptt, self.n_segments())?;
        let n = self.samples;
        Ok(self
            .segment
            .iter()
            .enumerate()
            .map(|(flat, seg)| match seg {
                Some(i) => {
                    let i = *i as usize;
                    let [p, tx, ty] = ptt[i];
                    let x = self.coordinate(flat % n) - self.centers[i][0];
                    let y = self.coordinate(flat / n) - self.centers[i][1];
                    p + tx * x + ty * y
                }
                None => 0.0,
            })
            .collect())
    }
}

pub(super) fn check_ptt(ptt: &[[f64; 3]], n: usize) -> Result<(), M1Error> {
    if ptt.len() == n {
        Ok(())
    } else {
        Err(M1Error::SizeMismatch {
            what: "segment piston/tip/tilt",
            expected: n,
            found: ptt.len(),
        })
    }
}

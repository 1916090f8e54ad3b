//! The mirror figures of `m1cs run`: the surface spectrum and the per-segment rms map.

use super::*;

/// Removes the recorded mirror displacement columns (`<component>.z[k]`) from `r` and returns
/// them as time series (one per actuator, settled second half of the run).
pub(crate) fn split_off_z(r: &mut cosim::system::Results) -> Vec<Vec<f64>> {
    let is_z = |c: &str| c.starts_with("mirror.z[") || c.starts_with("segments.z[");
    let keep: Vec<usize> = (0..r.columns.len())
        .filter(|&k| !is_z(&r.columns[k]))
        .collect();
    let zc: Vec<usize> = (0..r.columns.len())
        .filter(|&k| is_z(&r.columns[k]))
        .collect();
    let half = r.n_rows() / 2;
    let z: Vec<Vec<f64>> = zc
        .iter()
        .map(|&k| r.rows().skip(half).map(|row| row[k]).collect())
        .collect();
    r.keep_columns(&keep);
    z
}

/// Amplitude spectrum of the mirror displacement, power-averaged over the actuators (nm).
pub(super) fn mirror_spectrum(z: &[Vec<f64>], dt: f64) -> Vec<(f64, f64)> {
    let signals: Vec<&[f64]> = z.iter().map(Vec::as_slice).collect();
    m1::optics::metrics::amplitude_spectrum(&signals, dt)
        .into_iter()
        .map(|(f, a)| (f, a * 1e9))
        .collect()
}

/// rms over time of the residual surface of each segment (global piston, tip and tilt removed),
/// in nm, from actuator time series.
pub(crate) fn segment_rms_map(
    layout: &m1::aperture::layout::Layout,
    z: &[Vec<f64>],
) -> Result<Vec<f64>, String> {
    use m1::aperture::geometry::{Geometry, GeometryParams};
    use m1::optics::metrics::{MirrorMetrics, hexagon_area, hexagon_second_moment};
    let g = Geometry::new(layout, GeometryParams::for_layout(layout)).map_err(|e| e.to_string())?;
    let m = MirrorMetrics::new(&g).map_err(|e| e.to_string())?;
    let n = layout.n_segments();
    let a = layout.circumradius;
    let slope_weight = hexagon_second_moment(a) / hexagon_area(a);
    let samples = z.first().map_or(0, Vec::len);
    let mut acc = vec![0.0; n];
    let mut state = vec![0.0; 3 * n];
    let mut ptt = vec![[0.0; 3]; n];
    for k in 0..samples {
        for (s, col) in state.iter_mut().zip(z) {
            *s = col[k];
        }
        m.residual_ptt(&state, &mut ptt)
            .map_err(|e| e.to_string())?;
        for (acc, [p, tx, ty]) in acc.iter_mut().zip(&ptt) {
            *acc += p * p + (tx * tx + ty * ty) * slope_weight;
        }
    }
    Ok(acc
        .iter()
        .map(|s| (s / samples.max(1) as f64).sqrt() * 1e9)
        .collect())
}

/// The M1 maps (one per run) and the overlaid amplitude spectra.
pub(super) fn draw_z_plots(
    a: &RunCmd,
    maps: &[(String, Vec<Vec<f64>>)],
    spectra: &[(String, Vec<(f64, f64)>)],
) -> Result<(), String> {
    for (label, z) in maps {
        // The layout of the recorded mirror: the one asked for, else the preset of that size
        // (a user's .ssp).
        let Some(layout) = std::iter::once(a.system.layout.as_str())
            .chain(m1::aperture::layout::Layout::PRESETS.iter().copied())
            .filter_map(|name| m1::aperture::layout::Layout::preset(name).ok())
            .find(|l| l.n_actuators() == z.len())
        else {
            continue;
        };
        let rms = segment_rms_map(&layout, z)?;
        plot::mirror_map(
            a.out.join(format!("map_{}.png", label.replace(' ', "_"))),
            &layout,
            &rms,
            &format!(
                "{}, {label}: rms residual surface per segment (second half)",
                layout.name
            ),
            "nm",
        )
        .map_err(|e| e.to_string())?;
    }
    let series: Vec<(&str, &[(f64, f64)])> = spectra
        .iter()
        .filter(|(_, s)| !s.is_empty())
        .map(|(l, s)| (l.as_str(), s.as_slice()))
        .collect();
    if !series.is_empty() {
        plot::lines(
            a.out.join("spectrum.png"),
            &series,
            &format!(
                "{}: amplitude spectrum of the mirror displacement (actuator mean)",
                if a.ssp.is_some() {
                    "system"
                } else {
                    a.system.layout.as_str()
                }
            ),
            "frequency (Hz)",
            "amplitude (nm)",
            true,
            true,
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

//! The optics metrics and PSSN per evaluation, on Keck and TMT (the figures the optics FMU's
//! documentation quotes): `MirrorMetrics::evaluate` on a fixed pseudo-random surface, and
//! `Pssn::pssn_ptt` of its residual segment states at 128, 256 (the default) and 512 samples
//! across the pupil, in double precision and with the transforms in single precision (the
//! optics FMU's default, `PssnPrecision::Single`), the OTF by each `OtfMethod` (the correlation
//! of the row spectra, the 2-D transforms), side by side. Set-up is outside the timings.
//!
//! `cargo bench -p m1 --bench optics`
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};

use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::optics::metrics::MirrorMetrics;
use m1::optics::pssn::{OtfMethod, Pssn, PssnParams, PssnPrecision};

/// A deterministic surface of about `scale` (m) at every actuator.
fn surface(n: usize, scale: f64) -> Vec<f64> {
    let mut s = 3u64;
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            scale * (((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    for name in ["keck", "tmt"] {
        let layout = Layout::preset(name).unwrap();
        let g = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
        let m = MirrorMetrics::new(&g).unwrap();
        let z = surface(g.n_actuators(), 20e-9);
        let mut group = c.benchmark_group(format!("{name}_optics"));
        group.bench_function("metrics", |b| {
            b.iter(|| black_box(m.evaluate(black_box(&z)).unwrap().rms))
        });
        let mut ptt = vec![[0.0; 3]; m.n_segments()];
        m.residual_ptt(&z, &mut ptt).unwrap();
        group.sample_size(20);
        for samples in [128, 256, 512] {
            for (precision, label) in [
                (PssnPrecision::Double, "double"),
                (PssnPrecision::Single, "single"),
            ] {
                let params = PssnParams {
                    samples,
                    ..PssnParams::default()
                };
                for (method, how) in [
                    (OtfMethod::Correlation, "correlation"),
                    (OtfMethod::Transforms, "transforms"),
                ] {
                    let pssn = Pssn::with_method(&layout, params, precision, Some(method)).unwrap();
                    let id = format!(
                        "pssn/{samples}_samples/{label}/{how}_{}_lag_rows",
                        pssn.otf_lag_rows()
                    );
                    group.bench_function(id, |b| {
                        b.iter(|| black_box(pssn.pssn_ptt(black_box(&ptt)).unwrap()))
                    });
                }
            }
        }
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);

//! The global loop's set-up and per-sample costs on Keck, TMT and the ELT: the controller's
//! modes and reconstructor (`ControlModes::new`), one controller sample, the edge sensors with
//! installation errors (`EdgeSensors::new`) and one noisy reading.
//!
//! `cargo bench -p m1 --bench control`
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};

use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::{ControlModes, ControllerParams};
use m1::sensing::sensors::{EdgeSensors, SensorErrors};

fn bench(c: &mut Criterion) {
    for name in ["keck", "tmt", "elt"] {
        let layout = Layout::preset(name).unwrap();
        let g = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
        let errors = SensorErrors {
            noise_rms: 5e-9,
            gain_rms: 1e-3,
            position_rms: 1e-4,
            tilt_rms: 1e-4,
            ..Default::default()
        };
        let mut group = c.benchmark_group(format!("{name}_control"));
        group.sample_size(10);
        group.bench_function("controller_setup", |b| {
            b.iter(|| black_box(ControlModes::new(g.clone()).unwrap().shape()))
        });
        group.bench_function("sensors_setup", |b| {
            b.iter(|| black_box(EdgeSensors::new(&g, &errors).unwrap()))
        });
        let m = ControlModes::new(g.clone()).unwrap();
        let s = EdgeSensors::new(&g, &errors).unwrap();
        let (na, ns) = m.shape();
        let gains = ControllerParams::default().gains().unwrap();
        let mut scratch = m.scratch();
        let y: Vec<f64> = (0..ns).map(|i| 1e-9 * (i as f64).sin()).collect();
        let y_ref = vec![0.0; ns];
        let mut u = vec![0.0; na];
        group.sample_size(50);
        group.bench_function("controller_sample", |b| {
            b.iter(|| {
                m.sample(&gains, &mut u, black_box(&y), &y_ref, &mut scratch)
                    .unwrap();
                black_box(u[0])
            })
        });
        let (mut yy, mut gap) = (vec![0.0; ns], vec![0.0; ns]);
        let z: Vec<f64> = (0..na).map(|i| 1e-7 * (i as f64).cos()).collect();
        let mut k = 0u64;
        group.bench_function("sensors_read", |b| {
            b.iter(|| {
                k += 1;
                s.read_into(black_box(&z), &z, k, &mut yy, &mut gap)
                    .unwrap();
                black_box(yy[0])
            })
        });
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);

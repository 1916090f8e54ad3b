//! Wall time of the segments FMU model for one second of simulated time, in process (no C API).
//!
//! Each benchmark iteration is what a co-simulation master does for 1 s of simulated time: for
//! every communication step it copies the three input arrays (`u_cmd`, `z_cell`, `f_wind`) from
//! its own buffers into the value store, calls `do_step`, then copies both output arrays (`z`,
//! `f_cell`) out. The inputs change every step (small sinusoids with a different amplitude per
//! actuator). Single-threaded.
//!
//! Cases per layout (group `segments_<layout>`):
//! - `<variant>/1ms_x1000`: 1 ms communication step, 1000 calls (the requirement's case);
//! - `<variant>/0.2ms_x5000`: one servo period per call, 5000 calls (per-call overhead);
//! - `voicecoil/0.5ms_x2000_misaligned` (tmt only): a step that is not a whole number of servo
//!   periods, so calls also finish or start a cut period;
//! - `voicecoil/io_only_1ms_x1000`: the master-side input generation and copies alone, no
//!   `do_step` (what the first case spends outside the model).
//!
//! Run: `cargo bench -p segments` (or `cargo bench -p segments -- tmt` for one layout).

#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use std::f64::consts::TAU;
use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use fmu::{Model, Running, Values};

/// One model instance and a master's buffers around it.
struct Rig<M: Model> {
    model: M::Running,
    values: Values,
    /// (slot, len) of u_cmd, z_cell, f_wind.
    inputs: [(usize, usize); 3],
    /// (slot, len) of z, f_cell.
    outputs: [(usize, usize); 2],
    /// Per-actuator amplitude of each input.
    amp: [Vec<f64>; 3],
    /// The master's input buffers, refilled every step.
    buf: [Vec<f64>; 3],
    /// The master's output buffers.
    out: [Vec<f64>; 2],
    t: f64,
}

impl<M: Model> Rig<M> {
    fn new(layout: &str) -> Self {
        let (table, model) = M::new(layout).expect("model");
        let mut values = table.initial_values();
        let model = model.initialize(&mut values, 0.0).expect("initialize");
        let slot = |name: &str| {
            let v = table.by_name(name).expect(name);
            (v.slot, v.len)
        };
        let inputs = [slot("u_cmd"), slot("z_cell"), slot("f_wind")];
        let outputs = [slot("z"), slot("f_cell")];
        let na = inputs[0].1;
        // u_cmd ~ 0.1 um, z_cell ~ 10 nm, f_wind ~ 1 N, varying across the actuators.
        let scale = [1e-7, 1e-8, 1.0];
        let amp = scale.map(|s| (0..na).map(|i| s * (1.0 + (i % 7) as f64 / 7.0)).collect());
        Self {
            model,
            values,
            inputs,
            outputs,
            amp,
            buf: [vec![0.0; na], vec![0.0; na], vec![0.0; na]],
            out: [vec![0.0; na], vec![0.0; na]],
            t: 0.0,
        }
    }

    /// The master's side of one step: new inputs into its buffers and the store.
    #[inline]
    fn write_inputs(&mut self) {
        // 10 Hz command, 3 Hz cell motion, 1 Hz wind.
        let s = [
            (TAU * 10.0 * self.t).sin(),
            (TAU * 3.0 * self.t).sin(),
            (TAU * self.t).sin(),
        ];
        for (k, sk) in s.into_iter().enumerate() {
            for (b, a) in self.buf[k].iter_mut().zip(&self.amp[k]) {
                *b = a * sk;
            }
            let (slot, len) = self.inputs[k];
            self.values.reals[slot..slot + len].copy_from_slice(&self.buf[k]);
        }
    }

    /// The master's side after a step: copy the outputs out.
    #[inline]
    fn read_outputs(&mut self) {
        for k in 0..2 {
            let (slot, len) = self.outputs[k];
            self.out[k].copy_from_slice(&self.values.reals[slot..slot + len]);
        }
        black_box(&self.out);
    }

    /// `n` communication steps of `h` seconds with the inputs and outputs exchanged.
    fn run(&mut self, n: usize, h: f64) {
        for _ in 0..n {
            self.write_inputs();
            self.model
                .do_step(self.t, h, &mut self.values)
                .expect("do_step");
            self.t += h;
            self.read_outputs();
        }
    }

    /// The exchanges of `run` without the model.
    fn io_only(&mut self, n: usize, h: f64) {
        for _ in 0..n {
            self.write_inputs();
            black_box(&mut self.values);
            self.t += h;
            self.read_outputs();
        }
    }
}

/// (label, communication step, calls per simulated second).
const STEPS: [(&str, f64, usize); 2] = [("1ms_x1000", 1e-3, 1000), ("0.2ms_x5000", 2e-4, 5000)];

fn layout_group(c: &mut Criterion, layout: &str) {
    let mut g = c.benchmark_group(format!("segments_{layout}"));
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5))
        .sampling_mode(SamplingMode::Flat);
    for (label, h, n) in STEPS {
        g.throughput(Throughput::Elements(n as u64));
        let mut vc = Rig::<segments::VoiceCoil>::new(layout);
        g.bench_function(format!("voicecoil/{label}"), |b| b.iter(|| vc.run(n, h)));
        let mut pz = Rig::<segments::Piezo>::new(layout);
        g.bench_function(format!("piezo/{label}"), |b| b.iter(|| pz.run(n, h)));
    }
    if layout == "tmt" {
        // 0.5 ms is 2.5 servo periods: every call also cuts a period (two matrix exponentials
        // and up to three passes over the state).
        g.throughput(Throughput::Elements(2000));
        let mut vc = Rig::<segments::VoiceCoil>::new(layout);
        g.bench_function("voicecoil/0.5ms_x2000_misaligned", |b| {
            b.iter(|| vc.run(2000, 5e-4))
        });
    }
    g.throughput(Throughput::Elements(1000));
    let mut io = Rig::<segments::VoiceCoil>::new(layout);
    g.bench_function("voicecoil/io_only_1ms_x1000", |b| {
        b.iter(|| io.io_only(1000, 1e-3))
    });
    g.finish();
}

fn benches(c: &mut Criterion) {
    for layout in ["keck", "tmt", "elt"] {
        layout_group(c, layout);
    }
}

criterion_group!(step, benches);
criterion_main!(step);

//! Many instances in one process: no shared state between them (values, model, time, logger).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use fmu::VariableTable;

/// The parameters and input signal of one run.
#[derive(Debug, Clone, Copy)]
struct Setup {
    tau: f64,
    gain: f64,
    amplitude: f64,
    frequency: f64,
}

const SETUPS: [Setup; 3] = [
    Setup {
        tau: 0.5,
        gain: 2.0,
        amplitude: 1.0,
        frequency: 1.0,
    },
    Setup {
        tau: 0.05,
        gain: -1.0,
        amplitude: 3.0,
        frequency: 2.5,
    },
    Setup {
        tau: 2.0,
        gain: 0.5,
        amplitude: -0.5,
        frequency: 0.3,
    },
];

const H: f64 = 0.01;
const STEPS: usize = 200;

fn input(s: Setup, n: usize, k: usize) -> Vec<f64> {
    let t = k as f64 * H;
    (0..n)
        .map(|i| s.amplitude * (std::f64::consts::TAU * s.frequency * t + i as f64).sin())
        .collect()
}

/// Instantiated, parameters set, initialised.
fn start(name: &str, t: &VariableTable, guid: &str, s: Setup) -> Fmu {
    let mut fmu = instantiate(name, guid, None, false).unwrap();
    assert_eq!(fmu.setup(0.0, None), OK);
    assert_eq!(fmu.enter_init(), OK);
    assert_eq!(
        fmu.set_real(&[vr(t, "tau", 0), vr(t, "gain", 0)], &[s.tau, s.gain]),
        OK
    );
    assert_eq!(fmu.exit_init(), OK, "{}", fmu.log.dump());
    fmu
}

/// One step: set the input, step, read every Real output and the step count.
fn advance(fmu: &mut Fmu, t: &VariableTable, s: Setup, k: usize) -> (Vec<f64>, i32) {
    let n = t.by_name("u").unwrap().len;
    assert_eq!(fmu.set_real(&vrs(t, "u"), &input(s, n, k)), OK);
    assert_eq!(fmu.step(k as f64 * H, H), OK, "{}", fmu.log.dump());
    let mut out = fmu.get_reals_of(t, "y");
    out.extend(fmu.get_reals_of(t, "yd"));
    out.extend(fmu.get_reals_of(t, "total"));
    let steps = fmu.get_integer(&[vr(t, "steps", 0)]).unwrap()[0];
    (out, steps)
}

fn solo(variant: &str, s: Setup) -> Vec<Vec<f64>> {
    let d = describe(variant);
    let mut fmu = start("solo", &d.table, &d.guid, s);
    (0..STEPS)
        .map(|k| {
            let (out, steps) = advance(&mut fmu, &d.table, s, k);
            assert_eq!(steps, k as i32 + 1);
            out
        })
        .collect()
}

#[test]
fn interleaved_instances_match_solo_runs() {
    let d = describe("small");
    let mut fmus: Vec<Fmu> = SETUPS
        .iter()
        .enumerate()
        .map(|(i, s)| start(&format!("i{i}"), &d.table, &d.guid, *s))
        .collect();
    let mut traces: Vec<Vec<Vec<f64>>> = vec![Vec::new(); SETUPS.len()];
    for k in 0..STEPS {
        // Vary the order in which the instances are stepped.
        let order: Vec<usize> = match k % 3 {
            0 => vec![0, 1, 2],
            1 => vec![2, 0, 1],
            _ => vec![1, 2, 0],
        };
        for i in order {
            let (out, steps) = advance(&mut fmus[i], &d.table, SETUPS[i], k);
            assert_eq!(steps, k as i32 + 1);
            traces[i].push(out);
        }
    }
    for (i, s) in SETUPS.iter().enumerate() {
        assert_eq!(traces[i], solo("small", *s), "instance {i}");
        assert_eq!(fmus[i].last_time(), STEPS as f64 * H);
    }
    // The runs differ, so the comparison above can tell instances apart.
    assert_ne!(traces[0], traces[1]);
    assert_ne!(traces[1], traces[2]);
    assert_ne!(traces[0], traces[2]);
}

/// Instances of different variants side by side.
#[test]
fn variants_side_by_side() {
    let small = describe("small");
    let big = describe("big");
    let mut a = start("a", &small.table, &small.guid, SETUPS[0]);
    let mut b = start("b", &big.table, &big.guid, SETUPS[0]);
    for k in 0..50 {
        let (oa, _) = advance(&mut a, &small.table, SETUPS[0], k);
        let (ob, _) = advance(&mut b, &big.table, SETUPS[0], k);
        // Same parameters and (per element) the same input: the first three elements agree.
        assert_eq!(oa[..3], ob[..3], "y at step {k}");
        assert_eq!(oa[3..6], ob[5..8], "yd at step {k}");
        assert_eq!(oa.len(), 3 + 3 + 1);
        assert_eq!(ob.len(), 5 + 5 + 1);
    }
}

/// Instances on threads, concurrently, give the same results as the sequential runs.
#[test]
fn concurrent_instances_match_solo_runs() {
    let expected: Vec<Vec<Vec<f64>>> = SETUPS.iter().map(|s| solo("big", *s)).collect();
    let handles: Vec<_> = (0..12)
        .map(|j| {
            std::thread::spawn(move || {
                let s = SETUPS[j % SETUPS.len()];
                (j, solo("big", s))
            })
        })
        .collect();
    for h in handles {
        let (j, trace) = h.join().unwrap();
        assert_eq!(trace, expected[j % SETUPS.len()], "thread {j}");
    }
}

/// Messages go to the logger (and environment) of the instance concerned, with its name.
#[test]
fn each_instance_logs_to_its_own_logger() {
    let d = describe("small");
    let mut a = start("alpha", &d.table, &d.guid, SETUPS[0]);
    let mut b = start("beta", &d.table, &d.guid, SETUPS[1]);
    assert_eq!(b.set_real(&[vr(&d.table, "tau", 0)], &[1.0]), ERROR);
    assert!(a.log.entries().is_empty(), "{}", a.log.dump());
    let e = b.log.entries();
    assert_eq!(e.len(), 1);
    assert_eq!(e[0].instance, "beta");
    assert!(e[0].message.contains("tau"), "{}", e[0].message);
    // A failure of one instance leaves the other stepping.
    assert_eq!(a.step(0.0, H), OK);
    assert_eq!(b.step(0.5, H), ERROR, "time mismatch");
    assert_eq!(a.step(H, H), OK);
    assert_eq!(a.get_integer(&[vr(&d.table, "steps", 0)]).unwrap(), [2]);
    assert_eq!(b.get_integer(&[vr(&d.table, "steps", 0)]).unwrap(), [0]);
    assert!(a.log.entries().is_empty());
}

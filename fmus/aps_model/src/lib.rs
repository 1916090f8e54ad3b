//! Model wiring of the `aps` FMU: the Alignment and Phasing System, which every few weeks
//! measures the piston, tip and tilt of every segment optically and resets the desired
//! edge-sensor readings so that the measured error is removed ([`m1::control::aps::Aps`]).
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `z` | input | na | m |
//! | `y_ref` | output, no direct dependency | ns | m |
//! | `runs` | output, no direct dependency | 1 | count |
//!
//! with na = 3 x the number of segments (actuator k of segment i at index 3 i + k) and ns the
//! number of edge sensors of the packaged layout.
//!
//! # Runs
//!
//! Run k takes place at `t_k = first_run + k interval` (`k >= 0`, instants before the start
//! time are skipped). A run instant at the start time runs at initialisation, on the inputs set
//! during initialisation; one in the communication step `(t, t + h]` (to `1e-9 max(1, |t + h|)`
//! s) runs on the inputs held over the step and shows from `t + h` on. A run measures the
//! segment error `e` (the true positions `z` plus the seeded measurement error of run k, global
//! piston/tip/tilt removed, [`Aps::measure`]) and sets `y_ref <- y_ref - A_0 e`
//! ([`Aps::reset_reference`]); `y_ref` starts at 0 and is held between runs (a discrete
//! output: no direct dependency on `z`, no algebraic loop). When a step holds several run
//! instants (a step longer than `interval`) only the last one runs: the mirror cannot respond
//! in between, so repeating the measurement would remove the same error twice. `runs` counts
//! the runs so far.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use fmu::{
    Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T, Values,
    VariableTable,
};
use m1::analysis::quasistatic::default_geometry;
use m1::aperture::layout::Layout;
use m1::control::aps::{Aps, ApsParams};
use m1::control::controller::TIME_TOLERANCE;
use m1::control::nominal::Nominal;
use wiring::signals::{Y_REF, Z, layout_decl, n_segments_decl, n_sensors_decl};

/// Seconds per day.
const DAY: f64 = 86400.0;

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        n_sensors: IntVar = n_sensors_decl(layout),
        z: RealVar = Z.input(layout),
        y_ref: RealVar = Y_REF.output(layout).discrete().depends(Dependencies::None),
        runs: IntVar = T::integer("runs").output().describe("Number of APS runs so far"),
        interval: RealVar = T::real("interval").parameter().unit("s")
            .start(ApsParams::default().interval_days * DAY).positive()
            .describe("Time between APS runs (default 14 days; TMT plans every 2-4 weeks)"),
        first_run: RealVar = T::real("first_run").parameter().unit("s").start(0.0)
            .describe("Time of the first APS run (at the start time: a run at initialisation)"),
        piston_rms: RealVar = T::real("piston_rms").parameter().unit("m")
            .start(ApsParams::default().piston_rms).non_negative()
            .describe("rms error of each measured segment piston (assumed)"),
        tilt_rms: RealVar = T::real("tilt_rms").parameter().unit("rad")
            .start(ApsParams::default().tilt_rms).non_negative()
            .describe("rms error of each measured segment tilt, per axis (assumed)"),
        seed: IntVar = T::integer("seed").parameter()
            .start_int(i32::try_from(ApsParams::default().seed).unwrap_or(1)).non_negative()
            .describe("Seed of the measurement errors (run k draws from (seed, k))"),
    }
}

const DOC: &str = "<h2>Model</h2>\
<p>The Alignment and Phasing System measures the piston, tip and tilt of every segment \
optically and resets the desired edge-sensor readings so that the loop removes the measured \
error. Run k takes place at t<sub>k</sub> = <code>first_run</code> + k <code>interval</code> \
(default every 14 days from the start time; instants before the start time are skipped). It \
measures e, the true segment positions <code>z</code> at the actuators plus a measurement \
error (per segment N(0, <code>piston_rms</code>) in piston and N(0, <code>tilt_rms</code>) in \
each tilt, drawn from (<code>seed</code>, k)), with global piston, tip and tilt removed (the \
APS measures the segments relative to each other), and sets \
<code>y_ref</code> &larr; <code>y_ref</code> &minus; A<sub>0</sub> e with A<sub>0</sub> the \
nominal A-matrix. <code>y_ref</code> starts at 0 and is held between runs.</p>\
<p><b>Timing</b>: a run at the start time runs at initialisation on the inputs set then; a run \
instant in the communication step (t, t + h] runs on the inputs held over the step and shows \
from t + h on, so <code>y_ref</code> never depends directly on <code>z</code> (no algebraic \
loop). A step that holds several run instants runs only the last one (the mirror cannot \
respond in between). <code>runs</code> counts the runs so far.</p>";

/// The run instants `first + k interval`, `k >= 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Schedule {
    first: f64,
    interval: f64,
}

impl Schedule {
    /// The instant of run `k` (s).
    fn instant(&self, k: u64) -> f64 {
        self.first + k as f64 * self.interval
    }

    fn tolerance(t: f64) -> f64 {
        TIME_TOLERANCE * t.abs().max(1.0)
    }

    /// The latest run at or before `t` (within the tolerance); `None` before the first.
    fn latest_at(&self, t: f64) -> Option<u64> {
        let limit = t + Self::tolerance(t);
        if self.instant(0) > limit {
            return None;
        }
        let x = ((limit - self.first) / self.interval).floor();
        // A saturating conversion; the loops below correct the rounding.
        let mut k = if x.is_finite() && x > 0.0 {
            x as u64
        } else {
            0
        };
        while k > 0 && self.instant(k) > limit {
            k -= 1;
        }
        while k < u64::MAX && self.instant(k + 1) <= limit {
            k += 1;
        }
        Some(k)
    }

    /// Whether run `k` takes place at `t` (within the tolerance).
    fn is_at(&self, k: u64, t: f64) -> bool {
        (self.instant(k) - t).abs() <= Self::tolerance(t)
    }
}

/// What the APS is built from, fixed at initialisation.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Spec {
    layout: String,
    params: ApsParams,
    schedule: Schedule,
}

/// The APS and the nominal setup whose A-matrix it resets the readings with.
struct Built {
    aps: Aps,
    nominal: Nominal,
}

impl Spec {
    /// The parameters in `v`.
    fn read(x: &Vars, layout: &str, v: &Values) -> Self {
        let interval = v.scalar(x.interval);
        Self {
            layout: layout.to_string(),
            params: ApsParams {
                interval_days: interval / DAY,
                piston_rms: v.scalar(x.piston_rms),
                tilt_rms: v.scalar(x.tilt_rms),
                seed: u64::from(v.integer(x.seed).unsigned_abs()),
            },
            schedule: Schedule {
                first: v.scalar(x.first_run),
                interval,
            },
        }
    }

    /// Builds the APS and the nominal A-matrix of the packaged layout.
    fn build(&self) -> Result<Built, FmuError> {
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
        let geometry = default_geometry(&layout, false, None).map_err(wiring::model_error)?;
        let aps = Aps::new(&geometry, self.params).map_err(|e| {
            wiring::model_error_renamed(e, |name| match name {
                "aps_interval_days" => "interval",
                "aps_piston_rms" => "piston_rms",
                "aps_tilt_rms" => "tilt_rms",
                other => other,
            })
        })?;
        let nominal = Nominal::new(geometry).map_err(wiring::model_error)?;
        Ok(Built { aps, nominal })
    }
}

/// The `aps` FMU as configured: the handles and the packaged layout; [`ApsRunning`] runs.
#[derive(Debug, Clone)]
pub struct ApsFmu {
    vars: Vars,
    layout: String,
}

/// The initialised `aps` FMU: the APS, the held desired readings and the next run. A saved
/// state holds the readings, the run counters and what the APS is built from; the APS and the
/// A-matrix are rebuilt when it is read back.
#[derive(Clone, Serialize, Deserialize)]
#[serde(into = "SavedAps", try_from = "SavedAps")]
pub struct ApsRunning {
    vars: Vars,
    spec: Spec,
    /// Index of the next run.
    next: u64,
    /// Runs so far.
    runs: u64,
    /// The desired readings, held between runs.
    y_ref: Vec<f64>,
    built: Arc<Built>,
}

/// The serialised form of [`ApsRunning`].
#[derive(Serialize, Deserialize)]
struct SavedAps {
    vars: Vars,
    spec: Spec,
    next: u64,
    runs: u64,
    y_ref: Vec<f64>,
}

impl From<ApsRunning> for SavedAps {
    fn from(r: ApsRunning) -> Self {
        Self {
            vars: r.vars,
            spec: r.spec,
            next: r.next,
            runs: r.runs,
            y_ref: r.y_ref,
        }
    }
}

impl TryFrom<SavedAps> for ApsRunning {
    type Error = FmuError;

    fn try_from(s: SavedAps) -> Result<Self, FmuError> {
        let built = Arc::new(s.spec.build()?);
        if s.y_ref.len() != built.nominal.a.nrows() {
            return Err(FmuError::State(format!(
                "{} desired readings for {} sensors",
                s.y_ref.len(),
                built.nominal.a.nrows()
            )));
        }
        Ok(Self {
            vars: s.vars,
            spec: s.spec,
            next: s.next,
            runs: s.runs,
            y_ref: s.y_ref,
            built,
        })
    }
}

impl ApsRunning {
    /// Run `k` on the inputs in `v`: measures, resets the readings and writes the outputs
    /// (nothing changes on an error).
    fn run(&mut self, k: u64, v: &mut Values) -> Result<(), FmuError> {
        let e = self
            .built
            .aps
            .measure(v.real(self.vars.z), k)
            .map_err(wiring::model_error)?;
        let mut y_ref = self.y_ref.clone();
        Aps::reset_reference(&self.built.nominal.a, &mut y_ref, &e).map_err(wiring::model_error)?;
        self.y_ref = y_ref;
        self.next = k.saturating_add(1);
        self.runs = self.runs.saturating_add(1);
        self.write_outputs(v);
        Ok(())
    }

    fn write_outputs(&self, v: &mut Values) {
        v.real_mut(self.vars.y_ref).copy_from_slice(&self.y_ref);
        v.integers[self.vars.runs.slot] = i32::try_from(self.runs).unwrap_or(i32::MAX);
    }

    /// The APS (for in-process use and tests).
    pub fn aps(&self) -> &Aps {
        &self.built.aps
    }

    /// The nominal setup whose A-matrix resets the readings (for in-process use and tests).
    pub fn nominal(&self) -> &Nominal {
        &self.built.nominal
    }

    /// The desired readings held now.
    pub fn y_ref(&self) -> &[f64] {
        &self.y_ref
    }

    /// The runs so far.
    pub fn runs(&self) -> u64 {
        self.runs
    }
}

impl Model for ApsFmu {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "aps",
        model_name: "Alignment and Phasing System",
        description: "Alignment and Phasing System: periodic optical measurements of the segment \
            piston, tip and tilt (seeded errors) that reset the desired edge-sensor readings",
        documentation: DOC,
        default_stop_time: 60.0 * DAY,
        default_step: DAY,
    };

    type Running = ApsRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        let layout = variant.to_string();
        Ok((table, Self { vars, layout }))
    }

    fn initialize(&self, v: &mut Values, start_time: f64) -> Result<ApsRunning, FmuError> {
        let x = self.vars;
        let spec = Spec::read(&x, &self.layout, v);
        let built = Arc::new(spec.build()?);
        let schedule = spec.schedule;
        let ns = built.nominal.a.nrows();
        let mut running = ApsRunning {
            vars: x,
            spec,
            next: 0,
            runs: 0,
            y_ref: vec![0.0; ns],
            built,
        };
        match schedule.latest_at(start_time) {
            Some(k) if schedule.is_at(k, start_time) => running.run(k, v)?,
            Some(k) => running.next = k.saturating_add(1),
            None => {}
        }
        running.write_outputs(v);
        Ok(running)
    }
}

impl fmu::Running for ApsRunning {
    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // The readings change only at run instants, inside fmi2DoStep.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        match self.spec.schedule.latest_at(t + h) {
            // Only the latest run instant of the step runs, on the inputs held over it.
            Some(k) if k >= self.next => self.run(k, v),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;
    use m1::control::reconstructor::{orthonormalize, sparse_mul};
    use m1::sensing::interaction::global_ptt;

    /// An instance of `variant` through the runtime, in initialisation mode (start time 0),
    /// with the Real parameters `params` set.
    fn instance(variant: &str, params: &[(&str, f64)]) -> Instance<ApsFmu> {
        let (table, _) = ApsFmu::new(variant).expect("table");
        let guid = fmu::xml::guid(&ApsFmu::INFO, &table);
        let mut fmu = Instance::<ApsFmu>::new("test", &guid, None, None, false).expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        for (name, value) in params {
            let vr = vrs(&fmu, name)[0];
            fmu.set_real(&[vr], &[*value]).expect(name);
        }
        fmu
    }

    /// The value references of a variable's scalars.
    fn vrs(fmu: &Instance<ApsFmu>, name: &str) -> Vec<u32> {
        let v = fmu.table().by_name(name).expect(name);
        (v.vr..v.vr + v.len as u32).collect()
    }

    fn y_ref(fmu: &mut Instance<ApsFmu>) -> Vec<f64> {
        let vr = vrs(fmu, "y_ref");
        let mut out = vec![f64::NAN; vr.len()];
        fmu.get_real(&vr, &mut out).expect("y_ref");
        out
    }

    fn runs(fmu: &mut Instance<ApsFmu>) -> i32 {
        let mut out = [-1];
        fmu.get_integer(&vrs(fmu, "runs"), &mut out).expect("runs");
        out[0]
    }

    fn set_z(fmu: &mut Instance<ApsFmu>, z: &[f64]) {
        let vr = vrs(fmu, "z");
        fmu.set_real(&vr, z).expect("z");
    }

    fn step(fmu: &mut Instance<ApsFmu>, h: f64) {
        let t = fmu.time();
        fmu.do_step(t, h).expect("step");
    }

    /// A segment error: every actuator of segment 2 by different amounts.
    fn segment_error(na: usize) -> Vec<f64> {
        let mut z = vec![0.0; na];
        z[6..9].copy_from_slice(&[3e-8, -1e-8, 2e-8]);
        z
    }

    /// `z` without its global piston/tip/tilt (which the APS does not measure).
    fn relative(z: &[f64]) -> Vec<f64> {
        let layout = Layout::preset("keck").expect("layout");
        let g = default_geometry(&layout, false, None).expect("geometry");
        let modes = orthonormalize(global_ptt(&g).as_ref());
        let mut out = z.to_vec();
        for c in 0..modes.ncols() {
            let d: f64 = (0..z.len()).map(|i| modes[(i, c)] * z[i]).sum();
            for (i, v) in out.iter_mut().enumerate() {
                *v -= d * modes[(i, c)];
            }
        }
        out
    }

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = ApsFmu::new(variant).expect("table");
            let layout = Layout::preset(variant).expect("layout");
            let y = t.by_name("y_ref").expect("y_ref");
            assert_eq!(y.len, layout.n_sensors());
            assert_eq!(y.dependencies, Dependencies::None);
            assert_eq!(t.by_name("z").expect("z").len, layout.n_actuators());
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        assert_eq!(
            wiring::check_documented_signals::<ApsFmu>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// Without measurement errors a run removes a segment error exactly: y_ref moves by
    /// -A_0 z for a segment error z (relative to the global piston/tip/tilt, which the APS does
    /// not measure).
    #[test]
    fn an_exact_run_removes_a_segment_error() {
        let mut fmu = instance(
            "keck",
            &[("piston_rms", 0.0), ("tilt_rms", 0.0), ("first_run", 10.0)],
        );
        fmu.exit_initialization_mode().expect("initialise");
        let na = vrs(&fmu, "z").len();
        let z = relative(&segment_error(na));
        set_z(&mut fmu, &z);
        assert_eq!(runs(&mut fmu), 0);
        assert!(y_ref(&mut fmu).iter().all(|&y| y == 0.0));
        step(&mut fmu, 10.0);
        assert_eq!(runs(&mut fmu), 1);
        let got = y_ref(&mut fmu);
        let running = fmu.running().expect("running");
        // The library's run, bit for bit.
        let e = running.aps().measure(&z, 0).expect("measure");
        let mut want = vec![0.0; got.len()];
        Aps::reset_reference(&running.nominal().a, &mut want, &e).expect("reset");
        assert_eq!(got, want);
        // The physics: y_ref = -A_0 z, to rounding.
        let mut a0z = vec![0.0; got.len()];
        sparse_mul(&running.nominal().a, &z, &mut a0z);
        let scale = a0z.iter().fold(0.0_f64, |m, y| m.max(y.abs()));
        assert!(scale > 1e-9);
        for (y, a) in got.iter().zip(&a0z) {
            assert!((y + a).abs() < 1e-12 * scale, "{y} vs {}", -a);
        }
    }

    /// Runs at first_run + k interval: at initialisation when first_run is the start time, at
    /// the steps that reach each instant; between runs nothing changes whatever z does.
    #[test]
    fn runs_happen_at_their_instants_and_nothing_changes_between() {
        let mut fmu = instance("keck", &[("interval", 10.0), ("first_run", 0.0)]);
        let na = vrs(&fmu, "z").len();
        set_z(&mut fmu, &segment_error(na));
        fmu.exit_initialization_mode().expect("initialise");
        assert_eq!(runs(&mut fmu), 1, "a run at the start time");
        let mut held = y_ref(&mut fmu);
        assert!(held.iter().any(|&y| y != 0.0));
        let mut counts = Vec::new();
        for k in 1..=25 {
            // z changes at every step; y_ref changes only at the runs (t = 10, 20).
            let z: Vec<f64> = (0..na).map(|i| 1e-8 * ((i * k) as f64).sin()).collect();
            set_z(&mut fmu, &z);
            step(&mut fmu, 1.0);
            let now = y_ref(&mut fmu);
            let ran = runs(&mut fmu);
            counts.push(ran);
            if k % 10 == 0 {
                assert_ne!(now, held, "run at t = {k}");
            } else {
                assert_eq!(now, held, "no run at t = {k}");
            }
            held = now;
        }
        let want: Vec<i32> = (1..=25).map(|k| 1 + k / 10).collect();
        assert_eq!(counts, want);

        // first_run after the start: no run at initialisation; a long step runs only once,
        // with the latest instant's draw.
        let mut fmu = instance("keck", &[("interval", 10.0), ("first_run", 5.0)]);
        fmu.exit_initialization_mode().expect("initialise");
        assert_eq!(runs(&mut fmu), 0);
        step(&mut fmu, 4.0);
        assert_eq!(runs(&mut fmu), 0);
        step(&mut fmu, 1.0);
        assert_eq!(runs(&mut fmu), 1, "t = 5");
        let before = fmu.running().expect("running").y_ref().to_vec();
        let z = segment_error(na);
        set_z(&mut fmu, &z);
        step(&mut fmu, 25.0); // (5, 30]: instants 15 and 25, only 25 (k = 2) runs
        assert_eq!(runs(&mut fmu), 2);
        let running = fmu.running().expect("running");
        let e = running.aps().measure(&z, 2).expect("measure");
        let mut want = before;
        Aps::reset_reference(&running.nominal().a, &mut want, &e).expect("reset");
        assert_eq!(y_ref(&mut fmu), want);
        step(&mut fmu, 4.0);
        assert_eq!(runs(&mut fmu), 2);
        step(&mut fmu, 1.0);
        assert_eq!(runs(&mut fmu), 3, "t = 35");
    }

    /// Bad parameters are refused with an error status.
    #[test]
    fn bad_parameters_are_refused() {
        let mut fmu = instance("keck", &[]);
        let vr = vrs(&fmu, "interval")[0];
        assert!(fmu.set_real(&[vr], &[0.0]).is_err());
        let vr = vrs(&fmu, "piston_rms")[0];
        assert!(fmu.set_real(&[vr], &[-1e-9]).is_err());
        fmu.exit_initialization_mode().expect("defaults");
    }

    /// A serialised state steps on exactly as the instance it was taken from, with the APS
    /// rebuilt (its seeded errors included).
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let mut fmu = instance("keck", &[("interval", 3.0), ("first_run", 0.0)]);
        fmu.exit_initialization_mode().expect("initialise");
        let na = vrs(&fmu, "z").len();
        let z = segment_error(na);
        set_z(&mut fmu, &z);
        step(&mut fmu, 2.0);
        let bytes = Instance::serialize(&fmu.get_state().expect("state")).expect("serialize");
        let go = |fmu: &mut Instance<ApsFmu>| {
            let mut all = Vec::new();
            for _ in 0..5 {
                step(fmu, 2.0);
                all.extend(y_ref(fmu));
                all.push(f64::from(runs(fmu)));
            }
            all
        };
        let straight = go(&mut fmu);
        let state = fmu.deserialize(&bytes).expect("deserialize");
        fmu.set_state(&state).expect("set state");
        assert_eq!(runs(&mut fmu), 1);
        assert_eq!(go(&mut fmu), straight);
        assert_eq!(runs(&mut fmu), 5);
    }
}

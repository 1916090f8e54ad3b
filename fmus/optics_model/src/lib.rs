//! Model wiring of the `optics` FMU: optical metrics of the mirror state (rms surface,
//! focus-mode, PSSN), computed by [`m1::optics::metrics::MirrorMetrics`] and [`m1::optics::pssn::Pssn`].
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `z` | input | na | m |
//! | `rms_surface` | output (no direct dependency on inputs) | 1 | m |
//! | `focus_mode` | output (no direct dependency on inputs) | 1 | m |
//! | `rms_surface_without_focus` | output (no direct dependency on inputs) | 1 | m |
//! | `pssn` | output (no direct dependency on inputs) | 1 | 1 |
//! | `focus_mode_coefficient` | output (no direct dependency on inputs) | 1 | m |
//!
//! with na = 3 x the number of segments of the packaged layout (actuator k of segment i at
//! index 3 i + k).
//!
//! # Sampling
//!
//! The metrics are sampled at the FMU's own instants `t0 + k / metrics_rate`, PSSN at
//! `t0 + k / pssn_rate` (`pssn_rate = 0`: never), whatever the communication step, and held in
//! between. The input is held over a communication step (zero-order hold); an instant `t_k` in
//! the step `(t, t + h]` samples the value held just before it, `z(t_k^-)`, and the output
//! holds the result from `t_k` on. Several instants in one step see the same input, so the
//! evaluation is done once. The instant `t0` is sampled at initialisation from the initial
//! `z`. So the outputs never depend directly on `z` at the same communication point: the
//! ModelStructure declares no output dependency (no algebraic loop through this FMU), and the
//! outputs are Real variables of discrete variability.

use std::sync::{Arc, Mutex, PoisonError};

use serde::{Deserialize, Serialize};

use fmu::{
    BoolVar, Decl, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, Running, StrVar,
    TableBuilder as T, Values, VariableTable,
};
use m1::M1Error;
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::optics::metrics::{MetricsScratch, MirrorMetrics};
use m1::optics::pssn::{Pssn, PssnParams, PssnPrecision};
use wiring::signals::{Z, layout_decl, n_segments_decl};

/// Default samples across the aperture of the PSSN pupil grid (see the documentation).
pub const DEFAULT_PSSN_SAMPLES: i32 = 256;

/// Sample instants closer than this fraction of a period to a communication point count as
/// reached (rounding of sums of steps).
const INSTANT_TOLERANCE: f64 = 1e-9;

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        z: RealVar = Z.input(layout),
        rms_surface: RealVar = metric("rms_surface", "m")
            .describe("Area-weighted rms surface error over the aperture, global piston/tip/tilt \
                       removed (held between samples)"),
        focus_mode: RealVar = metric("focus_mode", "m")
            .describe("Focus-mode as rms surface: the rms of its component of the surface, signed \
                       as its coefficient (rms_surface^2 = rms_surface_without_focus^2 + \
                       focus_mode^2)"),
        rms_surface_without_focus: RealVar = metric("rms_surface_without_focus", "m")
            .describe("Rms surface error with global piston/tip/tilt and focus-mode removed"),
        pssn: RealVar = metric("pssn", "1")
            .describe("Normalised point-source sensitivity of the residual surface (0: not \
                       computed)"),
        focus_mode_coefficient: RealVar = metric("focus_mode_coefficient", "m")
            .describe("Focus-mode coefficient: amplitude of the unit-norm focus-mode vector over \
                       the actuators (actuator space; focus_mode = focus_mode_coefficient * \
                       focus_rms_per_unit)"),
        metrics_rate: RealVar = T::real("metrics_rate").parameter().unit("Hz").start(1000.0)
            .positive().describe("Sample rate of the rms and focus-mode metrics"),
        pssn_rate: RealVar = T::real("pssn_rate").parameter().unit("Hz").start(10.0)
            .non_negative().describe("Sample rate of PSSN (0: PSSN disabled, output 0)"),
        wavelength: RealVar = T::real("wavelength").parameter().unit("m").start(500e-9)
            .check(fmu::Check::Range(1e-7, 1e-4)).describe("Wavelength of the PSSN evaluation"),
        r0: RealVar = T::real("r0").parameter().unit("m").start(0.2).positive()
            .describe("Fried parameter at 500 nm (scaled to the wavelength as lambda^(6/5))"),
        outer_scale: RealVar = T::real("L0").parameter().unit("m").start(30.0).positive()
            .describe("Von Karman outer scale of the atmosphere"),
        pssn_samples: IntVar = T::integer("pssn_samples").parameter()
            .start_int(DEFAULT_PSSN_SAMPLES).check(fmu::Check::Range(16.0, 1024.0))
            .describe("Samples across the aperture of the PSSN pupil grid (cost ~ samples^2; \
                       1 - PSSN about 7 % high at 256, see the documentation)"),
        pssn_single_precision: BoolVar = T::boolean("pssn_single_precision").parameter()
            .start_bool(true)
            .describe("Hold the PSSN's pupil field, its FFTs and the OTF in single precision \
                       (phases, weights and sums stay double): 0.6x the time, the PSSN within \
                       5e-7 of double precision's on TMT (false: double throughout)"),
        actuator_radius: RealVar = T::real("actuator_radius").parameter().unit("m")
            .start(GeometryParams::for_layout(layout).actuator_radius).positive()
            .describe("Radius of the actuator circle of a segment (less than the circumradius)"),
        focus_rms_per_unit: RealVar = T::real("focus_rms_per_unit").calculated_parameter()
            .unit("1").describe("Rms surface (m) of a unit focus_mode_coefficient (m)"),
        pssn_grid_spacing: RealVar = T::real("pssn_grid_spacing").calculated_parameter()
            .unit("m").describe("Spacing of the PSSN pupil grid (0 when PSSN is disabled)"),
    }
}

/// An output metric: sampled (discrete), held between samples, with no direct dependency on
/// the input.
fn metric(name: &str, unit: &str) -> Decl {
    T::real(name)
        .output()
        .discrete()
        .unit(unit)
        .depends(Dependencies::None)
}

/// The parameters the precomputation depends on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Setup {
    actuator_radius: f64,
    /// None when PSSN is disabled; else samples, wavelength, r0, L0 and whether in single
    /// precision.
    pssn: Option<(usize, f64, f64, f64, bool)>,
}

/// The precomputed evaluators (shared between copies of the model: read-only).
struct Engine {
    setup: Setup,
    metrics: MirrorMetrics,
    pssn: Option<Pssn>,
}

/// One sampling clock: instants `t0 + k / rate`, `k = next, next + 1, ...` still to come.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
struct Clock {
    rate: f64,
    next: u64,
}

impl Clock {
    /// Whether an instant falls in `(t0 + (next - 1) / rate, t_end]`; advances past it.
    fn due(&mut self, t0: f64, t_end: f64) -> bool {
        if self.rate.is_nan() || self.rate <= 0.0 {
            return false;
        }
        let k = ((t_end - t0) * self.rate + INSTANT_TOLERANCE).floor();
        if k >= 0.0 && k as u64 >= self.next {
            self.next = k as u64 + 1;
            true
        } else {
            false
        }
    }
}

/// The `optics` FMU as configured: the handles and the layout; [`OpticsRunning`] steps.
pub struct Optics {
    vars: Vars,
    layout: String,
    /// The evaluators of the last initialisation, reused while the parameters they depend on
    /// stay the same (initialisation mode may evaluate the outputs several times).
    last_engine: Mutex<Option<Arc<Engine>>>,
}

/// The initialised `optics` FMU: the evaluators and the sampling clocks.
///
/// An FMU state serialises the parameters the evaluators were made from, not the evaluators:
/// they are rebuilt when it is read back.
#[derive(Clone, Serialize, Deserialize)]
#[serde(try_from = "OpticsState", into = "OpticsState")]
pub struct OpticsRunning {
    vars: Vars,
    layout: String,
    start_time: f64,
    metrics_clock: Clock,
    pssn_clock: Clock,
    engine: Arc<Engine>,
    /// Residual segment states fed to PSSN (scratch, length N).
    residual: Vec<[f64; 3]>,
    /// The metrics' working buffers, kept between steps.
    scratch: MetricsScratch,
}

/// What a serialised [`OpticsRunning`] holds.
#[derive(Serialize, Deserialize)]
struct OpticsState {
    vars: Vars,
    layout: String,
    setup: Setup,
    start_time: f64,
    metrics_clock: Clock,
    pssn_clock: Clock,
}

impl From<OpticsRunning> for OpticsState {
    fn from(r: OpticsRunning) -> Self {
        OpticsState {
            vars: r.vars,
            layout: r.layout,
            setup: r.engine.setup,
            start_time: r.start_time,
            metrics_clock: r.metrics_clock,
            pssn_clock: r.pssn_clock,
        }
    }
}

impl TryFrom<OpticsState> for OpticsRunning {
    type Error = FmuError;

    fn try_from(s: OpticsState) -> Result<Self, FmuError> {
        let engine = Arc::new(Engine::new(&s.layout, s.setup)?);
        Ok(OpticsRunning {
            vars: s.vars,
            layout: s.layout,
            start_time: s.start_time,
            metrics_clock: s.metrics_clock,
            pssn_clock: s.pssn_clock,
            residual: Vec::with_capacity(engine.metrics.n_segments()),
            scratch: MetricsScratch::default(),
            engine,
        })
    }
}

const DOC: &str = "<h2>Model</h2>\
<p>Input <code>z</code> (m): the displacement of the mirror normal to the segment at each \
actuator (actuator k of segment i at index 3i+k). Every segment is rigid: its surface over its \
hexagon in the aperture plane is the plane through the three actuator points (projected onto \
the aperture plane) at heights <code>z</code>, s<sub>i</sub>(x, y) = p<sub>i</sub> + \
t<sub>x,i</sub>(x &minus; c<sub>x,i</sub>) + t<sub>y,i</sub>(y &minus; c<sub>y,i</sub>). The \
metric is the area integral over the segmented aperture (gaps excluded), with the exact second \
moments of a regular hexagon of circumradius a: area A = 3&radic;3/2 a<sup>2</sup>, second \
moment I = 5&radic;3/16 a<sup>4</sup> about any in-plane axis through its centre.</p>\
<h2>Outputs</h2><ul>\
<li><code>rms_surface</code> (m, surface; the wavefront error is twice it): area-weighted rms \
over the aperture after removing the least-squares global plane (piston, tip, tilt) over the \
aperture: sqrt(&sum;<sub>i</sub> A r<sub>p,i</sub><sup>2</sup> + I (r<sub>x,i</sub><sup>2</sup> \
+ r<sub>y,i</sub><sup>2</sup>) / (N A)).</li>\
<li><code>focus_mode</code> (m, surface): the rms surface of the focus-mode component of the \
residual, signed as its coefficient c (below): c &times; <code>focus_rms_per_unit</code>. So \
<code>rms_surface</code><sup>2</sup> = <code>rms_surface_without_focus</code><sup>2</sup> + \
<code>focus_mode</code><sup>2</sup>, and its rms over time is the focus-mode amplitude in nm rms \
as the seed paper quotes it.</li>\
<li><code>focus_mode_coefficient</code> (m): the coefficient c of the focus-mode f, the least \
observable mode of the edge-sensor interaction matrix A, as a vector over the actuators of unit \
Euclidean norm: z = c f gives c (with any global piston/tip/tilt added too). It is the \
least-squares coefficient of the residual surface of f in the residual surface of z: an \
actuator-space amplitude, not a surface figure (38 times <code>focus_mode</code> on TMT, \
10 times on Keck).</li>\
<li><code>rms_surface_without_focus</code> (m): the rms surface with global piston/tip/tilt \
and c f removed.</li>\
<li><code>pssn</code> (1): the normalised point-source sensitivity (Seo et al.) of the residual \
surface (the global plane removed, to which PSSN is insensitive anyway), with a von K&aacute;rm&aacute;n \
atmosphere (<code>r0</code> at 500 nm scaled as &lambda;<sup>6/5</sup>, outer scale \
<code>L0</code>) at <code>wavelength</code>, from the pupil sampled with \
<code>pssn_samples</code> points across. 1 for a perfect mirror, 1 &minus; PSSN quadratic in \
small errors. 0 means not computed (<code>pssn_rate</code> = 0).</li></ul>\
<h2>Sampling</h2><p>The three surface metrics are sampled at the instants t0 + k / \
<code>metrics_rate</code>, PSSN at t0 + k / <code>pssn_rate</code>, whatever the communication \
step, and held in between. The input is held over a step; an instant inside the step (t, t+h] \
samples the value held just before it and the output holds the result from that instant. The \
instant t0 is sampled at initialisation from the initial input. No output depends directly on \
<code>z</code> (empty dependencies): the outputs are discrete Real variables.</p>\
<p>The archive holds the packaged layout as <code>resources/layout.json</code> (segment centres \
in the aperture plane, m; circumradius).</p>\
<h2>PSSN accuracy and cost</h2><p>Only the OTF's lags within a few Fried parameters carry \
weight (12 lag rows on TMT at 256 samples and 500 nm): an evaluation transforms the field's rows \
and correlates their spectra for those lag rows (<code>m1::optics::pssn::OtfMethod</code>; the \
2-D power spectrum's transforms where many rows carry weight). Measured (release build, one \
core of a shared machine, <code>cargo bench -p m1 --bench optics</code>) per evaluation in the \
default single precision of the field, its FFTs and the OTF (phases, OTF weights and sums in \
double): TMT 0.08 ms at 128 samples, 0.25 ms at the default 256 (grid spacing 0.117 m), 1.5 ms \
at 512; Keck 0.08, 0.26 and 1.6 ms; in double precision (<code>pssn_single_precision</code> \
false) TMT 0.10, 0.40 and 2.3 ms. Single precision moves the PSSN by less than 5e-7 on TMT. So \
the default costs about 2.5 ms of CPU per simulated second at the default 10 Hz. \
The deficit 1 &minus; PSSN converges with the grid spacing: at 500 nm and 256 samples it is \
about 7 % above the 512-sample value (TMT, random segment errors: 3.35e-2 against 3.14e-2); \
use 512 samples where a few per cent matter (dx &le; r0/4), or a longer wavelength, where the \
grid converges faster.</p>";

/// Physics errors with the FMU's variable names (the PSSN grid is `pssn_samples`, the outer
/// scale `L0`).
fn model_error(e: M1Error) -> FmuError {
    wiring::model_error_renamed(e, |name| match name {
        "samples" | "pad_factor" => "pssn_samples",
        "l0" => "L0",
        other => other,
    })
}

fn setup(x: &Vars, v: &Values) -> Setup {
    let pssn = (v.scalar(x.pssn_rate) > 0.0).then(|| {
        (
            usize::try_from(v.integer(x.pssn_samples)).unwrap_or(0),
            v.scalar(x.wavelength),
            v.scalar(x.r0),
            v.scalar(x.outer_scale),
            v.boolean(x.pssn_single_precision),
        )
    });
    Setup {
        actuator_radius: v.scalar(x.actuator_radius),
        pssn,
    }
}

impl Engine {
    /// The evaluators of `layout` for `setup`.
    fn new(layout: &str, setup: Setup) -> Result<Engine, FmuError> {
        let layout = Layout::preset(layout).map_err(|e| FmuError::Instantiate(e.to_string()))?;
        let mut params = GeometryParams::for_layout(&layout);
        params.actuator_radius = setup.actuator_radius;
        let geometry = Geometry::new(&layout, params).map_err(model_error)?;
        let metrics = MirrorMetrics::new(&geometry).map_err(model_error)?;
        let pssn = match setup.pssn {
            Some((samples, wavelength, r0, l0, single)) => Some(
                Pssn::with_precision(
                    &layout,
                    PssnParams {
                        samples,
                        wavelength,
                        r0,
                        l0,
                        ..PssnParams::default()
                    },
                    if single {
                        PssnPrecision::Single
                    } else {
                        PssnPrecision::Double
                    },
                )
                .map_err(model_error)?,
            ),
            None => None,
        };
        Ok(Engine {
            setup,
            metrics,
            pssn,
        })
    }
}

impl Optics {
    /// The evaluators for the current parameters: those of the last initialisation when they
    /// depend on the same, or built.
    fn engine(&self, v: &Values) -> Result<Arc<Engine>, FmuError> {
        let setup = setup(&self.vars, v);
        // A poisoned lock only means a panic while it was held: the cached value is complete.
        let mut last = self
            .last_engine
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(e) = last.as_ref()
            && e.setup == setup
        {
            return Ok(e.clone());
        }
        let engine = Arc::new(Engine::new(&self.layout, setup)?);
        *last = Some(engine.clone());
        Ok(engine)
    }
}

impl OpticsRunning {
    fn sample_metrics(&mut self, v: &mut Values) -> Result<(), FmuError> {
        let m = self
            .engine
            .metrics
            .evaluate_with(v.real(self.vars.z), &mut self.scratch)
            .map_err(model_error)?;
        v.real_mut(self.vars.rms_surface)[0] = m.rms;
        v.real_mut(self.vars.focus_mode)[0] = m.focus_rms;
        v.real_mut(self.vars.focus_mode_coefficient)[0] = m.focus;
        v.real_mut(self.vars.rms_surface_without_focus)[0] = m.rms_without_focus;
        Ok(())
    }

    fn sample_pssn(&mut self, v: &mut Values) -> Result<(), FmuError> {
        let e = &self.engine;
        let Some(pssn) = &e.pssn else {
            v.real_mut(self.vars.pssn)[0] = 0.0;
            return Ok(());
        };
        self.residual.resize(e.metrics.n_segments(), [0.0; 3]);
        e.metrics
            .residual_ptt(v.real(self.vars.z), &mut self.residual)
            .map_err(model_error)?;
        v.real_mut(self.vars.pssn)[0] = pssn.pssn_ptt(&self.residual).map_err(model_error)?;
        Ok(())
    }

    /// The metrics evaluator (for in-process use and tests).
    pub fn metrics(&self) -> &MirrorMetrics {
        &self.engine.metrics
    }
}

impl Model for Optics {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "optics",
        model_name: "M1 optical metrics",
        description: "Optical metrics of a segmented primary mirror from the actuator-point \
            displacements: rms surface (global piston/tip/tilt removed), focus-mode amplitude, \
            rms without focus-mode and PSSN, sampled at their own rates",
        documentation: DOC,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };

    type Running = OpticsRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    /// The packaged layout (segment centres in the aperture plane, circumradius) as
    /// `resources/layout.json`, so that users can map and check the metrics.
    fn resources(variant: &str) -> Vec<(String, Vec<u8>)> {
        Layout::preset(variant)
            .map(|l| vec![("layout.json".to_string(), l.to_json_string().into_bytes())])
            .unwrap_or_default()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        Ok((
            table,
            Optics {
                vars,
                layout: layout.name.clone(),
                last_engine: Mutex::new(None),
            },
        ))
    }

    fn initialize(&self, v: &mut Values, start_time: f64) -> Result<OpticsRunning, FmuError> {
        let engine = self.engine(v)?;
        let x = self.vars;
        v.real_mut(x.focus_rms_per_unit)[0] = engine.metrics.focus_rms_per_unit();
        v.real_mut(x.pssn_grid_spacing)[0] =
            engine.pssn.as_ref().map_or(0.0, |p| p.grid().spacing());
        let mut running = OpticsRunning {
            vars: x,
            layout: self.layout.clone(),
            start_time,
            metrics_clock: Clock {
                rate: v.scalar(x.metrics_rate),
                next: 1,
            },
            pssn_clock: Clock {
                rate: v.scalar(x.pssn_rate),
                next: 1,
            },
            residual: Vec::with_capacity(engine.metrics.n_segments()),
            scratch: MetricsScratch::default(),
            engine,
        };
        running.sample_metrics(v)?;
        running.sample_pssn(v)?;
        Ok(running)
    }
}

impl Running for OpticsRunning {
    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // No output depends directly on the input: they change only at sample instants.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let end = t + h;
        // Work on copies of the clocks so that a failed step leaves the model unchanged.
        let (mut mc, mut pc) = (self.metrics_clock, self.pssn_clock);
        if mc.due(self.start_time, end) {
            self.sample_metrics(v)?;
        }
        if pc.due(self.start_time, end) {
            self.sample_pssn(v)?;
        }
        self.metrics_clock = mc;
        self.pssn_clock = pc;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use fmu::Instance;

    /// An instance of `variant` through the runtime, in initialisation mode (start time 0).
    fn instance(variant: &str) -> Instance<Optics> {
        let (table, _) = Optics::new(variant).expect("table");
        let guid = fmu::xml::guid(&Optics::INFO, &table);
        let mut fmu = Instance::<Optics>::new("test", &guid, None, None, false).expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        fmu
    }

    /// The value references of a variable's scalars.
    fn vrs(fmu: &Instance<Optics>, name: &str) -> Vec<u32> {
        let v = fmu.table().by_name(name).expect(name);
        (v.vr..v.vr + v.len as u32).collect()
    }

    /// `steps` communication steps of 10 ms (`before(fmu, k)` first), then the values of `name`.
    fn run(
        fmu: &mut Instance<Optics>,
        steps: usize,
        before: impl Fn(&mut Instance<Optics>, usize),
        name: &str,
    ) -> Vec<f64> {
        for k in 0..steps {
            before(fmu, k);
            let t = fmu.time();
            fmu.do_step(t, 0.01).expect("step");
        }
        let vr = vrs(fmu, name);
        let mut out = vec![f64::NAN; vr.len()];
        fmu.get_real(&vr, &mut out).expect("get");
        out
    }

    #[test]
    fn clock_samples_its_own_instants() {
        let mut c = Clock {
            rate: 10.0,
            next: 1,
        };
        // Steps of 0.03 s: instants 0.1, 0.2, 0.3 fall in (0.09, 0.12], (0.18, 0.21], (0.27, 0.3].
        let mut hits = Vec::new();
        let mut t = 0.0;
        for k in 0..12 {
            let end = t + 0.03;
            if c.due(0.0, end) {
                hits.push(k);
            }
            t = end;
        }
        assert_eq!(hits, vec![3, 6, 9]);
        // One long step over several instants: one sample, the clock moves past all of them.
        let mut c = Clock {
            rate: 10.0,
            next: 1,
        };
        assert!(c.due(0.0, 0.55));
        assert_eq!(c.next, 6);
        assert!(!c.due(0.0, 0.59));
        let mut off = Clock { rate: 0.0, next: 1 };
        assert!(!off.due(0.0, 100.0));
    }

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = Optics::new(variant).unwrap();
            let na = Layout::preset(variant).unwrap().n_actuators();
            assert_eq!(t.by_name("z").unwrap().len, na);
            for name in [
                "rms_surface",
                "focus_mode",
                "rms_surface_without_focus",
                "pssn",
                "focus_mode_coefficient",
            ] {
                assert_eq!(t.by_name(name).unwrap().dependencies, Dependencies::None);
            }
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        assert_eq!(
            wiring::check_documented_signals::<Optics>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// `pssn_single_precision` chooses the precision of the PSSN's transforms: single (the
    /// default) and double give PSSNs within 1e-5 of each other, not the same bits, on a
    /// state with a PSSN well below 1.
    #[test]
    fn the_pssn_precision_is_a_parameter() {
        let pssn = |single: Option<bool>| {
            let mut fmu = instance("keck");
            fmu.set_integer(&vrs(&fmu, "pssn_samples"), &[64]).unwrap();
            if let Some(single) = single {
                fmu.set_boolean(&vrs(&fmu, "pssn_single_precision"), &[single])
                    .unwrap();
            }
            let z = vrs(&fmu, "z");
            let v: Vec<f64> = (0..z.len())
                .map(|i| 5e-8 * (i as f64 * 0.7).sin())
                .collect();
            fmu.set_real(&z, &v).unwrap();
            fmu.exit_initialization_mode().unwrap();
            run(&mut fmu, 1, |_, _| {}, "pssn")[0]
        };
        let (default, single, double) = (pssn(None), pssn(Some(true)), pssn(Some(false)));
        assert_eq!(default.to_bits(), single.to_bits());
        assert!(double > 0.0 && double < 0.99, "pssn {double}");
        assert!(
            (single - double).abs() < 1e-5 && single != double,
            "single {single}, double {double}"
        );
    }

    /// A serialised FMU state (the evaluators rebuilt from the parameters it holds, the
    /// sampling clocks as they were) steps on exactly as the instance it was taken from.
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let mut fmu = instance("keck");
        fmu.set_integer(&vrs(&fmu, "pssn_samples"), &[32]).unwrap();
        fmu.set_real(&vrs(&fmu, "pssn_rate"), &[40.0]).unwrap();
        fmu.exit_initialization_mode().unwrap();
        let n = Layout::preset("keck").unwrap().n_segments();
        assert_eq!(fmu.running().unwrap().metrics().n_segments(), n);
        // A different input every step.
        let z = vrs(&fmu, "z");
        let set_z = |fmu: &mut Instance<Optics>, k: usize| {
            let v: Vec<f64> = (0..z.len())
                .map(|i| 1e-8 * ((i * 7 + k * 3) as f64).sin())
                .collect();
            fmu.set_real(&z, &v).unwrap();
        };
        run(&mut fmu, 2, set_z, "pssn");
        let bytes = Instance::<Optics>::serialize(&fmu.get_state().unwrap()).unwrap();
        let outputs = [
            "rms_surface",
            "focus_mode",
            "pssn",
            "focus_mode_coefficient",
        ];
        let mut original = vec![run(&mut fmu, 5, set_z, "rms_surface")];
        original.extend(outputs.iter().map(|o| run(&mut fmu, 0, set_z, o)));
        let state = fmu.deserialize(&bytes).unwrap();
        fmu.set_state(&state).unwrap();
        let mut restored = vec![run(&mut fmu, 5, set_z, "rms_surface")];
        restored.extend(outputs.iter().map(|o| run(&mut fmu, 0, set_z, o)));
        assert!(
            original[3][0] > 0.0 && original[3][0] < 1.0,
            "pssn {:?}",
            original[3]
        );
        assert_eq!(original, restored);
    }
}

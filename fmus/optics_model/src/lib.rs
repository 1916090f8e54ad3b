//! Model wiring of the `optics` FMU: optical metrics of the mirror state (rms surface,
//! focus-mode, PSSN), computed by [`m1::optics::metrics::MirrorMetrics`] and [`m1::optics::pssn::Pssn`].
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `z` | input | na | m |
//! | `rms_surface` | output | 1 | m |
//! | `focus_mode` | output | 1 | m |
//! | `rms_surface_without_focus` | output | 1 | m |
//! | `pssn` | output | 1 | 1 |
//! | `focus_mode_coefficient` | output | 1 | m |
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

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use fmu::{
    Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T, Values,
    VariableTable,
};
use m1::M1Error;
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::optics::metrics::MirrorMetrics;
use m1::optics::pssn::{Pssn, PssnParams};

/// Default samples across the aperture of the PSSN pupil grid (see the documentation).
pub const DEFAULT_PSSN_SAMPLES: i32 = 256;

/// Sample instants closer than this fraction of a period to a communication point count as
/// reached (rounding of sums of steps).
const INSTANT_TOLERANCE: f64 = 1e-9;

/// Handles of every variable.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Vars {
    layout: StrVar,
    n_segments: IntVar,
    z: RealVar,
    rms_surface: RealVar,
    focus_mode: RealVar,
    rms_surface_without_focus: RealVar,
    pssn: RealVar,
    focus_mode_coefficient: RealVar,
    metrics_rate: RealVar,
    pssn_rate: RealVar,
    wavelength: RealVar,
    r0: RealVar,
    outer_scale: RealVar,
    pssn_samples: IntVar,
    actuator_radius: RealVar,
    focus_rms_per_unit: RealVar,
    pssn_grid_spacing: RealVar,
}

/// The parameters the precomputation depends on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Setup {
    actuator_radius: f64,
    /// None when PSSN is disabled.
    pssn: Option<(usize, f64, f64, f64)>,
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

/// The `optics` FMU.
#[derive(Clone, Serialize, Deserialize)]
pub struct Optics {
    vars: Vars,
    layout: String,
    start_time: f64,
    metrics_clock: Clock,
    pssn_clock: Clock,
    /// Rebuilt from the parameters after a deserialised FMU state.
    #[serde(skip)]
    engine: Option<Arc<Engine>>,
    /// Residual segment states fed to PSSN (scratch, length N).
    #[serde(skip)]
    residual: Vec<[f64; 3]>,
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
<h2>PSSN accuracy and cost</h2><p>The cost grows as (2 <code>pssn_samples</code>)<sup>2</sup> \
log. Measured (release build, one core of a shared machine) per evaluation: TMT 0.4 ms at 128 \
samples, 3.3 ms at the default 256 (grid spacing 0.117 m, FFT 512), 18 ms at 512; Keck 0.7, 3.2 \
and 23 ms. So the default costs about 35 ms of CPU per simulated second at the default 10 Hz. \
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

fn table(layout: &Layout) -> Result<(VariableTable, Vars), FmuError> {
    let na = layout.n_actuators();
    let mut b = T::new();
    let layout_var = b.add_string(
        T::string("layout")
            .structural()
            .start_str(&layout.name)
            .describe("Mirror layout this FMU was packaged for"),
    );
    let n_segments = b.add_integer(
        T::integer("n_segments")
            .structural()
            .start_int(i32::try_from(layout.n_segments()).unwrap_or(i32::MAX))
            .describe("Number of segments (the input has 3 x n_segments elements)"),
    );
    let z = b.add_real(
        T::real("z")
            .input()
            .len(na)
            .unit("m")
            .start(0.0)
            .describe("Mirror displacement normal to the segment at each actuator"),
    );
    let out = |b: &mut T, name: &str, unit: &str, desc: &str| {
        b.add_real(
            T::real(name)
                .output()
                .discrete()
                .unit(unit)
                .depends(Dependencies::None)
                .describe(desc),
        )
    };
    let rms_surface = out(
        &mut b,
        "rms_surface",
        "m",
        "Area-weighted rms surface error over the aperture, global piston/tip/tilt removed \
         (held between samples)",
    );
    let focus_mode = out(
        &mut b,
        "focus_mode",
        "m",
        "Focus-mode as rms surface: the rms of its component of the surface, signed as its \
         coefficient (rms_surface^2 = rms_surface_without_focus^2 + focus_mode^2)",
    );
    let rms_surface_without_focus = out(
        &mut b,
        "rms_surface_without_focus",
        "m",
        "Rms surface error with global piston/tip/tilt and focus-mode removed",
    );
    let pssn = out(
        &mut b,
        "pssn",
        "1",
        "Normalised point-source sensitivity of the residual surface (0: not computed)",
    );
    let focus_mode_coefficient = out(
        &mut b,
        "focus_mode_coefficient",
        "m",
        "Focus-mode coefficient: amplitude of the unit-norm focus-mode vector over the \
         actuators (actuator space; focus_mode = focus_mode_coefficient * focus_rms_per_unit)",
    );
    let metrics_rate = b.add_real(
        T::real("metrics_rate")
            .parameter()
            .unit("Hz")
            .start(1000.0)
            .positive()
            .describe("Sample rate of the rms and focus-mode metrics"),
    );
    let pssn_rate = b.add_real(
        T::real("pssn_rate")
            .parameter()
            .unit("Hz")
            .start(10.0)
            .non_negative()
            .describe("Sample rate of PSSN (0: PSSN disabled, output 0)"),
    );
    let wavelength = b.add_real(
        T::real("wavelength")
            .parameter()
            .unit("m")
            .start(500e-9)
            .check(fmu::Check::Range(1e-7, 1e-4))
            .describe("Wavelength of the PSSN evaluation"),
    );
    let r0 = b.add_real(
        T::real("r0")
            .parameter()
            .unit("m")
            .start(0.2)
            .positive()
            .describe("Fried parameter at 500 nm (scaled to the wavelength as lambda^(6/5))"),
    );
    let outer_scale = b.add_real(
        T::real("L0")
            .parameter()
            .unit("m")
            .start(30.0)
            .positive()
            .describe("Von Karman outer scale of the atmosphere"),
    );
    let pssn_samples = b.add_integer(
        T::integer("pssn_samples")
            .parameter()
            .start_int(DEFAULT_PSSN_SAMPLES)
            .check(fmu::Check::Range(16.0, 1024.0))
            .describe(
                "Samples across the aperture of the PSSN pupil grid (cost ~ samples^2; \
                 1 - PSSN about 7 % high at 256, see the documentation)",
            ),
    );
    let actuator_radius = b.add_real(
        T::real("actuator_radius")
            .parameter()
            .unit("m")
            .start(GeometryParams::for_layout(layout).actuator_radius)
            .positive()
            .describe("Radius of the actuator circle of a segment (less than the circumradius)"),
    );
    let focus_rms_per_unit = b.add_real(
        T::real("focus_rms_per_unit")
            .calculated_parameter()
            .unit("1")
            .describe("Rms surface (m) of a unit focus_mode_coefficient (m)"),
    );
    let pssn_grid_spacing = b.add_real(
        T::real("pssn_grid_spacing")
            .calculated_parameter()
            .unit("m")
            .describe("Spacing of the PSSN pupil grid (0 when PSSN is disabled)"),
    );
    let table = b.build()?;
    Ok((
        table,
        Vars {
            layout: layout_var,
            n_segments,
            z,
            rms_surface,
            focus_mode,
            rms_surface_without_focus,
            pssn,
            focus_mode_coefficient,
            metrics_rate,
            pssn_rate,
            wavelength,
            r0,
            outer_scale,
            pssn_samples,
            actuator_radius,
            focus_rms_per_unit,
            pssn_grid_spacing,
        },
    ))
}

impl Optics {
    fn setup(&self, v: &Values) -> Setup {
        let x = &self.vars;
        let pssn = (v.scalar(x.pssn_rate) > 0.0).then(|| {
            (
                usize::try_from(v.integer(x.pssn_samples)).unwrap_or(0),
                v.scalar(x.wavelength),
                v.scalar(x.r0),
                v.scalar(x.outer_scale),
            )
        });
        Setup {
            actuator_radius: v.scalar(x.actuator_radius),
            pssn,
        }
    }

    /// The evaluators for the current parameters, built unless already there.
    fn engine(&mut self, v: &Values) -> Result<Arc<Engine>, FmuError> {
        let setup = self.setup(v);
        if let Some(e) = &self.engine
            && e.setup == setup
        {
            return Ok(e.clone());
        }
        let layout =
            Layout::preset(&self.layout).map_err(|e| FmuError::Instantiate(e.to_string()))?;
        let mut params = GeometryParams::for_layout(&layout);
        params.actuator_radius = setup.actuator_radius;
        let geometry = Geometry::new(&layout, params).map_err(model_error)?;
        let metrics = MirrorMetrics::new(&geometry).map_err(model_error)?;
        let pssn = match setup.pssn {
            Some((samples, wavelength, r0, l0)) => Some(
                Pssn::new(
                    &layout,
                    PssnParams {
                        samples,
                        wavelength,
                        r0,
                        l0,
                        ..PssnParams::default()
                    },
                )
                .map_err(model_error)?,
            ),
            None => None,
        };
        let engine = Arc::new(Engine {
            setup,
            metrics,
            pssn,
        });
        self.engine = Some(engine.clone());
        Ok(engine)
    }

    fn sample_metrics(&self, e: &Engine, v: &mut Values) -> Result<(), FmuError> {
        let m = e
            .metrics
            .evaluate(v.real(self.vars.z))
            .map_err(model_error)?;
        v.real_mut(self.vars.rms_surface)[0] = m.rms;
        v.real_mut(self.vars.focus_mode)[0] = m.focus_rms;
        v.real_mut(self.vars.focus_mode_coefficient)[0] = m.focus;
        v.real_mut(self.vars.rms_surface_without_focus)[0] = m.rms_without_focus;
        Ok(())
    }

    fn sample_pssn(&mut self, e: &Engine, v: &mut Values) -> Result<(), FmuError> {
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

    /// The metrics evaluator, once initialised (for in-process use and tests).
    pub fn metrics(&self) -> Option<&MirrorMetrics> {
        self.engine.as_deref().map(|e| &e.metrics)
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
        let (table, vars) = table(&layout)?;
        Ok((
            table,
            Optics {
                vars,
                layout: layout.name.clone(),
                start_time: 0.0,
                metrics_clock: Clock::default(),
                pssn_clock: Clock::default(),
                engine: None,
                residual: Vec::with_capacity(layout.n_segments()),
            },
        ))
    }

    fn initialize(&mut self, v: &mut Values, start_time: f64) -> Result<(), FmuError> {
        let engine = self.engine(v)?;
        self.start_time = start_time;
        self.metrics_clock = Clock {
            rate: v.scalar(self.vars.metrics_rate),
            next: 1,
        };
        self.pssn_clock = Clock {
            rate: v.scalar(self.vars.pssn_rate),
            next: 1,
        };
        v.real_mut(self.vars.focus_rms_per_unit)[0] = engine.metrics.focus_rms_per_unit();
        v.real_mut(self.vars.pssn_grid_spacing)[0] =
            engine.pssn.as_ref().map_or(0.0, |p| p.grid().spacing());
        self.sample_metrics(&engine, v)?;
        self.sample_pssn(&engine, v)
    }

    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // No output depends directly on the input: they change only at sample instants.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let engine = self.engine(v)?;
        let end = t + h;
        // Work on copies of the clocks so that a failed step leaves the model unchanged.
        let (mut mc, mut pc) = (self.metrics_clock, self.pssn_clock);
        if mc.due(self.start_time, end) {
            self.sample_metrics(&engine, v)?;
        }
        if pc.due(self.start_time, end) {
            self.sample_pssn(&engine, v)?;
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
}

//! Model wiring of the mirror FMUs: every segment of one actuator variant and the telescope
//! structure, solved together at every servo sample ([`m1::plant::mirror::CoupledMirror`]). The
//! parameters are those of the segments FMU of the same variant plus those of the structure FMU,
//! and `quasi_static`, which swaps in the quasi-static plant for wind studies
//! ([`m1::plant::static_mirror::QuasiStaticMirror`]).
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `u_cmd` | input | na | m |
//! | `f_wind` | input | na | N |
//! | `pier_z` | input | 1 | m |
//! | `z` | output (no direct dependency on inputs) | na | m |
//! | `z_cell` | output (no direct dependency on inputs) | na | m |
//! | `f_cell` | output (no direct dependency on inputs) | na | N |
//!
//! with na = 3 x the number of segments of the packaged layout (actuator k of segment i at
//! index 3 i + k, 1-based in FMI names: `z[3 i + k + 1]`).
//!
//! `z_cell` and `f_cell` are computed when they are read ([`fmu::Running::on_demand`]): a
//! master that only reads `z` (the standard system) saves a pass over the mode shapes per
//! step (TMT, 300 modes: about a tenth of the mirror's step); one that reads them gets the
//! values of the current state, as always.
//!
//! Why a combined FMU: exchanged between a segments FMU and a structure FMU, the stiff actuator
//! coupling lags one communication step on each side and diverges unless the step is far below
//! a millisecond (and, for the piezo, at any step tried). See [`m1::plant::mirror`].

use std::marker::PhantomData;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use fmu::{
    BoolVar, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, Running, StrVar,
    TableBuilder as T, Values, VariableTable,
};
use m1::aperture::layout::Layout;
use m1::plant::mirror::CoupledMirror;
use m1::plant::static_mirror::QuasiStaticMirror;
use segments::{ParamVars, PiezoVariant, Variant, VoiceCoilVariant};
use structure_model::CellVars;
use wiring::signals::{F_CELL, F_WIND, PIER_Z, U_CMD, Z, Z_CELL, layout_decl, n_segments_decl};

/// The facts of a mirror FMU of one actuator variant.
pub trait MirrorVariant: Variant {
    /// Static facts of the FMU.
    const MIRROR_INFO: ModelInfo;
    /// Default coupled sub-steps per servo period: the first, 150 N/um piezo stacks needed two
    /// to stay within 1 % of the exact coupling at a 30 Hz pier tone (Keck: 1.5 % with one,
    /// 0.36 % with two), kept for the piezo; the voice coil is within 2e-5 with one.
    const COUPLING_SUBSTEPS: i32;
}

const DOC: &str = "<h2>Model</h2><p>Every segment on its three actuators (as in the segments \
FMU of the same variant: rigid mirror, actuator node, segment support, drive, 5 kHz encoder PID) \
mounted on the telescope structure (as in the structure FMU: modal model of the built-in mirror \
cell or of an imported FE model, pier base excitation). The two are solved <b>together at every servo sample</b>: per servo period the \
segment channels and the retained modes are advanced exactly (matrix exponentials) with the cell \
displacement and the modal forces varying linearly over the period, and the end values are made \
consistent by one r&times;r linear solve (r retained modes; the matrix is inverted once). The \
servo's drive and the pier input are held over the period; <code>coupling_substeps</code> \
solves the coupling that many times per period (default 1 for the voice coil, 2 for the stiff \
piezo; measured on Keck against the exact discretisation at a 30 Hz pier tone: voice coil \
9e-6, piezo 1.4e-4).</p>\
<p><b>Retained modes only.</b> Unlike the structure FMU, no static correction is added for the \
truncated modes: that instantaneous, dense compliance cannot lag a servo period against the \
stiff actuators (it diverges) and solving it implicitly would cost O(na<sup>2</sup>) per period. \
The response converges with the retained modes instead (Keck, pier tone at 5 and 29.6 Hz: \
less than 0.03 % between 30 modes and all 109); raise <code>n_modes</code> for a stiffer check.</p>\
<p><b>Why one FMU.</b> Exchanged between two FMUs at a communication step, the actuator forces \
and the cell displacement each lag by a step; with the stiff actuator coupling that delay \
destabilises the loop (measured on Keck with every mode: Gauss-Seidel exchange diverges at \
0.5 ms for the voice coil, and for the piezo at every step tried down to 0.1 ms).</p>\
<p><b>Communication step.</b> Any positive multiple of the servo period (default 0.2 ms at \
5 kHz); results do not depend on it. No output depends directly on the inputs. The FMU starts \
at rest, undeformed. <code>z_cell</code> and <code>f_cell</code> are computed when read (a \
master that reads only <code>z</code> saves their pass over the mode shapes).</p>\
<p><b>Quasi-static, for wind</b> (<code>quasi_static</code> = true; seed paper, section 4.1): \
the structure without inertia (its exact static response to the actuator forces and the pier) \
and each segment chain reduced to its low-frequency behaviour: the static equilibrium of the \
chain and the servo's proportional and leaky integral action, one state per channel, \
integrated exactly over each step. It follows the dynamic plant within 0.2 % for a 0.2 Hz \
load and 2 % at 1 Hz (Keck), ignores everything faster (cell modes, servo and support \
resonances: not for vibration or CSI) and accepts any positive step.</p>";

impl MirrorVariant for VoiceCoilVariant {
    const MIRROR_INFO: ModelInfo = ModelInfo {
        model_identifier: "mirror_voicecoil",
        model_name: "M1 on voice-coil actuators and its cell",
        description: "Every segment on three soft voice-coil actuators (5 kHz encoder PID) coupled \
            at every servo sample to the telescope structure (modal model, pier \
            excitation)",
        documentation: DOC,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };
    const COUPLING_SUBSTEPS: i32 = 1;
}

impl MirrorVariant for PiezoVariant {
    const MIRROR_INFO: ModelInfo = ModelInfo {
        model_identifier: "mirror_piezo",
        model_name: "M1 on piezo actuators and its cell",
        description: "Every segment on three hard piezo actuators (5 kHz-sampled integral servo, \
            optional LR shunt) coupled at every servo sample to the telescope structure (modal \
            model, pier excitation)",
        documentation: DOC,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };
    const COUPLING_SUBSTEPS: i32 = 2;
}

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars<V: MirrorVariant>(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        u_cmd: RealVar = U_CMD.input(layout),
        f_wind: RealVar = F_WIND.input(layout),
        pier_z: RealVar = PIER_Z.input(layout),
        z: RealVar = Z.output(layout).depends(Dependencies::None),
        z_cell: RealVar = Z_CELL.output(layout).depends(Dependencies::None),
        f_cell: RealVar = F_CELL.output(layout).depends(Dependencies::None),
        substeps: IntVar = T::integer("coupling_substeps")
            .parameter()
            .start_int(V::COUPLING_SUBSTEPS)
            .positive()
            .describe(
                "Coupled solves per servo period: 1 solves segments and structure together at \
                 every servo sample; more also between samples (second order: each doubling \
                 divides the coupling error by 4, for about twice the cost of a period)",
            ),
        segments: ParamVars => ParamVars::add_to::<V>(b, &V::defaults()),
        cell: CellVars => CellVars::add_to(b, DEFAULT_MODES),
        quasi_static: BoolVar = T::boolean("quasi_static")
            .parameter()
            .start_bool(false)
            .describe(
                "Quasi-static plant for wind studies: static structure, each segment chain \
                 reduced to its low-frequency stiffness and servo integrator (any step; nothing \
                 faster than about 1 Hz is modelled)",
            ),
        solver_threads: IntVar = T::integer("solver_threads")
            .parameter()
            .start_int(0)
            .non_negative()
            .describe(
                "Threads of the coupled solver's large products: 1 keeps them on the thread \
                 that calls fmi2DoStep, 2 splits them with a helper thread (the same results to \
                 the bit), 0 chooses 2 from 500 retained modes (where one core's cache \
                 bandwidth bounds the step), from 150 whichever of 1 and 2 a timed trial finds \
                 faster (every 1000 steps), and 1 below. Set 1 when other simulations already \
                 occupy every core",
            ),
    }
}

/// The solver behind a mirror FMU (boxed: their sizes differ by a factor of fifteen).
#[derive(Debug, Clone, Serialize, Deserialize)]
enum Solver {
    Coupled(Box<CoupledMirror>),
    QuasiStatic(Box<QuasiStaticMirror>),
}

/// The mirror FMU of one actuator variant, as configured; [`MirrorRunning`] steps.
#[derive(Debug, Clone)]
pub struct Mirror<V: MirrorVariant> {
    vars: Vars,
    layout: String,
    n_segments: usize,
    resource_dir: Option<PathBuf>,
    _v: PhantomData<V>,
}

/// An initialised mirror FMU: the solver and the handles it reads and writes.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MirrorRunning {
    vars: Vars,
    solver: Solver,
    /// `z_cell` and `f_cell`: computed when read (a master of the standard system never does).
    on_demand: [std::ops::Range<u32>; 2],
}

/// The `mirror_voicecoil` FMU.
pub type VoiceCoil = Mirror<VoiceCoilVariant>;
/// The `mirror_piezo` FMU.
pub type Piezo = Mirror<PiezoVariant>;

/// Retained modes by default: the response to the pier and the wind converges with few modes
/// (measured on Keck), and the cost of a servo period grows linearly with the count.
pub const DEFAULT_MODES: i32 = 60;

impl MirrorRunning {
    /// The mirror's displacement, the output every system reads (written in place).
    fn write_outputs(&self, v: &mut Values) {
        let z = v.real_mut(self.vars.z);
        match &self.solver {
            Solver::Coupled(m) => m.mirror(z),
            Solver::QuasiStatic(m) => m.mirror(z),
        }
    }

    /// The cell's displacement and force (the coupled solver computes them on this call).
    fn write_cell_outputs(&mut self, v: &mut Values) {
        let (z_cell, f_cell) = match &mut self.solver {
            Solver::Coupled(m) => m.cell_outputs(),
            Solver::QuasiStatic(m) => (m.cell_displacement(), m.cell_force()),
        };
        v.real_mut(self.vars.z_cell).copy_from_slice(z_cell);
        v.real_mut(self.vars.f_cell).copy_from_slice(f_cell);
    }

    /// The coupled solver, unless `quasi_static` is set (for in-process use and tests).
    pub fn solver(&self) -> Option<&CoupledMirror> {
        match &self.solver {
            Solver::Coupled(m) => Some(&**m),
            Solver::QuasiStatic(_) => None,
        }
    }

    /// The quasi-static solver, when `quasi_static` is set.
    pub fn quasi_static_solver(&self) -> Option<&QuasiStaticMirror> {
        match &self.solver {
            Solver::QuasiStatic(m) => Some(&**m),
            Solver::Coupled(_) => None,
        }
    }
}

impl<V: MirrorVariant> Model for Mirror<V> {
    const INFO: ModelInfo = V::MIRROR_INFO;

    type Running = MirrorRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to::<V>(b, &layout))?;
        let model = Self {
            vars,
            layout: variant.to_string(),
            n_segments: layout.n_segments(),
            resource_dir: None,
            _v: PhantomData,
        };
        Ok((table, model))
    }

    fn set_resource_dir(&mut self, dir: &Path) {
        self.resource_dir = Some(dir.to_path_buf());
    }

    fn initialize(&self, v: &mut Values, _start_time: f64) -> Result<MirrorRunning, FmuError> {
        let model = self.vars.segments.model(v);
        let cell = self.vars.cell.modal_model(
            v,
            &self.layout,
            3 * self.n_segments,
            self.resource_dir.as_deref(),
        )?;
        let (n_modes, damping) = self.vars.cell.modes_and_damping(v);
        let substeps = u32::try_from(v.integer(self.vars.substeps)).unwrap_or(0);
        let solver = if v.boolean(self.vars.quasi_static) {
            let m = QuasiStaticMirror::new(self.n_segments, model.clone(), cell, n_modes)
                .map_err(wiring::model_error)?;
            self.vars.cell.write_calculated(v, m.structure());
            Solver::QuasiStatic(Box::new(m))
        } else {
            let mut m = CoupledMirror::new(
                self.n_segments,
                model.clone(),
                cell,
                n_modes,
                damping,
                substeps,
            )
            .map_err(wiring::model_error)?;
            match v.integer(self.vars.solver_threads) {
                0 => {}
                1 => m.set_two_threads(false),
                2 => m.set_two_threads(true),
                n => {
                    return Err(FmuError::BadValue {
                        variable: "solver_threads".into(),
                        value: n.to_string(),
                        reason: "is not 0 (automatic), 1 or 2".into(),
                    });
                }
            }
            self.vars.cell.write_calculated(v, m.structure());
            Solver::Coupled(Box::new(m))
        };
        self.vars.segments.write_calculated(v, &model);
        let range = |r: RealVar| r.slot as u32..(r.slot + r.len) as u32;
        let mut running = MirrorRunning {
            vars: self.vars,
            solver,
            on_demand: [range(self.vars.z_cell), range(self.vars.f_cell)],
        };
        running.write_outputs(v);
        running.write_cell_outputs(v);
        Ok(running)
    }
}

impl Running for MirrorRunning {
    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        // No direct feedthrough: new inputs change nothing until the next step.
        self.write_outputs(v);
        Ok(())
    }

    fn do_step(&mut self, _t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let vars = self.vars;
        let (u, f, p) = (
            v.real(vars.u_cmd),
            v.real(vars.f_wind),
            v.scalar(vars.pier_z),
        );
        match &mut self.solver {
            Solver::Coupled(m) => m.advance(h, u, f, p),
            Solver::QuasiStatic(m) => m.advance(h, u, f, p),
        }
        .map_err(wiring::model_error)?;
        self.write_outputs(v);
        Ok(())
    }

    fn on_demand(&self) -> &[std::ops::Range<u32>] {
        &self.on_demand
    }

    fn write_on_demand(&mut self, v: &mut Values) -> Result<(), FmuError> {
        self.write_cell_outputs(v);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;

    #[test]
    fn tables_build_and_share_the_signals_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = VoiceCoil::new(variant).expect("voice coil");
            let (p, _) = Piezo::new(variant).expect("piezo");
            let na = Layout::preset(variant).expect("layout").n_actuators();
            for (name, len) in [
                ("u_cmd", na),
                ("f_wind", na),
                ("pier_z", 1),
                ("z", na),
                ("z_cell", na),
                ("f_cell", na),
            ] {
                let a = t.by_name(name).expect("voice coil signal");
                let b = p.by_name(name).expect("piezo signal");
                assert_eq!((a.len, a.vr, &a.unit), (len, b.vr, &b.unit));
            }
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        let doc = include_str!("lib.rs");
        assert_eq!(wiring::check_documented_signals::<VoiceCoil>(doc), Ok(()));
        assert_eq!(wiring::check_documented_signals::<Piezo>(doc), Ok(()));
    }

    /// A serialised FMU state steps on exactly as the instance it was taken from.
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let (table, _) = VoiceCoil::new("keck").expect("table");
        let guid = fmu::xml::guid(&VoiceCoil::INFO, &table);
        let mut fmu = Instance::<VoiceCoil>::new("test", &guid, None, None, false).expect("new");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        fmu.exit_initialization_mode().expect("initialise");
        assert!(fmu.running().expect("running").solver().is_some());
        let f = fmu.table().by_name("f_wind").expect("f_wind").vr;
        fmu.set_real(&[f], &[10.0]).expect("set f_wind");
        let z = fmu.table().by_name("z").expect("z");
        let z: Vec<u32> = (z.vr..z.vr + z.len as u32).collect();
        let run = |fmu: &mut Instance<VoiceCoil>, steps: usize| {
            for _ in 0..steps {
                let t = fmu.time();
                fmu.do_step(t, 1e-3).expect("step");
            }
            let mut out = vec![f64::NAN; z.len()];
            fmu.get_real(&z, &mut out).expect("get");
            out
        };
        run(&mut fmu, 2);
        let bytes =
            Instance::<VoiceCoil>::serialize(&fmu.get_state().expect("state")).expect("serialise");
        let original = run(&mut fmu, 3);
        let state = fmu.deserialize(&bytes).expect("deserialise");
        fmu.set_state(&state).expect("set state");
        assert_eq!(run(&mut fmu, 3), original);
        assert!(original.iter().any(|&x| x != 0.0));
    }

    /// `solver_threads`: 2 gives the mirror's displacement and the cell's outputs of 1 to the
    /// bit, 0 follows the retained modes, and any other value is refused at initialisation
    /// with the variable named.
    #[test]
    fn solver_threads_change_no_value_and_bad_ones_are_refused() {
        let (table, _) = VoiceCoil::new("keck").expect("table");
        let guid = fmu::xml::guid(&VoiceCoil::INFO, &table);
        let threads = table.by_name("solver_threads").expect("solver_threads").vr;
        let start = |n: i32| {
            let mut fmu =
                Instance::<VoiceCoil>::new("test", &guid, None, None, false).expect("new");
            fmu.setup_experiment(0.0, None).expect("setup");
            fmu.enter_initialization_mode().expect("initialisation");
            fmu.set_integer(&[threads], &[n])
                .expect("set solver_threads");
            fmu.exit_initialization_mode().map(|()| fmu)
        };
        let refs: Vec<u32> = ["z", "z_cell", "f_cell"]
            .iter()
            .flat_map(|name| {
                let v = table.by_name(name).expect(name);
                v.vr..v.vr + v.len as u32
            })
            .collect();
        let f = table.by_name("f_wind").expect("f_wind").vr;
        let run = |mut fmu: Instance<VoiceCoil>| {
            let two = fmu
                .running()
                .expect("running")
                .solver()
                .expect("coupled")
                .two_threads();
            fmu.set_real(&[f, f + 5], &[10.0, -4.0])
                .expect("set f_wind");
            for _ in 0..20 {
                let t = fmu.time();
                fmu.do_step(t, 1e-3).expect("step");
            }
            let mut out = vec![f64::NAN; refs.len()];
            fmu.get_real(&refs, &mut out).expect("get");
            (two, out)
        };
        let (one_threads, one) = run(start(1).expect("1"));
        let (two_threads, two) = run(start(2).expect("2"));
        let (auto_threads, _) = run(start(0).expect("0"));
        assert!(!one_threads && two_threads);
        assert_eq!(
            auto_threads,
            DEFAULT_MODES as usize >= m1::plant::mirror::TWO_THREADS_MIN_MODES
        );
        assert!(one.iter().any(|&x| x != 0.0));
        let same = one
            .iter()
            .zip(&two)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "two threads changed a value");
        let e = start(3).err().expect("3 refused").to_string();
        assert!(e.contains("solver_threads") && e.contains('3'), "{e}");
    }

    /// The cell's outputs, computed when read: read after every step, only at the end, one
    /// at a time, or after a saved state taken between reads was restored, they are the same
    /// values bit for bit, and they are the coupled solver's own.
    #[test]
    fn cell_outputs_read_on_demand_are_those_of_the_current_state() {
        let (table, _) = VoiceCoil::new("keck").expect("table");
        let guid = fmu::xml::guid(&VoiceCoil::INFO, &table);
        let new = || {
            let mut fmu =
                Instance::<VoiceCoil>::new("test", &guid, None, None, false).expect("new");
            fmu.setup_experiment(0.0, None).expect("setup");
            fmu.enter_initialization_mode().expect("initialisation");
            fmu.exit_initialization_mode().expect("initialise");
            let f = fmu.table().by_name("f_wind").expect("f_wind").vr;
            fmu.set_real(&[f, f + 5], &[10.0, -4.0])
                .expect("set f_wind");
            fmu
        };
        let refs = |name: &str| -> Vec<u32> {
            let v = table.by_name(name).expect(name);
            (v.vr..v.vr + v.len as u32).collect()
        };
        let (zc, fc, z) = (refs("z_cell"), refs("f_cell"), refs("z"));
        let get = |fmu: &mut Instance<VoiceCoil>, vrs: &[u32]| {
            let mut out = vec![f64::NAN; vrs.len()];
            fmu.get_real(vrs, &mut out).expect("get");
            out
        };
        let step = |fmu: &mut Instance<VoiceCoil>| {
            let t = fmu.time();
            fmu.do_step(t, 1e-3).expect("step");
        };
        let (mut every, mut end) = (new(), new());
        let mut saved = None;
        for k in 0..6 {
            step(&mut every);
            step(&mut end);
            let (a, b) = (get(&mut every, &zc), get(&mut every, &fc));
            assert!(a.iter().any(|&x| x != 0.0) && b.iter().any(|&x| x != 0.0));
            // Reading z alone leaves them to be computed later.
            assert_eq!(get(&mut end, &z), get(&mut every, &z));
            if k == 2 {
                saved = Some((end.get_state().expect("state"), a.clone(), b.clone()));
            }
        }
        // Scattered references (not one run): f_cell's first, then z_cell's last.
        let mixed = [fc[0], zc[zc.len() - 1]];
        let m = get(&mut end, &mixed);
        assert_eq!(
            m,
            [get(&mut every, &fc)[0], get(&mut every, &zc)[zc.len() - 1]]
        );
        assert_eq!(get(&mut end, &zc), get(&mut every, &zc));
        assert_eq!(get(&mut end, &fc), get(&mut every, &fc));
        let solver = every
            .running()
            .expect("running")
            .solver()
            .expect("coupled")
            .clone();
        let mut solver = solver;
        assert_eq!(solver.cell_force(), get(&mut every, &fc).as_slice());
        // A state saved with its cell outputs not yet computed gives the values of its time.
        let (state, a, b) = saved.expect("saved");
        end.set_state(&state).expect("restore");
        assert_eq!(get(&mut end, &fc), b);
        assert_eq!(get(&mut end, &zc), a);
    }

    #[test]
    fn keck_steps_and_refuses_a_step_off_the_servo_grid() {
        let (t, m) = VoiceCoil::new("keck").expect("keck");
        let mut v = t.initial_values();
        let mut r = m.initialize(&mut v, 0.0).expect("init");
        v.real_mut(m.vars.f_wind).fill(10.0);
        r.do_step(0.0, 1e-3, &mut v).expect("step");
        assert!(v.real(m.vars.z)[0] > 0.0, "{}", v.real(m.vars.z)[0]);
        let e = r
            .do_step(1e-3, 3e-4, &mut v)
            .expect_err("0.3 ms is not a multiple of 0.2 ms")
            .to_string();
        assert!(
            e.contains("communicationStepSize") && e.contains("servo"),
            "{e}"
        );
    }

    #[test]
    fn quasi_static_settles_on_the_static_stiffness_at_any_step() {
        let (t, m) = VoiceCoil::new("keck").expect("keck");
        let mut v = t.initial_values();
        *v.boolean_mut(m.vars.quasi_static) = true;
        let mut r = m.initialize(&mut v, 0.0).expect("init");
        assert!(r.solver().is_none());
        // A uniform push on every actuator (piston pattern) of 1 N: once the integrators have
        // settled, the glass moves with the cell plus 1 / static stiffness.
        v.real_mut(m.vars.f_wind).fill(1.0);
        for k in 0..200 {
            r.do_step(f64::from(k) * 0.07, 0.07, &mut v)
                .expect("a 70 ms step");
        }
        let model = r
            .quasi_static_solver()
            .expect("quasi-static")
            .model()
            .clone();
        let want = 1.0 / model.static_stiffness(m1::plant::segment::Channel::Piston);
        // The cell's outputs are written when read (the runtime calls this before a read).
        r.write_on_demand(&mut v).expect("cell outputs");
        let (z, zc) = (v.real(m.vars.z), v.real(m.vars.z_cell));
        for j in 0..z.len() {
            let rel = z[j] - zc[j];
            assert!((rel / want - 1.0).abs() < 1e-6, "{j}: {rel} vs {want}");
        }
        assert!(v.real(m.vars.f_cell).iter().all(|&f| f == 1.0));
        assert!(zc.iter().all(|&c| c > 0.0));
    }
}

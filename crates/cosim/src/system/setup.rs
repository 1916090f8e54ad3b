//! Setting a system up: [`Simulation::new`] checks the experiment, opens each FMU once, wires
//! and checks the connections (`wiring.rs`), instantiates every component with its parameters,
//! lets them leave initialisation mode in parallel (module docs, "Set-up"), decides which may
//! leave the master's thread, and publishes the initial outputs. Each phase is a function of
//! its own, in the order they run; the first error in that order is the one reported.

use std::time::Instant;

use super::definition::{Order, System, Value};
use super::init;
use super::ports::{CopyTrial, Port, Ports, SourcedRun, Values, sourced_runs};
use super::simulation::{KeptSink, Late, Memo, MemoPlan, Recorded, RecordedOf, Simulation};
use super::step::Running;
use super::threads::Lookahead;
use super::trial::Trials;
use super::wiring::{Kind, Recording, Wiring, var_of};
use crate::description::{ScalarVariable, VarType};
use crate::error::{CosimError, Result};
use crate::fmu::Fmu;
use crate::instance::Instance;

/// Sets parameter `v` of `inst` to `value` (`what` names it in the error).
fn set_value(inst: &mut Instance, v: &ScalarVariable, value: &Value, what: &str) -> Result<()> {
    let vr = [v.value_reference];
    let mismatch = |found: &str| CosimError::Mismatch {
        what: what.into(),
        reason: format!("{} is {:?}, the value is {found}", v.name, v.var_type),
    };
    match (v.var_type, value) {
        (VarType::Real, Value::Real(x)) => inst.set_real(&vr, &[*x]),
        (VarType::Real, Value::Integer(x)) => inst.set_real(&vr, &[f64::from(*x)]),
        (VarType::Integer | VarType::Enumeration, Value::Integer(x)) => {
            inst.set_integer(&vr, &[*x])
        }
        (VarType::Boolean, Value::Boolean(x)) => inst.set_boolean(&vr, &[*x]),
        (VarType::String, Value::String(x)) => inst.set_string(&vr, &[x.as_str()]),
        (_, Value::Real(_)) => Err(mismatch("Real")),
        (_, Value::Integer(_)) => Err(mismatch("Integer")),
        (_, Value::Boolean(_)) => Err(mismatch("Boolean")),
        (_, Value::String(_)) => Err(mismatch("String")),
    }
}

/// Checks the experiment (a positive step, the stop after the start) and the components
/// (unique names, rates of at least one base step), before any FMU is opened.
fn check_experiment(system: &System) -> Result<()> {
    if !(system.step > 0.0 && system.step.is_finite()) {
        return Err(CosimError::Invalid(format!(
            "communication step {} s must be positive",
            system.step
        )));
    }
    if system.stop_time.partial_cmp(&system.start_time) != Some(std::cmp::Ordering::Greater) {
        return Err(CosimError::Invalid(format!(
            "stop time {} s must be after start time {} s",
            system.stop_time, system.start_time
        )));
    }
    // The run advances on the base-step grid: a stop time between two points of it would make
    // the last step end past the stopTime the FMUs were given.
    let steps = (system.stop_time - system.start_time) / system.step;
    if (steps - steps.round()).abs() > 1e-6 * steps.max(1.0) {
        return Err(CosimError::Invalid(format!(
            "the run from {} s to {} s is {steps} base steps of {} s: make it a whole number \
             of steps",
            system.start_time, system.stop_time, system.step
        )));
    }
    let mut names = std::collections::HashSet::new();
    for c in &system.components {
        if !names.insert(c.name.as_str()) {
            return Err(CosimError::Invalid(format!(
                "component name {} is used twice",
                c.name
            )));
        }
        if c.every == 0 {
            return Err(CosimError::Invalid(format!(
                "{}: steps every 0 base steps; use 1 or more",
                c.name
            )));
        }
    }
    Ok(())
}

/// Opens each FMU once per distinct file, the files in parallel ([`Fmu::open_all`]): the FMUs,
/// and per component the index of its own.
fn open_fmus(system: &System) -> Result<(Vec<Fmu>, Vec<usize>)> {
    let mut paths: Vec<&std::path::Path> = Vec::new();
    let mut fmu_of = Vec::with_capacity(system.components.len());
    for c in &system.components {
        let k = match paths.iter().position(|p| *p == c.fmu.as_path()) {
            Some(k) => k,
            None => {
                paths.push(&c.fmu);
                paths.len() - 1
            }
        };
        fmu_of.push(k);
    }
    Ok((Fmu::open_all(&paths)?, fmu_of))
}

/// Instantiates component `c`, sets up its experiment and parameters and enters
/// initialisation mode; its ports are laid out by `wiring` (global slots `offsets[kind]`).
fn instantiate(
    system: &System,
    c: usize,
    fmu: &Fmu,
    wiring: &Wiring,
    offsets: &[Vec<usize>; 4],
) -> Result<Running> {
    let comp = &system.components[c];
    let t0 = Instant::now();
    let mut inst = fmu.instantiate(&comp.name, false)?;
    inst.setup_experiment(None, system.start_time, Some(system.stop_time))?;
    for (name, value) in &comp.parameters {
        let v = var_of(fmu, &comp.name, name)?;
        set_value(&mut inst, v, value, &format!("{}.{name}", comp.name))?;
    }
    inst.enter_initialization_mode()?;
    fn port<T: Clone + Default>(
        k: Kind,
        c: usize,
        wiring: &Wiring,
        offsets: &[Vec<usize>; 4],
    ) -> Port<T> {
        let off = &offsets[k as usize];
        let inputs = wiring.in_conn[k as usize][c]
            .iter()
            .map(|x| (x.0, off[x.1] + x.2))
            .collect();
        Port::new(inputs, wiring.out_vars[k as usize][c].clone(), off[c])
    }
    let mut real = port(Kind::Real, c, wiring, offsets);
    real.set_sources(&offsets[Kind::Real as usize]);
    let ports = Ports {
        real,
        integer: port(Kind::Integer, c, wiring, offsets),
        boolean: port(Kind::Boolean, c, wiring, offsets),
        string: port(Kind::String, c, wiring, offsets),
    };
    // Names of the Real variables by value reference, the first in document order of aliases
    // (a map: the TMT edge sensors publish 2772 outputs).
    let mut real_names = std::collections::HashMap::<u32, &str>::new();
    for v in fmu.description.variables.iter() {
        if v.var_type == VarType::Real {
            real_names
                .entry(v.value_reference)
                .or_insert(v.name.as_str());
        }
    }
    let out_names = ports
        .real
        .out_vrs
        .iter()
        .map(|&vr| {
            real_names
                .get(&vr)
                .map_or_else(|| format!("vr {vr}"), |n| (*n).to_string())
        })
        .collect();
    Ok(Running {
        name: comp.name.clone(),
        instance: inst,
        every: comp.every,
        ports,
        out_names,
        busy: 0.0,
        last: 0.0,
        // Until measured, assume a component is worth a thread.
        mean: f64::INFINITY,
        mean_weight: system.scheduler.mean_weight,
        setup: t0.elapsed().as_secs_f64(),
    })
}

/// Where the models get built: every component leaves initialisation mode, in parallel, one
/// instance per task; the first error in component order is reported.
fn exit_initialization(comps: &mut [Running]) -> Result<()> {
    use rayon::prelude::*;
    let exits: Vec<Result<()>> = comps
        .par_iter_mut()
        .map(|r| {
            let t0 = Instant::now();
            let out = r.instance.exit_initialization_mode();
            r.setup += t0.elapsed().as_secs_f64();
            out
        })
        .collect();
    exits.into_iter().collect::<Result<Vec<()>>>()?;
    Ok(())
}

/// Per component, whether it must stay on the master's thread in Gauss-Seidel order: another
/// instance of its FMU is in the system (instances of one library may share its global state,
/// and the sequential order never runs two of them at once).
fn stay_on_master(fmu_of: &[usize]) -> Vec<bool> {
    fmu_of
        .iter()
        .map(|f| fmu_of.iter().filter(|&g| g == f).count() > 1)
        .collect()
}

/// Per component, its recorded outputs.
fn recorded_of(n: usize, rec_local: &[Recording]) -> RecordedOf {
    let mut of = vec![Vec::new(); n];
    for (c, r) in rec_local.iter().enumerate() {
        of[r.component].push((c, r.kind, r.slot));
    }
    of
}

impl Simulation {
    /// Opens every FMU, instantiates and initialises every component, applies parameters and
    /// checks every connection (names, types, causalities, sizes, units). `record` lists
    /// signals to record as "component.signal" (arrays by base name), or patterns with `*`
    /// and `?` matched against every output (`mirror.z[*]`, `*.rms_surface`). The scheduler's
    /// thresholds are the system's ([`System::scheduler`]).
    ///
    /// # Errors
    /// Naming the component, variable or connection at fault.
    pub fn new(system: &System, record: &[String]) -> Result<Self> {
        check_experiment(system)?;
        let (fmus, fmu_of) = open_fmus(system)?;
        // Output slots: every connected or recorded output signal of each component.
        let mut wiring = Wiring::connect(system, &fmus, &fmu_of)?;
        let rec_local = wiring.record(system, &fmus, &fmu_of, record)?;
        let offsets = Kind::ALL.map(|k| wiring.offsets(k));
        // Instantiate, set parameters, initialise.
        let mut comps = Vec::with_capacity(system.components.len());
        for c in 0..system.components.len() {
            comps.push(instantiate(system, c, &fmus[fmu_of[c]], &wiring, &offsets)?);
        }
        if !system.zero_start {
            init::propagate(system, &fmus, &fmu_of, &wiring, &mut comps)?;
        }
        exit_initialization(&mut comps)?;
        let stay_on_master = stay_on_master(&fmu_of);
        let recorded_of = recorded_of(comps.len(), &rec_local);
        let slots: Vec<(Kind, usize)> = rec_local
            .iter()
            .map(|r| (r.kind, offsets[r.kind as usize][r.component] + r.slot))
            .collect();
        let recorded = Recorded {
            columns: rec_local.iter().map(|r| r.column.clone()).collect(),
            runs: Recorded::runs_of(&slots),
            slots,
        };
        let mut sim = Self::assemble(
            system,
            comps,
            &wiring,
            stay_on_master,
            (recorded, recorded_of),
            fmus,
        )?;
        // The initial outputs feed the first step (or zeros, fmpy.ssp's convention).
        if !system.zero_start {
            for c in 0..sim.comps.len() {
                sim.read_outputs(c)?;
            }
        }
        Ok(sim)
    }

    /// The simulation at the start time from its initialised components, with the look-ahead
    /// thread started for Gauss-Seidel (unless turned off, or with a single component).
    fn assemble(
        system: &System,
        comps: Vec<Running>,
        wiring: &Wiring,
        stay_on_master: Vec<bool>,
        (recorded, recorded_of): (Recorded, RecordedOf),
        fmus: Vec<Fmu>,
    ) -> Result<Self> {
        let n = comps.len();
        let total = Kind::ALL.map(|k| wiring.offsets(k)[n]);
        let lookahead = if n > 1 && !system.no_lookahead {
            Some(Lookahead::start(n)?)
        } else {
            None
        };
        let sources = wiring.sources();
        let real_offsets = wiring.offsets(Kind::Real);
        let real_runs: Vec<Vec<SourcedRun>> = comps
            .iter()
            .map(|r| sourced_runs(r.ports.real.in_runs(), &real_offsets))
            .collect();
        let sinks: Vec<Option<KeptSink>> = comps
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let read = sources.iter().any(|s| s.binary_search(&i).is_ok());
                let p = &r.ports;
                let only_real = !p.has_other_inputs();
                (!read && !stay_on_master[i] && r.every == 1 && only_real).then(|| KeptSink {
                    inputs: p.real.in_vrs.len(),
                    plans: (0..n)
                        .filter(|&j| j != i)
                        .filter_map(|j| MemoPlan::new(j, &real_runs[i], &real_runs[j]))
                        .collect(),
                    ..KeptSink::default()
                })
            })
            .collect();
        let memo_for = (0..n)
            .map(|j| {
                sinks
                    .iter()
                    .flatten()
                    .any(|k| k.plans.iter().any(|p| p.from == j))
            })
            .collect();
        let lazy = comps
            .iter()
            .enumerate()
            .map(|(i, r)| {
                system.order == Order::GaussSeidel && r.every == 1 && recorded_of[i].is_empty()
            })
            .collect();
        Ok(Self {
            lazy,
            real_runs,
            seen: vec![0; n],
            memo_for,
            memo: Memo {
                from: None,
                seen: vec![0; n],
            },
            memo_steps: 0,
            copy_trial: CopyTrial::default(),
            set_unchanged_inputs: system.set_unchanged_inputs,
            stale: vec![false; n],
            every: comps.iter().map(|r| r.every as u64).collect(),
            names: comps.iter().map(|r| r.name.clone()).collect(),
            comps: comps.into_iter().map(|r| Some(Box::new(r))).collect(),
            sources,
            sinks,
            recorded_of,
            late_rows: false,
            late: Late::default(),
            stay_on_master,
            trials: lookahead.as_ref().and_then(|_| {
                Trials::new(
                    system.scheduler.lookahead_trial_every,
                    system.scheduler.lookahead_trial_block,
                )
            }),
            lookahead_steps_before: 0,
            lookahead,
            lookahead_failed_at: None,
            params: system.scheduler,
            parallel_steps: 0,
            outputs: Values::zeroed(total),
            pending: vec![None; n],
            visible: 0,
            order: system.order,
            step: system.step,
            time: system.start_time,
            start: system.start_time,
            stop: system.stop_time,
            n_steps: 0,
            fmu_critical: 0.0,
            recorded,
            _fmus: fmus,
        })
    }
}

//! Two threads for the mirror's large streaming products: [`Pair::join`] runs one closure on
//! the calling thread and another on a helper thread at once, and returns when both are done.
//!
//! # Why not rayon
//!
//! A coupled TMT step at 1000 modes makes about a dozen such joins per millisecond, each
//! around a product of 50-130 us. Rayon's workers sleep between them, and waking one costs
//! 50-150 us on the project's 2-core machine (a `rayon::join` per product made the step six
//! times slower: BENCHMARKS.md, second round). Here the helper polls for its next job for
//! [`SPIN`] after each one (yielding the core now and then, so that another thread with work on
//! it, such as a co-simulation master's look-ahead thread, runs), then sleeps; a join
//! then costs well under a microsecond when the helper is awake.
//!
//! When the helper has not started its half by the time the caller's is done (the cores busy
//! with other work, e.g. parallel runs of a parameter sweep), the caller runs it too: a busy
//! machine costs the split its gain, never a wait for the helper to be scheduled.
//!
//! Each half reads the other's inputs only after the join, so the results do not depend on
//! the split: a product split by rows gives every row the same arithmetic as on one thread.

use std::cell::UnsafeCell;
use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// How long the helper polls for its next job before it sleeps.
pub const SPIN: Duration = Duration::from_micros(300);

/// A job posted to the helper: a closure on the caller's stack, its lifetime erased. It is
/// valid until the helper reports it finished, which [`Pair::join`] waits for.
struct JobPtr(*mut (dyn FnMut() + Send + 'static));

// SAFETY: the closure behind the pointer is `Send`; the pointer itself only crosses to the
// helper while the caller waits for it (see `Pair::join`).
unsafe impl Send for JobPtr {}

struct Shared {
    /// Jobs posted so far.
    posted: AtomicU64,
    /// The latest job claimed, by the helper or by the caller (which runs a job itself when
    /// the helper has not claimed it by the time its own half is done).
    claimed: AtomicU64,
    /// The latest job finished.
    finished: AtomicU64,
    /// The job of the latest post (written before `posted` is raised, taken by the helper
    /// before `finished` is).
    job: UnsafeCell<Option<JobPtr>>,
    sleeping: AtomicBool,
    stop: AtomicBool,
    panicked: AtomicBool,
}

// SAFETY: `job` is written only by the caller while the helper is not reading it (before a
// post, after the previous job finished) and read only by the helper between a post and
// its finish; the atomics order the two (Release/Acquire on `posted` and `finished`).
unsafe impl Sync for Shared {}

/// A calling thread and a helper thread (module docs). Dropping it stops the helper.
pub struct Pair {
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl std::fmt::Debug for Pair {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pair")
            .field("posted", &self.shared.posted.load(Ordering::Relaxed))
            .finish()
    }
}

impl Pair {
    /// Starts the helper thread; `None` if the system refuses a thread (the caller then runs
    /// both halves itself).
    pub fn start() -> Option<Self> {
        let shared = Arc::new(Shared {
            posted: AtomicU64::new(0),
            claimed: AtomicU64::new(0),
            finished: AtomicU64::new(0),
            job: UnsafeCell::new(None),
            sleeping: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            panicked: AtomicBool::new(false),
        });
        let theirs = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("m1-pair".into())
            .spawn(move || helper(&theirs))
            .ok()?;
        Some(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Runs `here` on this thread and `there` on the helper at once; returns when both are
    /// done. A panic in either is resumed here once both are done.
    pub fn join<A: FnOnce(), B: FnOnce() + Send>(&mut self, here: A, there: B) {
        let Some(thread) = self.thread.as_ref() else {
            here();
            there();
            return;
        };
        let mut there = Some(there);
        let mut call = move || {
            if let Some(f) = there.take() {
                f();
            }
        };
        let short: *mut (dyn FnMut() + Send + '_) = &mut call;
        // SAFETY: only the lifetime is erased; `call` outlives its use, since this function
        // does not return (nor unwind) before the helper has finished it.
        let long: *mut (dyn FnMut() + Send + 'static) = unsafe { std::mem::transmute(short) };
        let s = &*self.shared;
        // SAFETY: the helper does not read `job` now (every earlier job has finished).
        unsafe { *s.job.get() = Some(JobPtr(long)) };
        let n = s.posted.fetch_add(1, Ordering::SeqCst) + 1;
        if s.sleeping.load(Ordering::SeqCst) {
            thread.thread().unpark();
        }
        let mine = catch_unwind(AssertUnwindSafe(here));
        // A helper that has not claimed its half by now is not running (the cores are busy
        // with other work): this thread runs that half too, rather than wait for the system
        // to schedule the helper (a time slice, milliseconds).
        if s.claimed
            .compare_exchange(n - 1, n, Ordering::AcqRel, Ordering::Acquire)
            .is_ok()
        {
            // SAFETY: claimed here, so the helper does not touch the job.
            let job = unsafe { (*s.job.get()).take() };
            let theirs = job.map(|JobPtr(f)| {
                // SAFETY: `call` lives on this frame.
                catch_unwind(AssertUnwindSafe(|| unsafe { (*f)() }))
            });
            s.finished.store(n, Ordering::Release);
            if let Err(p) = mine {
                resume_unwind(p);
            }
            if let Some(Err(p)) = theirs {
                resume_unwind(p);
            }
            return;
        }
        let start = Instant::now();
        let mut polls = 0u32;
        while s.finished.load(Ordering::Acquire) != n {
            polls = polls.wrapping_add(1);
            // Past the spin, give the core away at each poll (the helper may share it).
            if polls.is_multiple_of(64) && start.elapsed() >= SPIN {
                std::thread::yield_now();
            } else {
                std::hint::spin_loop();
            }
        }
        if s.panicked.swap(false, Ordering::AcqRel) {
            panic!("the mirror's helper thread panicked during its half of a product");
        }
        if let Err(p) = mine {
            resume_unwind(p);
        }
    }

    /// The shortest wall time (ns) of `rounds` joins whose halves only wait for each other (the
    /// caller's for at most 200 us): the hand-over of a job to the helper and back, a few cache
    /// lines' round trips between the two threads' cores. It tells whether splitting small
    /// products pays: on the project's 2-core VM it is 0.24-0.33 us while the two cores share
    /// an L3 cache and 1.0-1.3 us while they sit on two (BENCHMARKS.md, twelfth round). The
    /// shortest, because other work on the cores (waking a sleeping helper, another thread
    /// polling) only adds to it; 200 us means the helper got no core in any round.
    pub fn handoff_ns(&mut self, rounds: usize) -> f64 {
        const PATIENCE: Duration = Duration::from_micros(200);
        let times: Vec<f64> = (0..rounds.max(1))
            .map(|_| {
                let started = AtomicBool::new(false);
                let t = Instant::now();
                self.join(
                    || {
                        let s = Instant::now();
                        while !started.load(Ordering::Acquire) && s.elapsed() < PATIENCE {
                            std::hint::spin_loop();
                        }
                    },
                    || started.store(true, Ordering::Release),
                );
                t.elapsed().as_secs_f64() * 1e9
            })
            .collect();
        times.into_iter().fold(f64::INFINITY, f64::min)
    }
}

fn helper(s: &Shared) {
    let mut seen = 0u64;
    loop {
        let mut start = Instant::now();
        let mut polls = 0u32;
        while s.posted.load(Ordering::Acquire) == seen {
            if s.stop.load(Ordering::Acquire) {
                return;
            }
            polls = polls.wrapping_add(1);
            if polls.is_multiple_of(64) && start.elapsed() >= SPIN {
                s.sleeping.store(true, Ordering::SeqCst);
                if s.posted.load(Ordering::SeqCst) == seen && !s.stop.load(Ordering::SeqCst) {
                    std::thread::park();
                }
                s.sleeping.store(false, Ordering::SeqCst);
                start = Instant::now();
            } else if polls.is_multiple_of(16) {
                // Now and then another thread with work on this core runs first.
                std::thread::yield_now();
            } else {
                std::hint::spin_loop();
            }
        }
        // The latest post (the caller ran the earlier ones itself if they were missed).
        seen = s.posted.load(Ordering::Acquire);
        if s.claimed
            .compare_exchange(seen - 1, seen, Ordering::AcqRel, Ordering::Acquire)
            .is_err()
        {
            continue;
        }
        // SAFETY: posted (Acquire above) after the caller wrote the job, and claimed here; the
        // caller does not touch it again before `finished` says so.
        let job = unsafe { (*s.job.get()).take() };
        if let Some(JobPtr(f)) = job {
            // SAFETY: the closure lives until `finished` reaches `seen` (`Pair::join` waits).
            let r = catch_unwind(AssertUnwindSafe(|| unsafe { (*f)() }));
            if r.is_err() {
                s.panicked.store(true, Ordering::Release);
            }
        }
        s.finished.store(seen, Ordering::Release);
    }
}

impl Drop for Pair {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

/// An optional [`Pair`], started when first wanted: what a model holds, cloned as not yet
/// started (a clone gets its own helper) and never serialised.
#[derive(Debug, Default)]
pub struct LazyPair {
    pair: Option<Pair>,
    failed: bool,
}

impl Clone for LazyPair {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl LazyPair {
    /// The pair, started now if it was not (None if no thread could be started).
    pub fn get(&mut self) -> Option<&mut Pair> {
        if self.pair.is_none() && !self.failed {
            self.pair = Pair::start();
            self.failed = self.pair.is_none();
        }
        self.pair.as_mut()
    }

    /// Stops the helper, if it runs.
    pub fn stop(&mut self) {
        self.pair = None;
    }
}

/// The median time (ns) for a value to go from this thread to another spinning thread and back
/// (a cache line's round trip between the two cores they run on), over 20 rounds of 2000: the
/// least a hand-over of work to another thread and its reply cost. On the project's 2-core VM it
/// tells where the host put the two virtual cores: about 60 ns on one L3 cache, about 300 ns on
/// two, 30-50 ns on the two hardware threads of one core (BENCHMARKS.md, twelfth round). For
/// benchmarks and examples; it spins a thread for a few milliseconds.
pub fn round_trip_ns() -> f64 {
    const ROUNDS: usize = 20;
    const TRIPS: u64 = 2000;
    let ping = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
    let other = Arc::clone(&ping);
    let echo = std::thread::spawn(move || {
        for i in 1..=ROUNDS as u64 * TRIPS {
            while other[0].load(Ordering::Acquire) != i {
                std::hint::spin_loop();
            }
            other[1].store(i, Ordering::Release);
        }
    });
    let mut times = Vec::with_capacity(ROUNDS);
    let mut i = 0;
    for _ in 0..ROUNDS {
        let t = Instant::now();
        for _ in 0..TRIPS {
            i += 1;
            ping[0].store(i, Ordering::Release);
            while ping[1].load(Ordering::Acquire) != i {
                std::hint::spin_loop();
            }
        }
        times.push(t.elapsed().as_secs_f64() * 1e9 / TRIPS as f64);
    }
    let _ = echo.join();
    times.sort_by(f64::total_cmp);
    times[ROUNDS / 2]
}

#[cfg(test)]
mod tests {
    use super::Pair;

    #[test]
    fn both_halves_run_and_write_their_own_part() {
        let mut pair = Pair::start().expect("a thread");
        let mut data = vec![0u64; 1000];
        for round in 0..2000u64 {
            let (lo, hi) = data.split_at_mut(500);
            pair.join(
                || lo.iter_mut().for_each(|v| *v += round),
                || hi.iter_mut().for_each(|v| *v += 2 * round),
            );
            if round == 1000 {
                // Let the helper fall asleep once: the next join wakes it.
                std::thread::sleep(super::SPIN * 3);
            }
        }
        let s: u64 = (0..2000u64).sum();
        assert!(data[..500].iter().all(|&v| v == s));
        assert!(data[500..].iter().all(|&v| v == 2 * s));
    }

    /// With the helper asleep (past its spin, waking takes tens of microseconds) and the
    /// caller's own half empty, the caller claims the helper's half and runs it itself.
    #[test]
    fn the_caller_runs_a_half_the_helper_did_not_claim() {
        let mut pair = Pair::start().expect("a thread");
        let here = std::thread::current().id();
        let mut stolen = 0;
        for _ in 0..20 {
            std::thread::sleep(super::SPIN * 3);
            let mut ran_on = None;
            pair.join(|| {}, || ran_on = Some(std::thread::current().id()));
            assert!(ran_on.is_some());
            stolen += usize::from(ran_on == Some(here));
        }
        assert!(stolen > 0, "the caller never ran the helper's half");
    }

    #[test]
    fn a_panic_on_either_side_comes_back_after_both_are_done() {
        let mut pair = Pair::start().expect("a thread");
        let done = std::sync::atomic::AtomicBool::new(false);
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            pair.join(
                || {},
                || {
                    panic!("there");
                },
            )
        }));
        assert!(r.is_err());
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            pair.join(
                || panic!("here"),
                || {
                    std::thread::sleep(std::time::Duration::from_millis(5));
                    done.store(true, std::sync::atomic::Ordering::SeqCst);
                },
            )
        }));
        assert!(r.is_err());
        assert!(done.load(std::sync::atomic::Ordering::SeqCst));
        // Still usable.
        let mut x = 0;
        let mut y = 0;
        pair.join(|| x = 1, || y = 2);
        assert_eq!((x, y), (1, 2));
    }
}

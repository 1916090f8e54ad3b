//! A one-way queue between the master and its look-ahead thread: `rtrb`'s wait-free ring of one
//! sender and one receiver, with a receive that polls and then sleeps.
//!
//! Why not `std::sync::mpsc`: its bounded channel takes a message with a locked
//! compare-and-swap on a line the polling receiver keeps reading, and the lock waits for the
//! message's own stores to reach the other core: 0.14-0.18 us per send on the project's 2-core
//! machine (BENCHMARKS.md, fifteenth round), twice per TMT step on the master's thread. The
//! ring publishes a message with a plain store (the receiver pays the transfer when it reads),
//! about 7 ns per send.
//!
//! A receiver that has polled for its `spin` sleeps ([`std::thread::park_timeout`]) and the
//! sender wakes it. The sender reads the sleeping flag without a fence (a fence would wait for
//! the message's stores again), so on a processor that lets a load pass an earlier store it may
//! miss a receiver falling asleep at that very moment. Such a receiver re-polls for a moment
//! after it raises the flag, and its naps are bounded ([`NAP_MAX`]): a missed wake-up costs at
//! most one nap, it never loses a message.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::Thread;
use std::time::{Duration, Instant};

/// The first nap of a sleeping receiver; each next one twice as long, up to [`NAP_MAX`].
const NAP_MIN: Duration = Duration::from_micros(50);

/// The longest nap of a sleeping receiver: what a missed wake-up can cost at most, and how
/// often an idle thread looks at its queue (a few microseconds per look).
const NAP_MAX: Duration = Duration::from_millis(2);

/// How long a receiver keeps polling after it raised its sleeping flag, for a message whose
/// sender read the flag before it was raised (far longer than a store takes to reach the other
/// core).
const LAST_POLL: Duration = Duration::from_micros(2);

/// Polls between two yields of the core while a receiver polls.
const YIELD_EVERY: u32 = 8;

/// What both ends share besides the ring.
struct Shared {
    /// The sender is gone: nothing more will come after what the ring holds.
    closed: AtomicBool,
    /// The receiver is gone: nothing sent will be read.
    gone: AtomicBool,
    /// The receiver sleeps, or is about to.
    sleeping: AtomicBool,
    /// The receiving thread, while it sleeps.
    receiver: Mutex<Option<Thread>>,
}

impl Shared {
    /// Wakes the receiver if it sleeps.
    #[cold]
    fn wake(&self) {
        let t = self.receiver.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(t) = t.as_ref() {
            t.unpark();
        }
    }
}

/// The sending end of a [`queue`].
pub(super) struct Sender<T> {
    ring: rtrb::Producer<T>,
    shared: Arc<Shared>,
}

/// The receiving end of a [`queue`].
pub(super) struct Receiver<T> {
    ring: rtrb::Consumer<T>,
    shared: Arc<Shared>,
}

/// A queue of room for `capacity` values in flight.
pub(super) fn queue<T>(capacity: usize) -> (Sender<T>, Receiver<T>) {
    let (tx, rx) = rtrb::RingBuffer::new(capacity);
    let shared = Arc::new(Shared {
        closed: AtomicBool::new(false),
        gone: AtomicBool::new(false),
        sleeping: AtomicBool::new(false),
        receiver: Mutex::new(None),
    });
    (
        Sender {
            ring: tx,
            shared: Arc::clone(&shared),
        },
        Receiver { ring: rx, shared },
    )
}

impl<T> Sender<T> {
    /// Sends `value`, or gives it back when the queue is full or its receiver is gone.
    pub(super) fn send(&mut self, value: T) -> Result<(), T> {
        if self.shared.gone.load(Ordering::Acquire) {
            return Err(value);
        }
        self.ring
            .push(value)
            .map_err(|rtrb::PushError::Full(v)| v)?;
        if self.shared.sleeping.load(Ordering::Relaxed) {
            self.shared.wake();
        }
        Ok(())
    }
}

impl<T> Drop for Sender<T> {
    fn drop(&mut self) {
        self.shared.closed.store(true, Ordering::SeqCst);
        if self.shared.sleeping.load(Ordering::SeqCst) {
            self.shared.wake();
        }
    }
}

/// What [`Receiver::try_recv`] found.
pub(super) enum TryRecv<T> {
    /// The next value.
    Ready(T),
    /// Nothing yet.
    Empty,
    /// Nothing, and the sender is gone.
    Closed,
}

impl<T> Receiver<T> {
    /// The next value if there is one, without waiting.
    pub(super) fn try_recv(&mut self) -> TryRecv<T> {
        if let Ok(v) = self.ring.pop() {
            return TryRecv::Ready(v);
        }
        if !self.shared.closed.load(Ordering::Acquire) {
            return TryRecv::Empty;
        }
        // Closed after its last send: that value is in the ring now.
        match self.ring.pop() {
            Ok(v) => TryRecv::Ready(v),
            Err(_) => TryRecv::Closed,
        }
    }

    /// The next value: polled for up to `spin`, then waited for (sleeping). `None` once the
    /// sender is gone and everything it sent has been read.
    pub(super) fn recv(&mut self, spin: Duration) -> Option<T> {
        let start = Instant::now();
        let mut polls = 0u32;
        loop {
            match self.try_recv() {
                TryRecv::Ready(v) => return Some(v),
                TryRecv::Closed => return None,
                TryRecv::Empty => {}
            }
            polls += 1;
            // The clock is read every 64 polls: cheap beside the poll, fine enough for the
            // limit.
            if polls.is_multiple_of(64) && start.elapsed() >= spin {
                return self.sleep();
            }
            // Now and then a thread with work on this core (an FMU's own helper thread) runs
            // first; a yield at every poll made the master's own core slower (a system call
            // per poll: the TMT mirror's step 10-15 % longer at 60 and 300 modes).
            if polls.is_multiple_of(YIELD_EVERY) {
                std::thread::yield_now();
            } else {
                std::hint::spin_loop();
            }
        }
    }

    /// Sleeps until the next value comes (or the sender goes), as the module docs say.
    #[cold]
    fn sleep(&mut self) -> Option<T> {
        *self
            .shared
            .receiver
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = Some(std::thread::current());
        self.shared.sleeping.store(true, Ordering::SeqCst);
        let raised = Instant::now();
        let mut nap = NAP_MIN;
        let out = loop {
            match self.try_recv() {
                TryRecv::Ready(v) => break Some(v),
                TryRecv::Closed => break None,
                TryRecv::Empty => {}
            }
            if raised.elapsed() < LAST_POLL {
                std::hint::spin_loop();
                continue;
            }
            std::thread::park_timeout(nap);
            nap = (nap * 2).min(NAP_MAX);
        };
        self.shared.sleeping.store(false, Ordering::Relaxed);
        out
    }
}

impl<T> Drop for Receiver<T> {
    fn drop(&mut self) {
        self.shared.gone.store(true, Ordering::Release);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_come_in_order_and_the_end_is_seen_after_them() {
        let (mut tx, mut rx) = queue::<u64>(4);
        let h = std::thread::spawn(move || {
            for i in 0..10_000u64 {
                let mut v = i;
                // Full: wait for room (the receiver sleeps now and then, below).
                while let Err(back) = tx.send(v) {
                    v = back;
                    std::thread::yield_now();
                }
                if i % 1000 == 0 {
                    std::thread::sleep(Duration::from_millis(3));
                }
            }
        });
        let mut next = 0;
        // A short spin, so that the receiver also sleeps and is woken.
        while let Some(v) = rx.recv(Duration::from_micros(20)) {
            assert_eq!(v, next);
            next += 1;
        }
        assert_eq!(next, 10_000, "every value before the end");
        h.join().unwrap();
    }

    #[test]
    fn a_full_queue_or_a_gone_receiver_gives_the_value_back() {
        let (mut tx, rx) = queue::<u8>(1);
        assert!(tx.send(1).is_ok());
        assert!(matches!(tx.send(2), Err(2)), "full");
        drop(rx);
        let (mut tx2, rx2) = queue::<u8>(1);
        drop(rx2);
        assert!(matches!(tx2.send(3), Err(3)), "receiver gone");
    }

    #[test]
    fn a_sleeping_receiver_gets_what_comes_later() {
        let (mut tx, mut rx) = queue::<u8>(1);
        let shared = Arc::clone(&tx.shared);
        let h = std::thread::spawn(move || rx.recv(Duration::ZERO));
        let t0 = Instant::now();
        while !shared.sleeping.load(Ordering::SeqCst) {
            assert!(
                t0.elapsed() < Duration::from_secs(10),
                "the receiver never slept"
            );
            std::thread::yield_now();
        }
        std::thread::sleep(Duration::from_millis(20));
        assert!(tx.send(7).is_ok());
        assert_eq!(h.join().unwrap(), Some(7));
        assert!(!shared.sleeping.load(Ordering::SeqCst), "awake again");
    }
}

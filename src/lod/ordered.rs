//! An ordered parallel pipeline for the level passes: items computed on
//! every core, their results consumed in item order on the calling thread
//! while the next items are computed.
//!
//! Takes: an item count, a window, an in-order input reader (`take`), the
//! per-item work (`compute`) and the in-order consumer (`consume`). Gives:
//! every item's result to `consume`, in order, or the first error.
//!
//! Why not rayon batches: a pass used to compute a batch of nodes with
//! `par_iter`, then write the batch's results on one thread. Each batch
//! ended waiting for its slowest node, and the writes ran with the other
//! core idle (`docs/build-costs.md`). Here workers take the next item as soon as they are free (at
//! most `window` items ahead of the consumer, which bounds memory like a
//! batch did), and the consumer writes while they compute.

use crate::error::Result;
use std::collections::BTreeMap;
use std::sync::{Condvar, Mutex};

struct State<F> {
    /// Next item to hand out.
    next: usize,
    /// Items consumed so far.
    consumed: usize,
    stop: bool,
    take: F,
}

struct StopOnPanic<'a, F>(&'a Mutex<State<F>>, &'a Condvar);

impl<F> Drop for StopOnPanic<'_, F> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.lock().unwrap_or_else(|e| e.into_inner()).stop = true;
            self.1.notify_all();
        }
    }
}

/// Runs `compute(i, take(i))` for `i` in `0..n` on the rayon pool's number
/// of threads and calls `consume(i, result)` in order of `i` on this
/// thread. `take` is called in order of `i` (under a lock: it may read a
/// file sequentially); at most `window` items are taken and not yet
/// consumed. Stops at the first error (of `take`, `compute` or `consume`)
/// and returns it.
pub fn ordered<I, T, Take, Comp, Cons>(n: usize, window: usize, take: Take, compute: Comp, mut consume: Cons) -> Result<()>
where
    I: Send,
    T: Send,
    Take: FnMut(usize) -> Result<I> + Send,
    Comp: Fn(usize, I) -> Result<T> + Sync,
    Cons: FnMut(usize, T) -> Result<()>,
{
    if n == 0 {
        return Ok(());
    }
    let threads = rayon::current_num_threads().clamp(1, n);
    let window = window.max(threads);
    let state = Mutex::new(State { next: 0, consumed: 0, stop: false, take });
    let ready = Condvar::new();
    let (tx, rx) = std::sync::mpsc::channel::<(usize, Result<T>)>();
    std::thread::scope(|scope| {
        for _ in 0..threads {
            let tx = tx.clone();
            let (state, ready, compute) = (&state, &ready, &compute);
            scope.spawn(move || {
                // A panicking worker stops the others (none waits for the
                // item it lost); the scope then passes the panic on.
                let _guard = StopOnPanic(state, ready);
                loop {
                    let (i, input) = {
                        let mut s = state.lock().unwrap_or_else(|e| e.into_inner());
                        while !s.stop && s.next < n && s.next >= s.consumed + window {
                            s = ready.wait(s).unwrap_or_else(|e| e.into_inner());
                        }
                        if s.stop || s.next >= n {
                            return;
                        }
                        let i = s.next;
                        s.next += 1;
                        (i, (s.take)(i))
                    };
                    let r = input.and_then(|x| compute(i, x));
                    if tx.send((i, r)).is_err() {
                        return;
                    }
                }
            });
        }
        drop(tx);
        // A panicking consumer stops the workers too (the scope waits for them).
        let _guard = StopOnPanic(&state, &ready);
        let mut waiting: BTreeMap<usize, Result<T>> = BTreeMap::new();
        let mut want = 0usize;
        let mut out = Ok(());
        'recv: while want < n {
            let Ok((i, r)) = rx.recv() else { break };
            waiting.insert(i, r);
            while let Some(r) = waiting.remove(&want) {
                // Each consumed item is a safe point for signals.
                let res = r.and_then(|t| consume(want, t)).and_then(|()| crate::io::signal::check());
                want += 1;
                state.lock().unwrap_or_else(|e| e.into_inner()).consumed = want;
                ready.notify_all();
                if let Err(e) = res {
                    out = Err(e);
                    break 'recv;
                }
            }
        }
        // Workers waiting for room (or about to take more) stop.
        state.lock().unwrap_or_else(|e| e.into_inner()).stop = true;
        ready.notify_all();
        out
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Error;

    #[test]
    fn results_come_in_order_with_inputs_taken_in_order() {
        let mut taken = Vec::new();
        let mut seen = Vec::new();
        let r = ordered(
            1000,
            8,
            |i| {
                taken.push(i);
                Ok(i * 3)
            },
            |i, x| {
                // Uneven work, so items finish out of order.
                let spins = (i * 7919) % 5000;
                let mut acc = 0u64;
                for k in 0..spins {
                    acc = acc.wrapping_add(k as u64 * x as u64);
                }
                Ok((i, x, acc))
            },
            |i, (j, x, _)| {
                assert_eq!(i, j);
                assert_eq!(x, 3 * i);
                seen.push(i);
                Ok(())
            },
        );
        assert!(r.is_ok());
        assert_eq!(seen, (0..1000).collect::<Vec<_>>());
        drop(r);
        assert_eq!(taken, (0..1000).collect::<Vec<_>>());
    }

    #[test]
    fn a_panicking_item_panics_the_caller_instead_of_hanging() {
        let r = std::panic::catch_unwind(|| ordered(1000, 4, Ok, |i, _| if i == 20 { panic!("item 20") } else { Ok(i) }, |_, _| Ok(())));
        assert!(r.is_err());
        let r = std::panic::catch_unwind(|| ordered(1000, 4, Ok, |i, _| Ok(i), |i, _| if i == 20 { panic!("consumer at 20") } else { Ok(()) }));
        assert!(r.is_err());
    }

    #[test]
    fn the_first_error_stops_the_pipeline() {
        let mut consumed = 0;
        let r = ordered(
            10_000,
            4,
            Ok,
            |i, _| if i == 50 { Err(Error::Usage("item 50".into())) } else { Ok(i) },
            |_, _| {
                consumed += 1;
                Ok(())
            },
        );
        assert!(matches!(r, Err(Error::Usage(m)) if m == "item 50"));
        assert_eq!(consumed, 50);
        let r = ordered(100, 4, Ok, |i, _| Ok(i), |i, _| if i == 7 { Err(Error::Usage("seven".into())) } else { Ok(()) });
        assert!(matches!(r, Err(Error::Usage(m)) if m == "seven"));
    }
}

//! A sequential stage cut in two and run on two threads: the first half
//! hands batches to the second over a bounded channel, in order, and the
//! second gives the emptied batches back to be filled again.
//!
//! Takes: a producer (run on the caller's thread) and a consumer (run on a
//! scoped thread) that agree on a batch type. Gives: both results, or the
//! first failure (the consumer's when it stopped first: the producer then
//! only saw the channel close).
//!
//! Why: the soup's phases 1 and 2 each ran on one thread (reading and
//! coding records, then appending them to bucket files) while the other
//! core waited; a pipeline keeps both busy without splitting the
//! delta-coded record streams, which must be written in order. Hand-written
//! over `std::sync::mpsc` (a dozen lines) rather than a crate: at most
//! `depth + 2` batches exist, so the memory it holds is known up front.

use crate::error::{Error, Result};
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};

/// The producer's end: batches go out in order; emptied ones come back.
pub(crate) struct Hand<M> {
    tx: SyncSender<M>,
    back: Receiver<M>,
}

impl<M> Hand<M> {
    /// Hands `m` over (waits while `depth` batches are queued). Fails only
    /// when the consumer has stopped: its own error is the one reported.
    pub(crate) fn send(&self, m: M) -> Result<()> {
        self.tx.send(m).map_err(|_| Error::io("relay", "hand over a batch", std::io::Error::new(std::io::ErrorKind::BrokenPipe, "the consumer stopped")))
    }

    /// A batch the consumer is done with, to be filled again, if any.
    pub(crate) fn spare(&self) -> Option<M> {
        self.back.try_recv().ok()
    }
}

/// The consumer's end: batches in the order they were handed over.
pub(crate) struct Take<M> {
    rx: Receiver<M>,
    back: Sender<M>,
}

impl<M> Take<M> {
    /// The next batch; None once the producer is done.
    pub(crate) fn next(&self) -> Option<M> {
        self.rx.recv().ok()
    }

    /// Gives an emptied batch back to the producer.
    pub(crate) fn give_back(&self, m: M) {
        let _ = self.back.send(m);
    }

    /// `f` on each batch in turn, each given back once done; stops at
    /// `f`'s first error.
    pub(crate) fn each(&self, mut f: impl FnMut(&M) -> Result<()>) -> Result<()> {
        while let Some(m) = self.next() {
            f(&m)?;
            self.give_back(m);
        }
        Ok(())
    }
}

/// Runs `produce` here and `consume` on another thread, joined by a queue
/// of at most `depth` batches. Each side's error stops both: a failing
/// consumer closes the queue (the producer's next `send` fails and its
/// error is dropped for the consumer's), a failing producer ends the
/// consumer's input and its own error is returned.
pub(crate) fn relay<M: Send, A, B: Send>(
    depth: usize,
    produce: impl FnOnce(Hand<M>) -> Result<A>,
    consume: impl FnOnce(Take<M>) -> Result<B> + Send,
) -> Result<(A, B)> {
    std::thread::scope(|s| {
        let (tx, rx) = sync_channel(depth.max(1));
        let (back_tx, back) = channel();
        let consumer = s.spawn(move || consume(Take { rx, back: back_tx }));
        let a = produce(Hand { tx, back });
        let b = match consumer.join() {
            Ok(b) => b,
            Err(panic) => std::panic::resume_unwind(panic),
        };
        match (a, b) {
            (_, Err(e)) => Err(e),
            (Err(e), _) => Err(e),
            (Ok(a), Ok(b)) => Ok((a, b)),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batches_arrive_in_order_and_are_reused() {
        let (made, sum) = relay(
            2,
            |hand: Hand<Vec<u64>>| {
                let mut made = 0;
                for k in 0..100u64 {
                    let mut b = hand.spare().unwrap_or_else(|| {
                        made += 1;
                        Vec::new()
                    });
                    b.clear();
                    b.extend(k * 10..k * 10 + 10);
                    hand.send(b)?;
                }
                Ok(made)
            },
            |take| {
                let mut next = 0u64;
                take.each(|b| {
                    for &x in b {
                        assert_eq!(x, next);
                        next += 1;
                    }
                    Ok(())
                })?;
                Ok(next)
            },
        )
        .unwrap();
        assert_eq!(sum, 1000);
        // At most the queue's depth, one being filled and one being read.
        assert!(made <= 4, "{made} batches made");
    }

    #[test]
    fn either_side_failing_stops_both_with_its_own_error() {
        // The consumer fails: its error, not the producer's closed queue.
        let r = relay(
            1,
            |hand: Hand<u32>| {
                for k in 0.. {
                    hand.send(k)?;
                }
                Ok(())
            },
            |take| {
                while let Some(k) = take.next() {
                    if k == 5 {
                        return Err::<(), _>(Error::Usage("bad record 5".into()));
                    }
                }
                Ok(())
            },
        );
        assert!(r.unwrap_err().to_string().contains("bad record 5"));
        // The producer fails: the consumer sees its input end.
        let r = relay(
            1,
            |hand: Hand<u32>| {
                hand.send(1)?;
                Err::<(), _>(Error::Usage("bad face 7".into()))
            },
            |take| {
                let mut n = 0;
                while take.next().is_some() {
                    n += 1;
                }
                Ok(n)
            },
        );
        assert!(r.unwrap_err().to_string().contains("bad face 7"));
    }
}

//! How an upload is admitted: by the memory its bytes take as they arrive and by a minimum rate,
//! not by a number of turns. A client that keeps a connection open and sends nothing, or a byte
//! a second, holds no turn another upload waits for and is closed after [`MinRate::grace`], as
//! nginx's `client_body_timeout` and Apache's `mod_reqtimeout` (`MinRate`) close such clients.
//!
//! The rule: after the grace period, a body must have arrived at no less than
//! [`MinRate::bytes_per_second`] on average since its first byte was awaited. Every chunk
//! reserves its size from the server's receiving budget ([`Receiving`]) until the upload has
//! been saved to disk; when the budget is spent, reading waits, and the wait counts against the
//! rate.

use axum::body::{Body, Bytes};
use futures_util::StreamExt as _;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::Instant;

/// The slowest an upload may arrive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MinRate {
    /// Seconds before the rate applies (connection set-up, a slow start).
    pub grace: Duration,
    /// Bytes a second, on average from the start, after the grace period.
    pub bytes_per_second: f64,
}

impl Default for MinRate {
    /// 5 s, then 8 KiB/s: a phone on a poor link sends far more; a client that stalls is closed
    /// within seconds.
    fn default() -> Self {
        Self {
            grace: Duration::from_secs(5),
            bytes_per_second: 8192.0,
        }
    }
}

impl MinRate {
    /// When `received` bytes must have arrived, for a body whose reading began at `start`.
    pub fn deadline(&self, start: Instant, received: u64) -> Instant {
        let secs = received as f64 / self.bytes_per_second.max(1.0);
        start + self.grace + Duration::from_secs_f64(secs.min(1e9))
    }
}

/// The server's budget for uploads being received, in KiB, shared by all of them.
pub type Receiving = Arc<Semaphore>;

/// What one upload holds while it is read: its share of the budget, and whether it was closed
/// for being too slow.
#[derive(Clone, Default)]
pub struct Held {
    permit: Arc<Mutex<Option<OwnedSemaphorePermit>>>,
    slow: Arc<AtomicBool>,
}

impl Held {
    /// Whether the body was cut off for arriving too slowly.
    pub fn too_slow(&self) -> bool {
        self.slow.load(Ordering::SeqCst)
    }

    /// Gives the budget back (once the upload is on disk or refused).
    pub fn release(&self) {
        if let Ok(mut p) = self.permit.lock() {
            p.take();
        }
    }

    fn keep(&self, more: OwnedSemaphorePermit) {
        if let Ok(mut p) = self.permit.lock() {
            match p.as_mut() {
                Some(held) => held.merge(more),
                None => *p = Some(more),
            }
        }
    }
}

/// The error a body stream ends with when its client is too slow.
fn too_slow(rule: MinRate) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::TimedOut,
        format!(
            "the upload arrived slower than {:.0} KiB/s after its first {} s",
            rule.bytes_per_second / 1024.0,
            rule.grace.as_secs()
        ),
    )
}

/// `body`, read under `rule` with its bytes reserved from `budget` into `held`.
pub fn limited(body: Body, rule: MinRate, budget: Receiving, held: Held) -> Body {
    let start = Instant::now();
    let stream = body.into_data_stream();
    let chunks = futures_util::stream::unfold((stream, 0u64, false), move |(mut stream, received, ended)| {
        let (budget, held) = (budget.clone(), held.clone());
        async move {
            if ended {
                return None;
            }
            let deadline = rule.deadline(start, received);
            let fail = |held: &Held| {
                held.slow.store(true, Ordering::SeqCst);
                Err::<Bytes, std::io::Error>(too_slow(rule))
            };
            let chunk = match tokio::time::timeout_at(deadline, stream.next()).await {
                Err(_) => return Some((fail(&held), (stream, received, true))),
                Ok(None) => return None,
                Ok(Some(Err(e))) => return Some((Err(std::io::Error::other(e)), (stream, received, true))),
                Ok(Some(Ok(chunk))) => chunk,
            };
            let kib = chunk.len().div_ceil(1024).min(u32::MAX as usize) as u32;
            if kib > 0 {
                match tokio::time::timeout_at(deadline, budget.acquire_many_owned(kib)).await {
                    Ok(Ok(permit)) => held.keep(permit),
                    Ok(Err(_)) => {
                        return Some((
                            Err(std::io::Error::other("the server is stopping")),
                            (stream, received, true),
                        ));
                    }
                    Err(_) => return Some((fail(&held), (stream, received, true))),
                }
            }
            let n = chunk.len() as u64;
            Some((Ok(chunk), (stream, received + n, false)))
        }
    });
    Body::from_stream(chunks)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_deadline_grows_with_what_arrived_after_the_grace_period() {
        let r = MinRate::default();
        let t = Instant::now();
        assert_eq!(r.deadline(t, 0), t + Duration::from_secs(5));
        assert_eq!(r.deadline(t, 8192 * 10), t + Duration::from_secs(15));
        let far = r.deadline(t, u64::MAX);
        assert!(
            far > t + Duration::from_secs(1_000_000),
            "no overflow at the end of the range"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_stalled_body_is_cut_off_after_the_grace_period_and_its_budget_given_back() {
        let budget: Receiving = Arc::new(Semaphore::new(64));
        let held = Held::default();
        let (tx, rx) = tokio::sync::mpsc::channel::<Result<Bytes, std::io::Error>>(4);
        let body = Body::from_stream(tokio_stream(rx));
        let mut read = limited(body, MinRate::default(), budget.clone(), held.clone()).into_data_stream();
        tx.send(Ok(Bytes::from(vec![1u8; 2048]))).await.unwrap();
        assert_eq!(read.next().await.unwrap().unwrap().len(), 2048);
        assert_eq!(budget.available_permits(), 62, "2 KiB held");
        // Then nothing: cut off at 5 s + 2048 / 8192 s.
        let t = Instant::now();
        assert!(read.next().await.unwrap().is_err());
        assert!(held.too_slow());
        assert!(t.elapsed() >= Duration::from_millis(5200) && t.elapsed() < Duration::from_secs(6));
        held.release();
        assert_eq!(budget.available_permits(), 64);
        drop(tx);
    }

    fn tokio_stream(
        mut rx: tokio::sync::mpsc::Receiver<Result<Bytes, std::io::Error>>,
    ) -> impl futures_util::Stream<Item = Result<Bytes, std::io::Error>> {
        futures_util::stream::poll_fn(move |cx| rx.poll_recv(cx))
    }
}

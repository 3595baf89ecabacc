//! Progress of long work as its user sees it: a bar on a terminal; without one (a batch job's
//! log under Slurm or Kubernetes, where bars hide), a plain line every `MATEDIT_PROGRESS_SECS`
//! seconds (default 30) and one at the end: done/total, rate, elapsed, ETA, and the caller's
//! message (the running loss, say).

use indicatif::{HumanDuration, ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A bar or a log line, whichever the output can show.
pub struct Progress {
    bar: ProgressBar,
    log: Option<Log>,
}

struct Log {
    what: String,
    every: Duration,
    state: Mutex<(Instant, String, bool)>,
}

/// How often the plain line is printed.
fn interval() -> Duration {
    std::env::var("MATEDIT_PROGRESS_SECS")
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0)
        .map_or(Duration::from_secs(30), Duration::from_secs_f64)
}

impl Progress {
    /// `len` units of `what`; `template` is the bar's indicatif template. Silent unless
    /// `enabled`.
    pub fn new(enabled: bool, len: u64, what: &str, template: &str) -> Self {
        let terminal = std::io::stderr().is_terminal();
        let bar = if enabled && terminal {
            ProgressBar::new(len)
        } else {
            // Hidden, but it still counts and estimates the rate for the log line.
            let b = ProgressBar::hidden();
            b.set_length(len);
            b
        };
        bar.set_style(
            ProgressStyle::with_template(template)
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        bar.set_message(what.to_string());
        let log = (enabled && !terminal).then(|| Log {
            what: what.to_string(),
            every: interval(),
            state: Mutex::new((Instant::now(), String::new(), false)),
        });
        Self { bar, log }
    }

    /// The indicatif bar (for prefixes and styles).
    pub fn bar(&self) -> &ProgressBar {
        &self.bar
    }

    /// `n` more done.
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        self.maybe_log(false);
    }

    /// Resumed work: `pos` done already.
    pub fn set_position(&self, pos: u64) {
        self.bar.set_position(pos);
        self.bar.reset_eta();
    }

    /// The message after the counts (the bar's `{msg}`).
    pub fn set_message(&self, msg: String) {
        if let Some(l) = &self.log
            && let Ok(mut s) = l.state.lock()
        {
            s.1 = msg.clone();
        }
        if self.log.is_none() {
            self.bar.set_message(msg);
        }
    }

    /// Done: the bar stays; the log gets its last line.
    pub fn finish(&self) {
        self.bar.finish();
        self.maybe_log(true);
    }

    /// Stopped before the end: the bar keeps its position; the log gets its last line.
    pub fn abandon(&self) {
        self.bar.abandon();
        self.maybe_log(true);
    }

    /// Done: the bar disappears; the log gets its last line.
    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
        self.maybe_log(true);
    }

    fn maybe_log(&self, last: bool) {
        let Some(l) = &self.log else { return };
        let Ok(mut s) = l.state.lock() else { return };
        if s.2 || !(last || s.0.elapsed() >= l.every) {
            return;
        }
        s.0 = Instant::now();
        s.2 = last;
        eprintln!("{}", self.line(&l.what, &s.1, last));
    }

    /// `what: done/total (percent), rate, elapsed[, ETA][, message]`.
    fn line(&self, what: &str, msg: &str, last: bool) -> String {
        let (pos, len) = (self.bar.position(), self.bar.length().unwrap_or(0));
        let pct = if len > 0 {
            100.0 * pos as f64 / len as f64
        } else {
            100.0
        };
        let mut line = format!(
            "{what}: {pos}/{len} ({pct:.1} %), {:.2}/s, {} elapsed",
            self.bar.per_sec(),
            HumanDuration(self.bar.elapsed())
        );
        if !last {
            line += &format!(", ETA {}", HumanDuration(self.bar.eta()));
        }
        if !msg.is_empty() {
            line += &format!(", {msg}");
        }
        line
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_a_terminal_it_counts_and_stays_silent_when_disabled() {
        // Tests run without a terminal on stderr: the log variant.
        let p = Progress::new(true, 10, "samples", "{msg} {pos}/{len}");
        assert_eq!(p.log.is_some(), !std::io::stderr().is_terminal());
        p.set_position(3);
        p.inc(2);
        p.set_message("loss 1.0e-1".into());
        assert_eq!(p.bar().position(), 5);
        let line = p.line("samples", "loss 1.0e-1", false);
        assert!(line.starts_with("samples: 5/10 (50.0 %), "), "{line}");
        assert!(
            line.contains(" elapsed, ETA ") && line.ends_with(", loss 1.0e-1"),
            "{line}"
        );
        assert!(!p.line("samples", "", true).contains("ETA"));
        p.abandon();
        assert_eq!(p.bar().position(), 5, "stopped early, the count stays");
        p.finish();
        let q = Progress::new(false, 10, "samples", "{msg}");
        assert!(q.log.is_none());
        q.inc(10);
        assert_eq!(q.bar().position(), 10);
    }
}

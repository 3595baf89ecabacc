//! The server's life: its private work folder (made first, removed on every way out), the
//! signals that stop it (listened for before anything is made), and the accept loop (connections
//! capped below the open-file limit, a failed accept backed off rather than retried at once).

use anyhow::{Context, Result};
use axum::Router;
use std::path::PathBuf;
use std::sync::Arc;

/// The server's work folder, removed when dropped if the server made it: a start that fails
/// or is interrupted (SIGTERM while the model loads) and a stop leave nothing behind.
pub(super) struct WorkFolder {
    pub(super) path: PathBuf,
    remove: bool,
}

impl WorkFolder {
    /// Creates `path` readable by this user only (0700), as everything the server writes in it
    /// (the process's file mode mask is set to 0077 first): uploads, outputs and job ids are
    /// nobody else's to list or read.
    pub(super) fn create(path: PathBuf, remove: bool) -> Result<Self> {
        #[cfg(unix)]
        {
            use std::os::unix::fs::DirBuilderExt as _;
            // SAFETY: umask only swaps the process's mask; it cannot fail.
            unsafe { libc::umask(0o077) };
            std::fs::DirBuilder::new()
                .recursive(true)
                .mode(0o700)
                .create(&path)
                .with_context(|| format!("cannot create the work folder {}", path.display()))?;
        }
        #[cfg(not(unix))]
        std::fs::create_dir_all(&path).with_context(|| format!("cannot create the work folder {}", path.display()))?;
        Ok(Self { path, remove })
    }
}

impl Drop for WorkFolder {
    fn drop(&mut self) {
        if self.remove {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

/// How long a stopping server waits for the running edit to notice it was cancelled before it
/// leaves it behind (the process then ends, and the edit with it).
pub const CANCEL_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

/// Ctrl-C (SIGINT) or SIGTERM, listened for from the moment it is made (before the model loads,
/// so that a signal during start-up is a clean stop, not the default action's kill).
pub(super) struct Interrupt {
    #[cfg(unix)]
    term: Option<tokio::signal::unix::Signal>,
}

impl Interrupt {
    pub(super) fn new() -> Self {
        Self {
            #[cfg(unix)]
            term: tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok(),
        }
    }

    pub(super) async fn wait(&mut self) {
        #[cfg(unix)]
        if let Some(term) = self.term.as_mut() {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            return;
        }
        let _ = tokio::signal::ctrl_c().await;
    }
}

/// Serves connections until `stop`: each connection's headers must arrive within `headers`
/// (hyper closes it otherwise, also when it sits idle between requests); on `stop`, connections
/// finish their request and close (what does not finish is dropped by [`Server::stop`]).
pub(super) async fn accept(
    listener: tokio::net::TcpListener,
    router: Router,
    mut stop: tokio::sync::oneshot::Receiver<()>,
    headers: std::time::Duration,
) {
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    // Connections are capped below the open-file limit, which leaves descriptors for the files
    // an edit opens; at the cap, the next connection waits in the listen queue until one closes
    // (an idle one within the header deadline).
    let open = Arc::new(tokio::sync::Semaphore::new(connection_cap()));
    loop {
        let slot = tokio::select! {
            slot = open.clone().acquire_owned() => slot,
            _ = &mut stop => break,
        };
        let Ok(slot) = slot else { break };
        tokio::select! {
            conn = listener.accept() => {
                let stream = match conn {
                    Ok((stream, _)) => stream,
                    // Out of descriptors (EMFILE, ENFILE) or another passing error: back off
                    // rather than retry at once, which would spin a core while the error lasts.
                    Err(_) => {
                        tokio::time::sleep(ACCEPT_BACKOFF).await;
                        continue;
                    }
                };
                let service = hyper_util::service::TowerToHyperService::new(router.clone());
                let conn = hyper::server::conn::http1::Builder::new()
                    .timer(hyper_util::rt::TokioTimer::new())
                    .header_read_timeout(headers)
                    .serve_connection(hyper_util::rt::TokioIo::new(stream), service);
                let conn = graceful.watch(conn);
                tokio::spawn(async move {
                    let _ = conn.await;
                    drop(slot);
                });
            }
            _ = &mut stop => break,
        }
    }
    drop(listener);
    graceful.shutdown().await;
}

/// How long the accept loop waits after a failed accept (out of file descriptors, say).
const ACCEPT_BACKOFF: std::time::Duration = std::time::Duration::from_millis(100);

/// Open connections at most: the open-file limit less 64 descriptors for the model, the edit's
/// files and the runtime, at least 8 and at most 4096.
fn connection_cap() -> usize {
    #[cfg(unix)]
    {
        let mut lim = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: getrlimit writes the struct it is given.
        if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) } == 0 {
            let soft = usize::try_from(lim.rlim_cur).unwrap_or(usize::MAX);
            return soft.saturating_sub(64).clamp(8, 4096);
        }
    }
    1024
}

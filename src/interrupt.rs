//! A clean stop on SIGINT (Ctrl-C) and SIGTERM (a batch scheduler's stop or `kill`).
//!
//! [`install`] (the CLI calls it once) turns the first such signal into a request that the time
//! loop honours between two steps ([`check`]): the run ends with [`crate::Error::Interrupted`],
//! its output folder keeps the frames written so far beside a summary.json that says
//! `"status": "failed"`, `"error": "interrupted"`, and the process exits with 130 (SIGINT) or
//! 143 (SIGTERM), the shells' 128 + signal. A second signal ends the process at once with the
//! same code (a stop that hangs can still be forced). A library user who never calls [`install`]
//! keeps the default behaviour of the signals; [`request`] stops a run from another thread.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use crate::{Error, Result};

/// POSIX signal numbers (the same on every platform hytled builds for).
pub const SIGINT: i32 = 2;
/// See [`SIGINT`].
pub const SIGTERM: i32 = 15;

/// Set by the first signal; arms the immediate exit on the second.
static ANY: AtomicBool = AtomicBool::new(false);
/// The signal that asked for the stop (0: none).
static WHICH: AtomicUsize = AtomicUsize::new(0);

/// Installs the handlers of SIGINT and SIGTERM (see the module documentation).
pub fn install() -> std::io::Result<()> {
    use signal_hook::consts::{SIGINT as INT, SIGTERM as TERM};
    for sig in [INT, TERM] {
        // Registered first, so it acts only from the second signal on (the flag is still
        // false during the first).
        signal_hook::flag::register_conditional_shutdown(sig, 128 + sig, &ANY)?;
        signal_hook::flag::register_usize(sig, &WHICH, sig as usize)?;
        signal_hook::flag::register(sig, &ANY)?;
    }
    Ok(())
}

/// Asks the running solve to stop as if `signal` had arrived (another thread, a GUI's stop
/// button).
pub fn request(signal: i32) {
    WHICH.store(signal.max(1) as usize, Ordering::SeqCst);
    ANY.store(true, Ordering::SeqCst);
}

/// Forgets a request (a library user that goes on after an interrupted solve).
pub fn clear() {
    WHICH.store(0, Ordering::SeqCst);
    ANY.store(false, Ordering::SeqCst);
}

/// The signal that asked for a stop, if one did.
pub fn requested() -> Option<i32> {
    match WHICH.load(Ordering::Relaxed) {
        0 => None,
        s => Some(s as i32),
    }
}

/// [`Error::Interrupted`] once a stop was asked for; `at` says where the run is.
pub fn check(at: impl FnOnce() -> String) -> Result<()> {
    match requested() {
        None => Ok(()),
        Some(signal) => Err(Error::Interrupted { signal, at: at() }),
    }
}

/// "SIGINT (Ctrl-C)", "SIGTERM", or the number.
pub fn signal_name(signal: i32) -> String {
    match signal {
        SIGINT => "SIGINT (Ctrl-C)".into(),
        SIGTERM => "SIGTERM".into(),
        s => format!("signal {s}"),
    }
}

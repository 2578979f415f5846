//! A foreign library's call (TetGen) run in a forked child process, so that what it does
//! wrong cannot take hytled down with it (issue 56):
//!
//! - an `abort()` (TetGen's failed `assert`, SIGABRT) or a crash ends the child only, and
//!   becomes an error naming the mesher and its last words;
//! - what it prints (TetGen's "status = 3") goes into the error message, never to hytled's
//!   stdout, where `--json` writes its one object;
//! - a stop request (SIGINT, SIGTERM, [`crate::interrupt::request`]) kills the child at once
//!   (checked every 50 ms), where a call in-process could only be waited for.
//!
//! The child returns its result as two flat arrays through a pipe. On targets without
//! `fork` the call runs in-process.

use crate::{Error, InputKind, Result};

/// What a child returns: numbers and indices.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Output {
    /// Real numbers (coordinates).
    pub reals: Vec<f64>,
    /// Whole numbers (counts, indices).
    pub ints: Vec<u64>,
}

/// How much of the child's printed text is kept for the message (its end).
const LOG_TAIL: usize = 2000;

/// Runs `job` in a forked child and returns its output and the end of what it printed (up to
/// 2,000 bytes). `what` names the work in messages ("TetGen meshing the surface"). `job`'s `Err` is returned as [`Error::Input`] with its text;
/// a child that dies is an `Input` error saying how (the signal, or out of memory), with the
/// last lines it printed; a stop request ends it with [`Error::Interrupted`].
#[cfg(unix)]
pub fn run(
    what: &str,
    job: impl FnOnce() -> std::result::Result<Output, String>,
) -> Result<(Output, String)> {
    crate::interrupt::check(|| format!("before {what}"))?;
    let (data_r, data_w) = pipe(what)?;
    let (log_r, log_w) = match pipe(what) {
        Ok(p) => p,
        Err(e) => {
            close(data_r);
            close(data_w);
            return Err(e);
        }
    };
    // SAFETY: the child runs `job` and leaves through `_exit`, never returning into the
    // caller; it touches only its own copy of memory and the pipes' ends. glibc's malloc is
    // safe to use after fork; the child takes no lock another thread may have held (no Rust
    // stdout/stderr, no log).
    let pid = unsafe { libc::fork() };
    if pid < 0 {
        for fd in [data_r, data_w, log_r, log_w] {
            close(fd);
        }
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "{what}: could not start a process for it: {}",
                std::io::Error::last_os_error()
            ),
        ));
    }
    if pid == 0 {
        child(job, data_r, data_w, log_r, log_w);
    }
    close(data_w);
    close(log_w);
    let collected = collect(data_r, log_r, pid, what);
    close(data_r);
    close(log_r);
    let (data, log) = match collected {
        Ok(v) => v,
        Err(e) => {
            // SAFETY: pid is our child; SIGKILL and reaping it leave nothing behind.
            unsafe {
                libc::kill(pid, libc::SIGKILL);
            }
            let _ = wait(pid);
            return Err(e);
        }
    };
    let status = wait(pid);
    let printed = String::from_utf8_lossy(&log).trim().to_string();
    let said = if printed.is_empty() {
        String::new()
    } else {
        format!("; it printed: \"{}\"", printed.replace('\n', " / "))
    };
    match status {
        Ok(0) => decode(&data)
            .map(|o| (o, printed.clone()))
            .map_err(|m| Error::input(InputKind::Mesh, format!("{what}: {m}{said}"))),
        Ok(code) if code == crate::error::exit::INPUT as i32 && data.is_empty() => Err(Error::input(InputKind::Limit, format!(
            "{what}: it ran out of memory{said}; raise discretization.size or run where more memory is free"
        ))),
        Ok(code) => Err(Error::input(InputKind::Mesh, format!("{what}: it stopped with exit code {code}{said}"))),
        Err(signal) => Err(Error::input(InputKind::Mesh, format!(
            "{what}: it crashed ({}){said}; the input is probably one the mesher cannot handle: \
             check the surface for thin or nearly degenerate triangles, or remesh it (e.g. with \
             a uniform remesher) before meshing",
            signal_name(signal)
        ))),
    }
}

/// In-process fallback where there is no `fork`.
#[cfg(not(unix))]
pub fn run(
    what: &str,
    job: impl FnOnce() -> std::result::Result<Output, String>,
) -> Result<(Output, String)> {
    crate::interrupt::check(|| format!("before {what}"))?;
    job()
        .map(|o| (o, String::new()))
        .map_err(|m| Error::input(InputKind::Mesh, format!("{what}: {m}")))
}

#[cfg(unix)]
fn signal_name(signal: i32) -> String {
    match signal {
        libc::SIGABRT => "SIGABRT: an assertion inside it failed".into(),
        libc::SIGSEGV => "SIGSEGV: it read memory it does not own".into(),
        libc::SIGKILL => {
            "SIGKILL: killed from outside, often by the system's out-of-memory killer".into()
        }
        libc::SIGFPE => "SIGFPE: an arithmetic fault".into(),
        s => format!("signal {s}"),
    }
}

#[cfg(unix)]
fn pipe(what: &str) -> Result<(i32, i32)> {
    let mut fds = [0i32; 2];
    // SAFETY: fds has room for the two descriptors.
    if unsafe { libc::pipe(fds.as_mut_ptr()) } != 0 {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "{what}: could not open a pipe: {}",
                std::io::Error::last_os_error()
            ),
        ));
    }
    Ok((fds[0], fds[1]))
}

#[cfg(unix)]
fn close(fd: i32) {
    // SAFETY: fd is a descriptor this module opened and closes once.
    unsafe {
        libc::close(fd);
    }
}

/// The child's side: stdout and stderr into the log pipe, `job`'s result into the data pipe,
/// then `_exit`.
#[cfg(unix)]
fn child(
    job: impl FnOnce() -> std::result::Result<Output, String>,
    data_r: i32,
    data_w: i32,
    log_r: i32,
    log_w: i32,
) -> ! {
    // SAFETY: plain descriptor calls on this process's own descriptors.
    let data_w = unsafe {
        libc::close(data_r);
        libc::close(log_r);
        libc::dup2(log_w, 1);
        libc::dup2(log_w, 2);
        libc::close(log_w);
        // The result pipe as descriptor 3, and every other descriptor closed: the child must
        // not hold what the parent opens (an output folder's lock, another child's pipe) for
        // as long as it runs.
        if data_w != 3 {
            libc::dup2(data_w, 3);
            libc::close(data_w);
        }
        if libc::syscall(libc::SYS_close_range, 4u32, u32::MAX, 0u32) != 0 {
            let max = libc::sysconf(libc::_SC_OPEN_MAX).clamp(4, 1 << 16) as i32;
            for fd in 4..max {
                libc::close(fd);
            }
        }
        3
    };
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(job))
        .unwrap_or_else(|_| Err("it panicked".to_string()));
    let bytes = encode(&result);
    let mut rest = &bytes[..];
    while !rest.is_empty() {
        // SAFETY: writes from a live buffer to our own pipe end.
        let n = unsafe { libc::write(data_w, rest.as_ptr().cast(), rest.len()) };
        if n <= 0 {
            break;
        }
        rest = &rest[n as usize..];
    }
    // SAFETY: flushes C's stdio (TetGen's printf) into the log pipe, then leaves without
    // running the parent's exit handlers or destructors.
    unsafe {
        libc::fflush(std::ptr::null_mut());
        libc::_exit(0)
    }
}

/// Reads both pipes to their end, keeping the data and the log's tail, and kills the child on a
/// stop request.
#[cfg(unix)]
fn collect(data_r: i32, log_r: i32, pid: i32, what: &str) -> Result<(Vec<u8>, Vec<u8>)> {
    let (mut data, mut log) = (Vec::new(), Vec::new());
    let mut open = [true, true];
    let mut buf = vec![0u8; 1 << 16];
    while open.iter().any(|&o| o) {
        crate::interrupt::check(|| format!("during {what} (its process {pid} was stopped)"))?;
        let mut fds: Vec<libc::pollfd> = [data_r, log_r]
            .iter()
            .zip(open)
            .filter(|(_, o)| *o)
            .map(|(&fd, _)| libc::pollfd {
                fd,
                events: libc::POLLIN,
                revents: 0,
            })
            .collect();
        // SAFETY: fds is a live array of fds.len() pollfd entries.
        let n = unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, 50) };
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if e.kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return Err(Error::input(
                InputKind::Mesh,
                format!("{what}: waiting for its process: {e}"),
            ));
        }
        for p in fds.iter().filter(|p| p.revents != 0) {
            // SAFETY: reads into a live buffer of buf.len() bytes.
            let got = unsafe { libc::read(p.fd, buf.as_mut_ptr().cast(), buf.len()) };
            let k = if p.fd == data_r { 0 } else { 1 };
            if got <= 0 {
                if got < 0
                    && std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted
                {
                    continue;
                }
                open[k] = false;
            } else if k == 0 {
                data.extend_from_slice(&buf[..got as usize]);
            } else {
                log.extend_from_slice(&buf[..got as usize]);
                if log.len() > 2 * LOG_TAIL {
                    log.drain(..log.len() - LOG_TAIL);
                }
            }
        }
    }
    if log.len() > LOG_TAIL {
        log.drain(..log.len() - LOG_TAIL);
    }
    Ok((data, log))
}

/// Reaps the child: its exit code, or the signal that ended it.
#[cfg(unix)]
fn wait(pid: i32) -> std::result::Result<i32, i32> {
    let mut status = 0;
    loop {
        // SAFETY: waits for our own child.
        let r = unsafe { libc::waitpid(pid, &mut status, 0) };
        if r == pid {
            break;
        }
        if r < 0 && std::io::Error::last_os_error().kind() != std::io::ErrorKind::Interrupted {
            return Err(0);
        }
    }
    if libc::WIFEXITED(status) {
        Ok(libc::WEXITSTATUS(status))
    } else if libc::WIFSIGNALED(status) {
        Err(libc::WTERMSIG(status))
    } else {
        Err(0)
    }
}

/// `[tag u8][count of reals u64][count of ints u64][reals][ints]` (tag 0), or `[1][message]`.
fn encode(r: &std::result::Result<Output, String>) -> Vec<u8> {
    match r {
        Ok(o) => {
            let mut b = Vec::with_capacity(17 + 8 * (o.reals.len() + o.ints.len()));
            b.push(0);
            b.extend_from_slice(&(o.reals.len() as u64).to_le_bytes());
            b.extend_from_slice(&(o.ints.len() as u64).to_le_bytes());
            for v in &o.reals {
                b.extend_from_slice(&v.to_le_bytes());
            }
            for v in &o.ints {
                b.extend_from_slice(&v.to_le_bytes());
            }
            b
        }
        Err(m) => {
            let mut b = vec![1];
            b.extend_from_slice(m.as_bytes());
            b
        }
    }
}

fn decode(b: &[u8]) -> std::result::Result<Output, String> {
    let word = |at: usize| -> Option<[u8; 8]> { b.get(at..at + 8)?.try_into().ok() };
    match b.first() {
        Some(1) => Err(String::from_utf8_lossy(&b[1..]).to_string()),
        Some(0) => {
            let bad = || "its process returned a truncated result".to_string();
            let nr = u64::from_le_bytes(word(1).ok_or_else(bad)?) as usize;
            let ni = u64::from_le_bytes(word(9).ok_or_else(bad)?) as usize;
            let need = nr
                .checked_add(ni)
                .and_then(|n| n.checked_mul(8))
                .and_then(|n| n.checked_add(17))
                .ok_or_else(bad)?;
            if b.len() != need {
                return Err(bad());
            }
            let reals = (0..nr)
                .map(|k| f64::from_le_bytes(word(17 + 8 * k).unwrap_or_default()))
                .collect();
            let ints = (0..ni)
                .map(|k| u64::from_le_bytes(word(17 + 8 * (nr + k)).unwrap_or_default()))
                .collect();
            Ok(Output { reals, ints })
        }
        _ => Err("its process returned no result".into()),
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    #[test]
    fn the_child_holds_none_of_the_parents_files() {
        // A lock the parent holds is free again as soon as the parent lets it go, while the
        // child still runs (an output folder's lock was held by TetGen's child).
        let path = std::env::temp_dir().join(format!("hytled-isolated-{}", std::process::id()));
        let f = std::fs::File::create(&path).unwrap();
        f.try_lock().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        let waiter = std::thread::spawn(move || {
            run("a test job", || {
                std::thread::sleep(std::time::Duration::from_millis(500));
                Ok(Output::default())
            })
            .map(|_| ())
            .map_err(|e| e.to_string())
            .and_then(|_| rx.recv().map_err(|e| e.to_string()))
        });
        std::thread::sleep(std::time::Duration::from_millis(100));
        drop(f);
        let again = std::fs::File::open(&path).unwrap();
        // Another test's child, forked by a parallel test thread while `f` was open, holds the
        // lock until it has closed its inherited descriptors (microseconds): a few tries within
        // 250 ms tell that from this child, which would hold it for all its 500 ms.
        let free = (0..25).any(|_| {
            let ok = again.try_lock().is_ok();
            if !ok {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            ok
        });
        assert!(free, "the child kept the parent's lock");
        tx.send(()).unwrap();
        waiter.join().unwrap().unwrap();
    }

    #[test]
    fn a_result_comes_back_whole() {
        let want = Output {
            reals: vec![1.5, -2.0, f64::MIN_POSITIVE],
            ints: (0..100_000).collect(),
        };
        let w = want.clone();
        assert_eq!(run("a test job", move || Ok(w)).unwrap().0, want);
        let e = run("a test job", || Err("no good".into()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a test job: no good"), "{e}");
    }

    #[test]
    fn an_abort_in_the_child_is_an_error_with_what_it_printed() {
        let e = run("a test job", || {
            // SAFETY: C's printf-free write and abort, in the child only.
            unsafe {
                let m = b"Assertion `pts[7] != dummypoint' failed.\n";
                libc::write(2, m.as_ptr().cast(), m.len());
                libc::abort()
            }
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("SIGABRT") && e.contains("pts[7] != dummypoint"),
            "{e}"
        );
    }
}

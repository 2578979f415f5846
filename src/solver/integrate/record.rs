//! What the time loop keeps and shows as it goes: output frames, history rows, progress.

use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use nalgebra::Vector3;

use super::{HistoryRow, Settings};
use crate::Result;

/// The frames and history rows of a run, planned before its first step so that the loop only
/// copies into buffers allocated here.
pub(super) struct Recorder {
    /// The steps that write a frame, ascending.
    frame_steps: Vec<usize>,
    /// The frames' times (s): a shortened step re-divides the rest of a dynamic run and moves
    /// the frames still to come to the steps nearest these times.
    frame_times: Vec<f64>,
    /// A history row every this many steps from `base`.
    every: usize,
    base: usize,
    buffers: Vec<Vec<Vector3<f64>>>,
    pub(super) frames: Vec<(f64, Vec<Vector3<f64>>)>,
    pub(super) history: Vec<HistoryRow>,
}

impl Recorder {
    /// Plans a run of `total_steps` steps of `dt` (s) over `n` nodes with `boundaries`
    /// reactions per row, refusing one whose frames and rows (with the model's `model_bytes`)
    /// would not fit in memory. `streaming`: frames go to a sink, none are kept.
    pub(super) fn plan(
        s: &Settings,
        (n, boundaries): (usize, usize),
        (total_steps, dt): (usize, f64),
        model_bytes: usize,
        streaming: bool,
    ) -> Result<Self> {
        let dynamic = s.mode == super::Mode::Dynamic;
        // More frames or rows than steps would only repeat them.
        let frames_wanted = s.frames.max(1).min(total_steps.max(1));
        let frame_steps: Vec<usize> = if dynamic {
            (0..=frames_wanted)
                .map(|k| (k * total_steps) / frames_wanted)
                .collect()
        } else {
            vec![0]
        };
        let frame_times: Vec<f64> = frame_steps.iter().map(|&k| k as f64 * dt).collect();
        let frame_bytes = if streaming {
            0.0
        } else {
            (frame_steps.len() + 1) as f64 * n as f64 * 24.0
        };
        let every = if dynamic {
            (total_steps / s.history_rows.max(1)).max(1)
        } else {
            s.estimate_interval.max(1)
        };
        // Relaxation records a row per estimate and usually stops long before max_steps, so
        // only the dynamic history (a row count fixed in advance) is planned for.
        let rows = if dynamic {
            (total_steps / every + 2) as f64
        } else {
            0.0
        };
        let row_bytes = (std::mem::size_of::<HistoryRow>()
            + boundaries * std::mem::size_of::<[f64; 3]>()
            + 16) as f64;
        let history_bytes = rows * row_bytes;
        let fix = if frame_bytes >= history_bytes {
            "lower output.frames"
        } else {
            "lower output.history_rows"
        };
        crate::memory::check(
            frame_bytes + history_bytes + model_bytes as f64,
            &format!(
                "the run ({} output frames of {n} nodes: {}; {rows:.0} history rows: {}; and the \
                 model)",
                frame_steps.len(),
                crate::memory::size(frame_bytes),
                crate::memory::size(history_bytes)
            ),
            fix,
        )?;
        let kept = if streaming {
            0
        } else {
            frame_steps.len() + usize::from(!dynamic)
        };
        let buffers: Vec<Vec<Vector3<f64>>> =
            (0..kept).map(|_| vec![Vector3::zeros(); n]).collect();
        Ok(Recorder {
            frame_steps,
            frame_times,
            every,
            base: 0,
            frames: Vec::with_capacity(buffers.len()),
            buffers,
            // A few rows more than planned: re-dividing the run after a shortened step rounds
            // the row spacing.
            history: Vec::with_capacity(if dynamic {
                s.history_rows.min(total_steps) + 8
            } else {
                1024
            }),
        })
    }

    /// Whether `step` records a history row.
    pub(super) fn row_due(&self, step: usize) -> bool {
        (step - self.base).is_multiple_of(self.every)
    }

    /// Whether `step` writes a frame.
    pub(super) fn frame_due(&self, step: usize) -> bool {
        self.frame_steps.binary_search(&step).is_ok()
    }

    /// Keeps the frame `u` (m) at time `t` (s) in the next free buffer.
    pub(super) fn keep(&mut self, t: f64, u: &[Vector3<f64>]) {
        if let Some(mut buf) = self.buffers.pop() {
            buf.copy_from_slice(u);
            self.frames.push((t, buf));
        }
    }

    /// Keeps the final frame of a relaxation run (in its planned buffer).
    pub(super) fn keep_last(&mut self, t: f64, u: &[Vector3<f64>]) {
        let buf = match self.buffers.pop() {
            Some(mut buf) => {
                buf.copy_from_slice(u);
                buf
            }
            None => u.to_vec(),
        };
        self.frames.push((t, buf));
    }

    /// A dynamic run's step shortened from `dt` to `new_dt` (s) at `step`, time `t_now` (s),
    /// with `k` steps left: the frames still to come move to the steps nearest their times,
    /// and the rows keep their spacing in time.
    pub(super) fn redivide(&mut self, step: usize, t_now: f64, (dt, new_dt): (f64, f64), k: usize) {
        for (fs, &ft) in self.frame_steps.iter_mut().zip(&self.frame_times) {
            if *fs > step {
                let r = ((ft - t_now) / new_dt).round().max(1.0) as usize;
                *fs = step + r.min(k);
            }
        }
        self.every = ((self.every as f64 * dt / new_dt).round() as usize).max(1);
        self.base = step;
    }
}

/// Progress on stderr: a bar on a terminal (`Settings::progress`), plain lines every so many
/// seconds in logs (`Settings::progress_lines`).
pub(super) struct Progress {
    bar: ProgressBar,
    /// The bar shows the relaxation's error estimate.
    messages: bool,
    lines: Option<f64>,
    /// Seconds since the start at the last plain line.
    last_line: f64,
    dynamic: bool,
}

/// Steps between progress updates.
pub(super) const PROGRESS_STEPS: usize = 64;

/// The state a progress update reports.
pub(super) struct Report {
    pub(super) step: usize,
    pub(super) total_steps: usize,
    /// Time (s) and load fraction at `step`.
    pub(super) t: f64,
    pub(super) load: f64,
    /// Relaxation: the error estimate (m), its tolerance (m) and the rate.
    pub(super) err_est: f64,
    pub(super) tolerance: f64,
    pub(super) r: f64,
}

impl Progress {
    pub(super) fn new(s: &Settings, total_steps: usize) -> Self {
        let dynamic = s.mode == super::Mode::Dynamic;
        let bar = if s.progress {
            let pb = ProgressBar::with_draw_target(
                Some(total_steps as u64),
                ProgressDrawTarget::stderr_with_hz(5),
            );
            let tmpl = if dynamic {
                "{bar:40} {pos}/{len} steps {elapsed} (eta {eta}) {msg}"
            } else {
                "{spinner} relaxation step {pos} {elapsed} {msg}"
            };
            pb.set_style(
                ProgressStyle::with_template(tmpl).unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            pb
        } else {
            ProgressBar::hidden()
        };
        Progress {
            bar,
            messages: !dynamic && s.progress,
            lines: s.progress_lines,
            last_line: 0.0,
            dynamic,
        }
    }

    pub(super) fn set_length(&self, total_steps: usize) {
        self.bar.set_length(total_steps as u64);
    }

    /// Shows the state at `rep.step` (every [`PROGRESS_STEPS`] steps); `start`: the run's start.
    pub(super) fn update(&mut self, rep: &Report, start: Instant) {
        let step = rep.step;
        self.bar.set_position(step as u64);
        if self.messages {
            self.bar.set_message(format!(
                "error estimate {:.2e} m, r = {:.5}",
                rep.err_est, rep.r
            ));
        }
        let Some(every) = self.lines else {
            return;
        };
        let elapsed = start.elapsed().as_secs_f64();
        if elapsed < self.last_line + every {
            return;
        }
        self.last_line = elapsed;
        let t = rep.t;
        if self.dynamic {
            let total_steps = rep.total_steps;
            let eta = elapsed * (total_steps.saturating_sub(step)) as f64 / step as f64;
            eprintln!(
                "progress: step {step} of {total_steps} ({:.1} %), t = {t:.4e} s, {elapsed:.0} s elapsed, about {eta:.0} s left",
                100.0 * step as f64 / total_steps as f64
            );
        } else {
            let est = if rep.err_est.is_finite() {
                format!("error estimate {:.2e} m", rep.err_est)
            } else {
                "no error estimate yet".into()
            };
            eprintln!(
                "progress: relaxation step {step} (load {:.0} %), {est} (tolerance {:.1e} m), {elapsed:.0} s elapsed",
                100.0 * rep.load.min(1.0),
                rep.tolerance
            );
        }
    }

    pub(super) fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

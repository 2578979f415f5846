//! The steps of a run: their lengths and times, the load path they follow, and the update
//! coefficients of each.

use super::{Mode, Settings};
use crate::{Error, InputKind, Result};

/// Dynamic runs needing more steps than this are refused unless `max_steps` allows them (a
/// mistyped dt_factor or density would otherwise run for days without a word).
const MAX_DYNAMIC_STEPS: f64 = 1e8;

/// The steps' lengths and times, and the load path they follow.
pub(super) struct Timeline {
    pub(super) dynamic: bool,
    /// The step in use and the one before it, s.
    pub(super) dt: f64,
    pub(super) dt_prev: f64,
    /// Steps from `base.0` (at time `base.1`, s) on are `dt` long.
    base: (usize, f64),
    /// Dynamic: the last step; relaxation: the most steps allowed.
    pub(super) total_steps: usize,
    /// Dynamic: time over which the load curves run from 0 to 1, s.
    load_time: f64,
    /// Relaxation: pseudo-steps over which the load comes, and the first step (s): once the
    /// step has been shortened (`varied`), the load follows the pseudo-time in steps of the
    /// first length, so that it comes as fast in pseudo-time as planned.
    pub(super) load_steps: usize,
    dt0: f64,
    varied: bool,
    /// Relaxation: the load fraction the load stops at until [`Self::resume`] (a load stage;
    /// 1 or above: none), and the load held back by the stages passed (the load comes on
    /// from where it stopped).
    pub(super) cap: f64,
    held: f64,
}

impl Timeline {
    /// Dynamic: the first step `dt` (s) shortened to divide the duration into whole steps;
    /// refused where that takes more than [`MAX_DYNAMIC_STEPS`] and `max_steps` allows.
    pub(super) fn new(s: &Settings, dt: f64, dt_factor: f64) -> Result<Self> {
        let dynamic = s.mode == Mode::Dynamic;
        let (dt, total_steps) = if dynamic {
            let steps = (s.duration / dt).ceil().max(1.0);
            if !(steps <= MAX_DYNAMIC_STEPS || steps <= s.max_steps as f64) {
                return Err(Error::input(InputKind::Limit, format!(
                    "the dynamic run needs {sci_steps:.3e} steps (duration {:.4e} s / dt {sci_dt:.4e} s), more than \
                     {sci_MAX_DYNAMIC_STEPS:.0e}: check solver.duration, solver.dt_factor ({}) and the material's \
                     density, or set solver.max_steps to at least that many to run it anyway",
                    crate::error::Sci(s.duration), dt_factor
                , sci_steps = crate::error::Sci(steps), sci_dt = crate::error::Sci(dt), sci_MAX_DYNAMIC_STEPS = crate::error::Sci(MAX_DYNAMIC_STEPS))));
            }
            let k = steps as usize;
            (s.duration / k as f64, k)
        } else {
            (dt, s.max_steps)
        };
        Ok(Timeline {
            dynamic,
            dt,
            dt_prev: dt,
            base: (0, 0.0),
            total_steps,
            load_time: s.load_time,
            load_steps: 0,
            dt0: dt,
            varied: false,
            cap: s.stages.first().copied().unwrap_or(1.0),
            held: 0.0,
        })
    }

    /// Simulated (dynamic) or pseudo (relaxation) time at `step`, s.
    pub(super) fn time(&self, step: usize) -> f64 {
        self.base.1 + (step - self.base.0) as f64 * self.dt
    }

    /// Load fraction at `step`: dynamic, its time over the load time; relaxation, the step
    /// over the load steps, or its pseudo-time in steps of the first length once the step
    /// has been shortened.
    pub(super) fn load(&self, step: usize) -> f64 {
        let l = self.rising_load(step) - self.held;
        if l > self.cap && self.cap < 1.0 {
            self.cap
        } else {
            l
        }
    }

    /// The load fraction the relaxation converges at before it stops or goes on: the stage's,
    /// or the full load.
    pub(super) fn target(&self) -> f64 {
        self.cap.min(1.0)
    }

    /// The stage held at `step` has converged: the load comes on again from it at the next
    /// step, up to `next` (the next stage, or 1 and above for none).
    pub(super) fn resume(&mut self, step: usize, next: f64) {
        self.held = self.rising_load(step) - self.cap;
        self.cap = next;
    }

    /// The load fraction without the stages' pauses.
    fn rising_load(&self, step: usize) -> f64 {
        let t = self.time(step);
        if self.dynamic {
            if self.load_time > 0.0 {
                t / self.load_time
            } else {
                1.0
            }
        } else if self.load_steps > 0 {
            if self.varied {
                t / self.dt0 / self.load_steps as f64
            } else {
                step as f64 / self.load_steps as f64
            }
        } else {
            1.0
        }
    }

    /// Shortens the step to `target` (s) from `step` on. A dynamic run re-divides the rest of
    /// its duration into whole steps: Err with the steps that would take where that is more
    /// than allowed. Relaxation has no end to divide; its load follows the pseudo-time.
    pub(super) fn shorten(
        &mut self,
        step: usize,
        target: f64,
        s: &Settings,
    ) -> std::result::Result<(), f64> {
        let t_now = self.time(step);
        if self.dynamic {
            let remaining = s.duration - t_now;
            let k = (remaining / target).ceil().max(1.0);
            if !(step as f64 + k <= MAX_DYNAMIC_STEPS || step as f64 + k <= s.max_steps as f64) {
                return Err(k);
            }
            let k = k as usize;
            self.total_steps = step + k;
            self.dt = remaining / k as f64;
        } else {
            self.varied = true;
            self.dt = target;
        }
        self.base = (step, t_now);
        Ok(())
    }

    /// Coefficients (A, B, C) of u(n+1) = A M^-1 (F_ext - F_int) + B u(n) + C u(n-1):
    /// central differences with mass-proportional `damping` (1/s), over a step change the
    /// velocity v(n+1/2) from v(n-1/2) over the mean of the two steps; dynamic relaxation at
    /// the rate `r`.
    pub(super) fn coefficients(&self, damping: f64, r: f64) -> (f64, f64, f64) {
        let (dt, dt_prev) = (self.dt, self.dt_prev);
        if self.dynamic && dt == dt_prev {
            let h = 0.5 * damping * dt;
            (dt * dt / (1.0 + h), 2.0 / (1.0 + h), -(1.0 - h) / (1.0 + h))
        } else if self.dynamic {
            let h_avg = 0.5 * (dt + dt_prev);
            let h = 0.5 * damping * h_avg;
            let q = dt / dt_prev * (1.0 - h) / (1.0 + h);
            (dt * h_avg / (1.0 + h), 1.0 + q, -q)
        } else {
            let a = 0.25 * ((1.0 + r) * dt).powi(2);
            (a, 1.0 + r * r, -r * r)
        }
    }
}

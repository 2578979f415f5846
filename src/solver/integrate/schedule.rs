//! When the time loop estimates its critical step again at the deformed state
//! ([`super::Settings::step_update`]), and how far it lets the estimate move the step.

/// Step updates ([`super::Settings::step_update`]): the first estimate at the deformed state comes
/// after this many steps; the interval then follows how fast the estimate moves, so that
/// omega_max changes by about [`UPDATE_CHANGE`] between estimates, within
/// [`UPDATE_MIN`]..[`UPDATE_MAX`] steps. An estimate takes 7-22 force evaluations on average;
/// the default cylinder compression spends 3-7 % of its steps' force evaluations on them.
const UPDATE_FIRST: usize = 100;
const UPDATE_MIN: usize = 50;
const UPDATE_MAX: usize = 2000;
const UPDATE_CHANGE: f64 = 0.02;
/// An estimate is also due once a node may have moved this fraction of the distance the
/// fastest wave covers in a critical step (about the smallest element's size) since the last
/// one: the frequencies follow the strains, whose rate the interval's history cannot foresee
/// when the loading speeds up.
const UPDATE_TRAVEL: f64 = 0.25;
/// ... up to this many times farther where estimates due to motion alone found the
/// frequencies unchanged (back to 1 at the first estimate that finds them moving).
const UPDATE_TRAVEL_GROWTH: f64 = 64.0;
/// The step is shortened only when the new estimate is this much below it (1 % is within the
/// allowance), so small wobbles of the estimate do not re-divide the run.
pub(super) const UPDATE_HYSTERESIS: f64 = 0.01;
/// The estimates at the deformed state are fresh: they keep this fraction of 2 / omega_max
/// instead of the reference estimate's [`super::DEFORMATION_ALLOWANCE`] (the controller above bounds
/// how far the frequencies move between estimates). With the 0.8 the 20 % compression of the
/// cylinder (fe hex8) shortened its step to 0.75x for 14 % more steps.
pub const UPDATE_ALLOWANCE: f64 = 0.95;
/// Ritz residual at which an update stops (relative; the reference estimate's is 1e-3). The
/// residual is added to the Ritz value, so a looser stop only shortens the step, by about
/// half of it.
pub(super) const UPDATE_TOLERANCE: f64 = 1e-2;
/// A step that has fallen below this fraction of the initial one stops the run: a point is
/// collapsing, and the run would take over 100x the planned steps.
pub(super) const UPDATE_MIN_RATIO: f64 = 0.01;

/// When the step is estimated again during a run ([`super::Settings::step_update`]).
pub(super) struct UpdateSchedule {
    /// The next step an estimate is due at by the interval.
    next: usize,
    interval: usize,
    /// The step of the last estimate.
    pub(super) last: usize,
    /// The last estimate of lambda_max, 1/s^2 (at first the reference one, where global).
    lambda: Option<f64>,
    /// The largest nodal change per step summed since the last estimate (m): a bound on how far
    /// any node has moved since, whatever the interval.
    pub(super) travel: f64,
    /// Multiplies [`UPDATE_TRAVEL`].
    travel_scale: f64,
}

impl UpdateSchedule {
    pub(super) fn new(reference_lambda: Option<f64>) -> Self {
        UpdateSchedule {
            next: UPDATE_FIRST,
            interval: UPDATE_FIRST,
            last: 0,
            lambda: reference_lambda,
            travel: 0.0,
            travel_scale: 1.0,
        }
    }

    /// Whether an estimate is due at `step`, and if so whether by the distance moved (`reach`:
    /// the distance the fastest wave covers in a critical step, m) rather than the interval.
    pub(super) fn due(&self, step: usize, reach: f64) -> Option<bool> {
        let by_travel = self.travel > self.travel_scale * UPDATE_TRAVEL * reach
            && step >= self.last + UPDATE_MIN;
        (step >= self.next || by_travel).then_some(by_travel)
    }

    /// An estimate made at `step` (lambda_max, 1/s^2, None where it failed): the next interval
    /// aims at a change of [`UPDATE_CHANGE`] in omega_max.
    pub(super) fn record(&mut self, step: usize, lambda: Option<f64>, by_travel: bool) {
        self.travel = 0.0;
        self.last = step;
        if let Some(l) = lambda {
            if let Some(l0) = self.lambda {
                let change = ((l / l0).sqrt() - 1.0).abs();
                let scale = if change > 0.0 {
                    (UPDATE_CHANGE / change).clamp(0.5, 2.0)
                } else {
                    2.0
                };
                self.interval =
                    ((self.interval as f64 * scale) as usize).clamp(UPDATE_MIN, UPDATE_MAX);
                // Motion without strain (a rigid rotation) moves nodes without moving the
                // frequencies: each estimate it triggers in vain doubles the distance.
                if change > UPDATE_CHANGE {
                    self.travel_scale = 1.0;
                } else if by_travel && change < 0.25 * UPDATE_CHANGE {
                    self.travel_scale = (2.0 * self.travel_scale).min(UPDATE_TRAVEL_GROWTH);
                }
            }
            self.lambda = Some(l);
        }
        self.next = step + self.interval;
    }
}

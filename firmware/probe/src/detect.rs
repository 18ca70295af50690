//! Stuck-reading detection: a live FSR behind a 12- or 16-bit converter always shows a few
//! counts of noise, so a reading that does not change for a whole window means the converter,
//! the bus or the wiring is frozen. At the rails (open or saturated) a constant reading is
//! expected and is not flagged.

/// Counts identical consecutive readings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StuckDetector {
    window: u32,
    last: Option<i16>,
    run: u32,
}

impl StuckDetector {
    /// Flags after `window` identical readings in a row (window 0 disables the check).
    pub fn new(window: u32) -> Self {
        Self {
            window,
            last: None,
            run: 0,
        }
    }

    /// Feeds a reading; `at_rail` readings reset the count. Returns true while stuck.
    pub fn update(&mut self, counts: i16, at_rail: bool) -> bool {
        if at_rail || self.last != Some(counts) {
            self.run = 0;
        } else {
            self.run = self.run.saturating_add(1);
        }
        self.last = Some(counts);
        self.window > 0 && self.run + 1 >= self.window
    }
}

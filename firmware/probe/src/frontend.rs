//! Counts → divider voltage → FSR conductance, with the saturation and open-circuit checks that
//! belong to this conversion (thesis §4.2: sensor value → force through the fitted curve).

use palpate_protocol::link::{status, Calibration};

/// Thresholds of the analogue front end.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrontEndLimits {
    /// Below this conductance (µS) the sensor is taken as not conducting (`OPEN_CIRCUIT`).
    /// 0.5 µS = 2 MΩ: Interlink FSRs rest above 1 MΩ unloaded and fall below 100 kΩ at their
    /// turn-on force.
    pub open_conductance_us: f32,
    /// Divider output as a fraction of the supply above which the reading is `SATURATED`
    /// (0.99: the FSR is below 1 % of the pull-down, ~100 Ω for 10 kΩ, where one ADC count
    /// spans more force than the calibration resolves).
    pub saturation_fraction: f32,
}

impl Default for FrontEndLimits {
    fn default() -> Self {
        Self {
            open_conductance_us: 0.5,
            saturation_fraction: 0.99,
        }
    }
}

/// One converted reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Divider output in volts.
    pub volts: f32,
    /// Sensor conductance in µS (clamped to the saturation point when saturated; 0 when open).
    pub conductance_us: f32,
    /// `SATURATED` and/or `OPEN_CIRCUIT`.
    pub flags: u8,
}

/// The conversion from ADC counts to sensor conductance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontEnd {
    /// The calibration in force.
    pub calibration: Calibration,
    /// Volts per ADC count at the configured range.
    pub volts_per_count: f32,
    /// The ADC's largest count (clipping).
    pub full_count: i16,
    /// Thresholds.
    pub limits: FrontEndLimits,
}

impl FrontEnd {
    /// Converts a raw reading.
    pub fn convert(&self, counts: i16) -> Reading {
        let d = &self.calibration.divider;
        let volts = f32::from(counts) * self.volts_per_count;
        let v_sat = d.v_supply_v * self.limits.saturation_fraction;
        let clipped = counts >= self.full_count.saturating_sub(1);
        if clipped || volts >= v_sat {
            let g = d.conductance_us(v_sat).unwrap_or(0.0);
            return Reading {
                volts,
                conductance_us: g,
                flags: status::SATURATED,
            };
        }
        match d.conductance_us(volts) {
            Some(g) if g >= self.limits.open_conductance_us => Reading {
                volts,
                conductance_us: g,
                flags: status::OK,
            },
            _ => Reading {
                volts,
                conductance_us: 0.0,
                flags: status::OPEN_CIRCUIT,
            },
        }
    }

    /// Force in N for a conductance, through the calibration curve.
    pub fn force_n(&self, conductance_us: f32) -> f32 {
        self.calibration.curve.force_n(conductance_us)
    }

    /// `OUT_OF_RANGE` when a non-zero force lies outside the calibration's usable range.
    pub fn range_flag(&self, force_n: f32) -> u8 {
        let c = &self.calibration;
        if force_n > c.usable_max_n || (force_n > 0.0 && force_n < c.usable_min_n) {
            status::OUT_OF_RANGE
        } else {
            status::OK
        }
    }
}

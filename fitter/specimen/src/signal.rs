//! The size of an injected effect: what it moves the markers by, against a reference world.

/// RMS over measurements and markers (m) of what effect `spec` alone does to the noise-free,
/// registration-free truth markers of seed `seed`, beyond what the reported data explain: the
/// specimen's truth minus the truth of the reference world, in which the applied force is the
/// reported one and nothing else is injected
/// ([`crate::SpecimenOptions::apply_reported_force`]). So a calibration error counts as the
/// displacement its force error causes, a tilt as the displacement of its tangential force, a
/// stiffening as the displacement it withholds. (Registration, noise, a noisy rest scan and
/// occlusion act on the measured or declared positions, not the truth: their signal here is
/// zero.)
pub fn signal_rms(truth: &crate::Truth, reference: &crate::Truth) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (a, b) in truth.measurements.iter().zip(&reference.measurements) {
        for (p, q) in a.markers.iter().zip(&b.markers) {
            sum += (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>();
            n += 1;
        }
    }
    (sum / n.max(1) as f64).sqrt()
}

//! The look controls an artist reads in photographic units: exposure in stops (the tone
//! map's factor is 2^stops, as the scripted `exposure` action's `stops`; `--exposure` and
//! the copied command keep the factor).

/// The stops the slider spans, each way from a factor of 1.
pub const MAX_STOPS: f64 = 10.0;

/// The stops of tone-map factor `exposure` (clamped to the slider's span).
pub fn stops_of(exposure: f32) -> f64 {
    f64::from(exposure)
        .max(f64::MIN_POSITIVE)
        .log2()
        .clamp(-MAX_STOPS, MAX_STOPS)
}

/// The exposure slider in stops; `exposure` (the factor) changes only when the slider does.
pub fn exposure_stops(ui: &mut egui::Ui, exposure: &mut f32) {
    let mut stops = stops_of(*exposure);
    let r = ui.add(
        egui::Slider::new(&mut stops, -MAX_STOPS..=MAX_STOPS)
            .step_by(0.1)
            .suffix(" stops")
            .text("exposure"),
    );
    if r.changed() {
        *exposure = stops.exp2() as f32;
    }
    r.on_hover_text(format!(
        "a tone-map factor of {:.4} (--exposure)",
        *exposure
    ));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stops_are_powers_of_two_of_the_factor() {
        assert_eq!(stops_of(1.0), 0.0);
        assert_eq!(stops_of(4.0), 2.0);
        assert_eq!(stops_of(0.125), -3.0);
        assert_eq!(stops_of(1e9), MAX_STOPS);
        assert_eq!(stops_of(0.0), -MAX_STOPS);
    }
}

//! Noise schedules and samplers (pure f64 math).

//! Wall-clock stage timings: the one small type every command's timing report is built from
//! (`kfuse calibrate`'s `report.json` `timings_ms`, `kfuse fuse --timings`, the calibration
//! fits' own split). A [`Timings`] is a list of named stages in the order they first ran, each
//! with its milliseconds summed over every time it ran.
//!
//! Timings are for people reading where a run's time goes; nothing depends on their values
//! (tests check their structure and consistency, never a duration).

use std::time::Instant;

use serde::Serialize;

/// Milliseconds since `t`.
pub fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// One stage's time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageTime {
    /// The stage's name ("read IR", "fit stereo", …).
    pub stage: String,
    /// Milliseconds, summed over every time the stage ran.
    pub ms: f64,
}

/// Named stages in the order they first ran, milliseconds each (serialised as a list of
/// `{"stage", "ms"}`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
#[serde(transparent)]
pub struct Timings {
    stages: Vec<StageTime>,
}

impl Timings {
    /// No stage yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `ms` to `stage` (appended when it has not run before). Negative or non-finite
    /// values count as 0: a clock never runs backwards, and a sum of stages must stay finite.
    pub fn add(&mut self, stage: &str, ms: f64) {
        let ms = if ms.is_finite() { ms.max(0.0) } else { 0.0 };
        match self.stages.iter_mut().find(|s| s.stage == stage) {
            Some(s) => s.ms += ms,
            None => self.stages.push(StageTime { stage: stage.to_string(), ms }),
        }
    }

    /// Runs `f`, adding its wall time to `stage`.
    pub fn time<T>(&mut self, stage: &str, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = f();
        self.add(stage, ms_since(t));
        out
    }

    /// Adds every stage of `other`, each name prefixed by `prefix` (`""` for none).
    pub fn extend(&mut self, prefix: &str, other: &Timings) {
        for s in &other.stages {
            self.add(&format!("{prefix}{}", s.stage), s.ms);
        }
    }

    /// The stages in the order they first ran.
    pub fn stages(&self) -> &[StageTime] {
        &self.stages
    }

    /// The milliseconds of `stage`, if it ran.
    pub fn get(&self, stage: &str) -> Option<f64> {
        self.stages.iter().find(|s| s.stage == stage).map(|s| s.ms)
    }

    /// The sum of every stage, ms.
    pub fn total_ms(&self) -> f64 {
        self.stages.iter().map(|s| s.ms).sum()
    }

    /// Whether no stage ran.
    pub fn is_empty(&self) -> bool {
        self.stages.is_empty()
    }

    /// The compact summary `--timings` prints: a `timings:` line with the wall time, one
    /// line per stage with its ms and share of the wall time (and its ms per item where
    /// `per` gives a count and the items' name, e.g. `(12, "image")`, for stages whose name
    /// is in `per_stages`), and the part of the wall time no stage accounts for.
    pub fn summary(&self, wall_ms: f64, per: Option<(usize, &str, &[&str])>) -> Vec<String> {
        let share = |ms: f64| if wall_ms > 0.0 { 100.0 * ms / wall_ms } else { 0.0 };
        let width = self.stages.iter().map(|s| s.stage.chars().count()).max().unwrap_or(0);
        let mut lines = vec![format!("timings: {wall_ms:.1} ms wall")];
        for s in &self.stages {
            let mut line =
                format!("  {:<width$}  {:>9.1} ms  {:>5.1} %", s.stage, s.ms, share(s.ms));
            if let Some((n, unit, stages)) = per
                && n > 0
                && stages.contains(&s.stage.as_str())
            {
                line.push_str(&format!("  {:.2} ms/{unit}", s.ms / n as f64));
            }
            lines.push(line);
        }
        let rest = wall_ms - self.total_ms();
        lines.push(format!(
            "  {:<width$}  {:>9.1} ms  {:>5.1} %",
            "(not in a stage)",
            rest.max(0.0),
            share(rest.max(0.0))
        ));
        lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_accumulate_in_first_run_order_and_clamp_bad_values() {
        let mut t = Timings::new();
        t.add("read", 2.0);
        t.add("detect", 3.0);
        t.add("read", 1.5);
        t.add("bad", f64::NAN);
        t.add("bad", -4.0);
        let names: Vec<&str> = t.stages().iter().map(|s| s.stage.as_str()).collect();
        assert_eq!(names, ["read", "detect", "bad"]);
        assert_eq!(t.get("read"), Some(3.5));
        assert_eq!(t.get("bad"), Some(0.0));
        assert_eq!(t.total_ms(), 6.5);
        let mut u = Timings::new();
        u.extend("mono ", &t);
        assert_eq!(u.get("mono detect"), Some(3.0));
        let json = serde_json::to_value(&t).unwrap();
        assert_eq!(json[0]["stage"], "read");
        assert_eq!(json[0]["ms"], 3.5);
    }

    #[test]
    fn the_summary_has_a_line_per_stage_and_the_rest() {
        let mut t = Timings::new();
        t.add("read", 4.0);
        t.add("fit", 2.0);
        let lines = t.summary(10.0, Some((2, "image", &["read"])));
        assert_eq!(lines.len(), 4, "{lines:?}");
        assert!(lines[0].starts_with("timings: 10.0 ms wall"), "{lines:?}");
        assert!(lines[1].contains("read") && lines[1].contains("40.0 %"), "{lines:?}");
        assert!(lines[1].contains("2.00 ms/image"), "{lines:?}");
        assert!(!lines[2].contains("ms/image"), "{lines:?}");
        assert!(lines[3].contains("(not in a stage)") && lines[3].contains("4.0 ms"), "{lines:?}");
    }
}

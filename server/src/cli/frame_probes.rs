//! The probe volume's part of `frame-time --update one-light` ([`super::frame_update`]): a game
//! with dynamic objects also keeps the probe field they read up to date while a light moves.
//! Both ways feed it the light leaving the surfaces (direct light at one bounce, direct plus
//! indirect with more, as `eval` does):
//! - **full**: `Runtime::apply_probes` on the whole leaving light, every frame;
//! - **update**: `Runtime::apply_probes_delta` on its change, the moved light's change of
//!   direct light plus the change of indirect light relighting by the change wrote (on
//!   `Runtime::delta_written`'s ranges), gathered only on the texels the probes read
//!   (`Runtime::probe_source_spans`): a change elsewhere moves no probe.
//!
//! The update's field is compared after the last frame with `apply_probes` of the update's
//! own leaving light (relative L2 over the field's values): they agree within float rounding.
//!
//! Units: milliseconds of wall time on this thread.

use std::ops::Range;
use std::time::Instant;

use lightfarm_client::{merge_spans, DirectLight, IndirectLight, ProbeField, Runtime};

use super::frame_update::median;
use crate::evaluate::leaving_light;

/// The probe volume's figures of one `--update one-light` run (medians over frames, ms).
#[derive(Clone, Copy, Debug)]
pub struct ProbeTimes {
    pub probes: usize,
    /// `apply_probes` of the whole leaving light (NaN when only the update way ran).
    pub full_ms: f64,
    /// The change of leaving light gathered and `apply_probes_delta`.
    pub update_ms: f64,
    /// Relative L2 between the update's field and `apply_probes` of its leaving light.
    pub drift: f64,
}

/// The update way's probe field and what it needs from frame to frame.
pub struct ProbeWay {
    bounced: bool,
    field: ProbeField,
    /// The indirect light as of the last probe update (bounced only).
    indirect: Vec<[f32; 3]>,
    /// The change of leaving light, zero outside `spans` between frames.
    change: DirectLight,
    spans: Vec<Range<usize>>,
    full_times: Vec<f64>,
    times: Vec<f64>,
}

impl ProbeWay {
    /// The field of the first frame's leaving light (`direct` and, when `bounced`,
    /// `indirect`); None for a bundle without a probe volume.
    pub fn new(
        runtime: &mut Runtime,
        direct: &DirectLight,
        indirect: &IndirectLight,
        bounced: bool,
    ) -> anyhow::Result<Option<ProbeWay>> {
        if !runtime.has_probes() {
            return Ok(None);
        }
        let mut field = ProbeField::default();
        let n = runtime.n_texels();
        fill_field(runtime, bounced, direct, indirect, &mut field)?;
        Ok(Some(ProbeWay {
            bounced,
            field,
            indirect: if bounced {
                indirect.radiance.clone()
            } else {
                Vec::new()
            },
            change: DirectLight {
                radiance: vec![[0.0; 3]; n],
            },
            spans: Vec::new(),
            full_times: Vec::new(),
            times: Vec::new(),
        }))
    }

    /// The full way's frame: `apply_probes` of the leaving light of `direct` and `indirect`
    /// (making that light is part of the frame), timed.
    pub fn full_frame(
        &mut self,
        runtime: &mut Runtime,
        direct: &DirectLight,
        indirect: &IndirectLight,
        field: &mut ProbeField,
    ) -> anyhow::Result<()> {
        let start = Instant::now();
        fill_field(runtime, self.bounced, direct, indirect, field)?;
        self.full_times.push(start.elapsed().as_secs_f64() * 1e3);
        Ok(())
    }

    /// The update way's frame, after `runtime.apply_delta_in` relit by `direct_change` (non-zero
    /// on `direct_spans` only) into `indirect`: the change of leaving light and
    /// `apply_probes_delta`, timed.
    pub fn update_frame(
        &mut self,
        runtime: &mut Runtime,
        direct_change: &DirectLight,
        direct_spans: &[Range<usize>],
        indirect: &IndirectLight,
    ) -> anyhow::Result<()> {
        let start = Instant::now();
        for span in &self.spans {
            self.change.radiance[span.clone()].fill([0.0; 3]);
        }
        let read = runtime.probe_source_spans();
        let direct = intersection(direct_spans, read);
        for t in direct.iter().flat_map(Range::clone) {
            self.change.radiance[t] = direct_change.radiance[t];
        }
        self.spans = direct;
        if self.bounced {
            let mut written: Vec<Range<usize>> = match runtime.delta_written() {
                Some(ranges) => ranges.collect(),
                None => std::iter::once(0..runtime.n_texels()).collect(),
            };
            merge_spans(&mut written);
            let written = intersection(&written, read);
            for r in &written {
                for t in r.clone() {
                    let (now, was) = (indirect.radiance[t], &mut self.indirect[t]);
                    // Zero here unless the direct light changed too (the last frame's spans
                    // were cleared above).
                    let c = &mut self.change.radiance[t];
                    for ch in 0..3 {
                        c[ch] += now[ch] - was[ch];
                    }
                    *was = now;
                }
            }
            self.spans.extend(written);
            merge_spans(&mut self.spans);
        }
        runtime.apply_probes_delta(&self.change, &self.spans, &mut self.field)?;
        self.times.push(start.elapsed().as_secs_f64() * 1e3);
        Ok(())
    }

    /// The update way's probe field as of its last frame.
    pub fn field(&self) -> &ProbeField {
        &self.field
    }

    /// The figures, after the last frame: the update's field against `apply_probes` of its
    /// leaving light (`direct` and `indirect`, the update's answer).
    pub fn finish(
        self,
        runtime: &mut Runtime,
        direct: &DirectLight,
        indirect: &IndirectLight,
    ) -> anyhow::Result<ProbeTimes> {
        let mut want = ProbeField::default();
        fill_field(runtime, self.bounced, direct, indirect, &mut want)?;
        let (mut d2, mut w2) = (0.0f64, 0.0f64);
        for (g, w) in self.field.as_slice().iter().zip(want.as_slice()) {
            d2 += (*g as f64 - *w as f64).powi(2);
            w2 += (*w as f64).powi(2);
        }
        let median = |v: Vec<f64>| if v.is_empty() { f64::NAN } else { median(v) };
        Ok(ProbeTimes {
            probes: want.n_probes(),
            full_ms: median(self.full_times),
            update_ms: median(self.times),
            drift: if w2 > 0.0 {
                (d2 / w2).sqrt()
            } else {
                d2.sqrt()
            },
        })
    }
}

/// `apply_probes` of the light leaving the texels into `field`: `direct` at one bounce, with
/// `bounced` direct plus `indirect` (as `eval` feeds the probes).
fn fill_field(
    runtime: &mut Runtime,
    bounced: bool,
    direct: &DirectLight,
    indirect: &IndirectLight,
    field: &mut ProbeField,
) -> anyhow::Result<()> {
    if bounced {
        runtime.apply_probes(&leaving_light(direct, indirect), field)?;
    } else {
        runtime.apply_probes(direct, field)?;
    }
    Ok(())
}

/// The texels in both `a` and `b` (each ascending and disjoint), ascending and disjoint.
fn intersection(a: &[Range<usize>], b: &[Range<usize>]) -> Vec<Range<usize>> {
    let (mut i, mut j, mut out) = (0, 0, Vec::new());
    while i < a.len() && j < b.len() {
        let (start, end) = (a[i].start.max(b[j].start), a[i].end.min(b[j].end));
        if start < end {
            out.push(start..end);
        }
        if a[i].end < b[j].end {
            i += 1;
        } else {
            j += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intersections_hold_the_texels_in_both() {
        let a = [0..5, 8..12, 20..30];
        let b = [3..9, 11..21, 29..40];
        assert_eq!(
            intersection(&a, &b),
            vec![3..5, 8..9, 11..12, 20..21, 29..30]
        );
        assert_eq!(intersection(&a, &[]), Vec::<Range<usize>>::new());
        // Touching is not overlapping.
        assert_eq!(
            intersection(&[0..10, 30..35], &[10..20, 35..36]),
            Vec::<Range<usize>>::new()
        );
    }
}

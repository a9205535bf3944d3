//! The GPU's films: a target's passes ([`GpuTarget`] as [`Passes`]) and a film past one
//! target's storage bindings driven over several targets ([`GpuChunks`]).

use super::passes::{PassReport, Passes};
use crate::error::{Error, Result};
use crate::film::{BlockSums, ExactSums};
use crate::gpu::stats::{AdaptQuery, AdaptSums, CheckQuery, CheckSums, Stop};
use crate::gpu::{GpuTarget, MAX_PASS_SAMPLES};

/// The slots `range` of `exact`: its sums (and replicates' squares, where it has them).
fn sums_part(exact: &ExactSums, range: std::ops::Range<usize>) -> ExactSums {
    ExactSums {
        sum: exact.sum[range.clone()].to_vec(),
        sum_sq: exact.sum_sq[range.clone()].to_vec(),
        replicate_sq: exact.replicate_sq.get(range).map_or_else(Vec::new, <[_]>::to_vec),
        pixel_samples: Vec::new(),
        pixel_replicates: Vec::new(),
        stopped: Vec::new(),
        ..*exact
    }
}

impl Passes for GpuTarget {
    fn pass(&mut self, first: u32, count: u32) -> Result<PassReport> {
        let c = self.render_pass(first, count)?;
        Ok(PassReport { ao_rays: c.ao_rays, gpu_seconds: c.gpu_seconds })
    }

    fn max_pass_samples(&self) -> u32 {
        MAX_PASS_SAMPLES
    }

    fn read(&mut self) -> Result<BlockSums> {
        self.film_block()
    }

    fn take(&mut self) -> Result<BlockSums> {
        let block = Passes::read(self)?;
        self.clear_film()?;
        self.mark_inactive(None)?;
        Ok(block)
    }

    fn load(&mut self, block: &BlockSums) -> Result<()> {
        let words = block.to_words();
        self.set_film_words(&words)?;
        self.mark_inactive(Some(&words))
    }

    fn device_bytes(&self) -> u64 {
        self.all_device_bytes()
    }

    fn keeps_sums(&self) -> bool {
        GpuTarget::keeps_sums(self)
    }

    fn write_sums(&mut self, exact: &ExactSums, samples: u32) -> Result<()> {
        GpuTarget::write_sums(self, exact, samples)
    }

    fn fold(&mut self, replicate: bool, taken: u32) -> Result<()> {
        GpuTarget::fold(self, replicate, taken)
    }

    fn adapt_check(&mut self, query: AdaptQuery, exponents: (i32, i32)) -> Result<(AdaptSums, Option<u32>)> {
        GpuTarget::adapt_check(self, query, exponents)
    }

    fn allocate(&mut self, query: AdaptQuery, exponents: (i32, i32), per_sigma: f32, stop: Stop) -> Result<(u32, u32)> {
        GpuTarget::allocate(self, query, exponents, per_sigma, stop)
    }

    fn read_counts(&mut self) -> Result<Vec<(u32, u32, bool)>> {
        GpuTarget::read_counts(self)
    }

    fn check(&mut self, query: CheckQuery, exponents: (i32, i32)) -> Result<(CheckSums, Option<u32>)> {
        GpuTarget::check(self, query, exponents)
    }

    fn read_sums(&mut self, exact: &mut ExactSums, replicates: bool) -> Result<Option<u32>> {
        GpuTarget::read_sums(self, exact, replicates)
    }

    fn take_readback_bytes(&mut self) -> u64 {
        GpuTarget::take_readback_bytes(self)
    }

    fn round_trips(&self) -> u64 {
        GpuTarget::round_trips(self)
    }

    fn set_inactive(&mut self, inactive: &[bool]) -> Result<()> {
        self.stop_pixels(inactive)
    }
}

/// A film past one target's storage bindings (lavapipe binds 128 MiB: an image of
/// 8,388,608 pixels, 2,796,202 probe points) over several targets, driven as one film:
/// slot order and sums are those of a single target. An image's targets are bands of
/// rows, a probe request's contiguous ranges of the points, each numbering its sample
/// sequences from its first point's index.
pub(super) struct GpuChunks {
    /// Each target, and its film's slots.
    pub(super) targets: Vec<(GpuTarget, usize)>,
}

impl GpuChunks {
    /// `words` (one entry per slot of the whole film) cut into the targets' parts.
    fn split<'a, T>(&self, words: &'a [T]) -> Vec<&'a [T]> {
        let mut start = 0;
        self.targets
            .iter()
            .map(|(_, slots)| {
                let part = &words[start.min(words.len())..(start + slots).min(words.len())];
                start += slots;
                part
            })
            .collect()
    }

    fn join(blocks: Vec<BlockSums>) -> BlockSums {
        let mut out = BlockSums::default();
        for block in blocks {
            out.sum.extend(block.sum);
            out.sum_sq.extend(block.sum_sq);
        }
        out
    }
}

impl Passes for GpuChunks {
    fn max_pass_samples(&self) -> u32 {
        MAX_PASS_SAMPLES
    }

    fn pass(&mut self, first: u32, count: u32) -> Result<PassReport> {
        let mut report = PassReport { ao_rays: 0, gpu_seconds: Some(0.0) };
        for (target, _) in &mut self.targets {
            let r = Passes::pass(target, first, count)?;
            report.ao_rays += r.ao_rays;
            report.gpu_seconds = report.gpu_seconds.zip(r.gpu_seconds).map(|(a, b)| a + b);
        }
        Ok(report)
    }

    fn read(&mut self) -> Result<BlockSums> {
        let blocks = self.targets.iter_mut().map(|(t, _)| Passes::read(t)).collect::<Result<Vec<_>>>()?;
        Ok(GpuChunks::join(blocks))
    }

    fn take(&mut self) -> Result<BlockSums> {
        let blocks = self.targets.iter_mut().map(|(t, _)| Passes::take(t)).collect::<Result<Vec<_>>>()?;
        Ok(GpuChunks::join(blocks))
    }

    fn load(&mut self, block: &BlockSums) -> Result<()> {
        if block.len() != self.targets.iter().map(|(_, slots)| slots).sum::<usize>() {
            return Err(Error::settings("the checkpoint's block does not fit the film"));
        }
        let (sums, squares) = (self.split(&block.sum), self.split(&block.sum_sq));
        let parts: Vec<BlockSums> =
            sums.into_iter().zip(squares).map(|(s, q)| BlockSums { sum: s.to_vec(), sum_sq: q.to_vec() }).collect();
        for ((target, _), part) in self.targets.iter_mut().zip(parts) {
            Passes::load(target, &part)?;
        }
        Ok(())
    }

    fn device_bytes(&self) -> u64 {
        self.targets.iter().map(|(t, _)| t.all_device_bytes()).sum()
    }

    fn keeps_sums(&self) -> bool {
        self.targets.iter().all(|(t, _)| t.keeps_sums())
    }

    fn write_sums(&mut self, exact: &ExactSums, samples: u32) -> Result<()> {
        let mut start = 0;
        for (target, slots) in &mut self.targets {
            let range = start..start + *slots;
            let mut part = sums_part(exact, range.clone());
            if !exact.pixel_samples.is_empty() {
                part.pixel_samples = exact.pixel_samples[range.clone()].to_vec();
                part.pixel_replicates = exact.pixel_replicates[range].to_vec();
            }
            target.write_sums(&part, samples)?;
            start += *slots;
        }
        Ok(())
    }

    fn fold(&mut self, replicate: bool, taken: u32) -> Result<()> {
        self.targets.iter_mut().try_for_each(|(t, _)| t.fold(replicate, taken))
    }

    fn adapt_check(&mut self, query: AdaptQuery, exponents: (i32, i32)) -> Result<(AdaptSums, Option<u32>)> {
        let (mut total, mut bad, mut start) = (None::<AdaptSums>, None, 0u32);
        for (target, slots) in &mut self.targets {
            let (s, b) = target.adapt_check(query, exponents)?;
            total = Some(match total {
                None => s,
                Some(t) => AdaptSums {
                    variance: t.variance + s.variance,
                    variance_sq: t.variance_sq + s.variance_sq,
                    mean: t.mean + s.mean,
                    sigma: t.sigma + s.sigma,
                    fewest: t.fewest.into_iter().chain(s.fewest).min(),
                    most: t.most.max(s.most),
                    pixels: t.pixels + s.pixels,
                },
            });
            bad = bad.or(b.map(|b| b + start));
            start += *slots as u32;
        }
        Ok((total.unwrap_or_default(), bad))
    }

    fn allocate(&mut self, query: AdaptQuery, exponents: (i32, i32), per_sigma: f32, stop: Stop) -> Result<(u32, u32)> {
        // Each target counts its own pixels; whether any goes on is the whole film's.
        let each = match stop {
            Stop::IfAnyGoesOn => Stop::Count,
            other => other,
        };
        let mut total = (0, 0);
        for (target, _) in &mut self.targets {
            let (stops, go) = target.allocate(query, exponents, per_sigma, each)?;
            total = (total.0 + stops, total.1 + go);
        }
        if each != stop && total.0 > 0 && stop.applies(total.1) {
            for (target, _) in &mut self.targets {
                target.allocate(query, exponents, per_sigma, Stop::Always)?;
            }
        }
        Ok(total)
    }

    fn read_counts(&mut self) -> Result<Vec<(u32, u32, bool)>> {
        let mut counts = Vec::new();
        for (target, _) in &mut self.targets {
            counts.extend(target.read_counts()?);
        }
        Ok(counts)
    }

    fn check(&mut self, query: CheckQuery, exponents: (i32, i32)) -> Result<(CheckSums, Option<u32>)> {
        let (mut total, mut bad, mut start) = (CheckSums::default(), None, 0u32);
        for (target, slots) in &mut self.targets {
            let (sums, b) = target.check(query, exponents)?;
            total = total + sums;
            bad = bad.or(b.map(|b| b + start));
            start += *slots as u32;
        }
        Ok((total, bad))
    }

    fn read_sums(&mut self, exact: &mut ExactSums, replicates: bool) -> Result<Option<u32>> {
        let (mut bad, mut start) = (None, 0usize);
        if replicates && exact.replicate_sq.len() != exact.sum.len() {
            exact.replicate_sq = vec![0; exact.sum.len()];
        }
        for (target, slots) in &mut self.targets {
            let range = start..start + *slots;
            let mut part = sums_part(exact, range.clone());
            let b = target.read_sums(&mut part, replicates)?;
            exact.sum[range.clone()].copy_from_slice(&part.sum);
            exact.sum_sq[range.clone()].copy_from_slice(&part.sum_sq);
            if replicates {
                exact.replicate_sq[range].copy_from_slice(&part.replicate_sq);
            }
            bad = bad.or(b.map(|b| b + start as u32));
            start += *slots;
        }
        Ok(bad)
    }

    fn take_readback_bytes(&mut self) -> u64 {
        self.targets.iter().map(|(t, _)| GpuTarget::take_readback_bytes(t)).sum()
    }

    fn round_trips(&self) -> u64 {
        // The bands share one device: its count is theirs.
        self.targets.first().map_or(0, |(t, _)| GpuTarget::round_trips(t))
    }

    fn set_inactive(&mut self, inactive: &[bool]) -> Result<()> {
        let parts: Vec<Vec<bool>> = if inactive.is_empty() {
            vec![Vec::new(); self.targets.len()]
        } else {
            self.split(inactive).into_iter().map(<[_]>::to_vec).collect()
        };
        for ((target, _), part) in self.targets.iter_mut().zip(parts) {
            Passes::set_inactive(target, &part)?;
        }
        Ok(())
    }
}

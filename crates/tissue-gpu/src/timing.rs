//! Per-kernel GPU time of one stage-2 iteration by timestamp queries: each
//! kernel in a compute pass of its own that writes a timestamp at its start
//! and end. The library itself asks for no optional features; this is for a
//! caller (the benchmark) that opened its device with
//! `wgpu::Features::TIMESTAMP_QUERY`.

use crate::GpuError;
use crate::pipelines::{Kernel, Pipelines};
use crate::readback::read_buffer;
use crate::state::DeformState;
use crate::support::Scopes;

/// GPU time of one iteration, from the device's own clock.
#[derive(Clone, Debug, PartialEq)]
pub struct IterationTimes {
    /// Milliseconds of each kernel's pass, in the order of
    /// [`DeformState::iteration`].
    pub kernels: Vec<(Kernel, f64)>,
    /// Milliseconds from the first kernel's start to the last one's end
    /// (the kernels, and the gaps between their passes).
    pub iteration_ms: f64,
}

/// A query set and its resolve buffer for timing the kernels of one iteration.
#[derive(Debug)]
pub struct KernelTimer {
    /// Two timestamps per kernel of an iteration.
    queries: wgpu::QuerySet,
    /// The timestamps resolved, `u64` each (a query resolve buffer, not a
    /// storage one: raw).
    resolved: wgpu::Buffer,
    /// Nanoseconds per timestamp tick (`Queue::get_timestamp_period`).
    period_ns: f64,
}

impl KernelTimer {
    /// A timer for `device`, which must have `TIMESTAMP_QUERY` enabled; an
    /// error names the missing feature otherwise.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Self, GpuError> {
        if !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return Err(GpuError::Validation(
                "the device was opened without wgpu::Features::TIMESTAMP_QUERY".into(),
            ));
        }
        // A start and an end per kernel of the longest iteration.
        let count = 2 * Kernel::longest_iteration() as u32;
        let scope = Scopes::push(device);
        let queries = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("kernel timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count,
        });
        let resolved = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("kernel timestamps resolved"),
            size: u64::from(count) * wgpu::QUERY_SIZE as u64,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        scope.pop()?;
        Ok(Self {
            queries,
            resolved,
            period_ns: f64::from(queue.get_timestamp_period()),
        })
    }

    /// Runs one iteration with the parameters of `slot` (it moves the state
    /// like any iteration) and reads back how long each kernel took.
    pub fn time_iteration(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        pipelines: &Pipelines,
        state: &DeformState,
        slot: u32,
    ) -> Result<IterationTimes, GpuError> {
        let scope = Scopes::push(device);
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("timed iteration"),
        });
        let iteration = state.iteration();
        let used = 2 * iteration.len() as u32;
        for (k, &kernel) in (0u32..).zip(&iteration) {
            pipelines.dispatch_timed(
                &mut encoder,
                state,
                kernel,
                slot,
                Some(wgpu::ComputePassTimestampWrites {
                    query_set: &self.queries,
                    beginning_of_pass_write_index: Some(2 * k),
                    end_of_pass_write_index: Some(2 * k + 1),
                }),
            );
        }
        encoder.resolve_query_set(&self.queries, 0..used, &self.resolved, 0);
        queue.submit([encoder.finish()]);
        scope.pop()?;
        let ticks: Vec<u64> = read_buffer(device, queue, &self.resolved, used as usize)?;
        let ms = |from: u64, to: u64| to.saturating_sub(from) as f64 * self.period_ns / 1e6;
        let kernels = iteration
            .iter()
            .copied()
            .zip(ticks.chunks_exact(2))
            .map(|(kernel, pair)| (kernel, ms(pair[0], pair[1])))
            .collect();
        let (first, last) = (
            ticks.first().copied().unwrap_or(0),
            ticks.last().copied().unwrap_or(0),
        );
        Ok(IterationTimes {
            kernels,
            iteration_ms: ms(first, last),
        })
    }
}

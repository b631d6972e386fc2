//! The GPU time of the viewer's main pass, from timestamp queries read back without waiting: a
//! few slots in flight, each mapped once its frame has finished, so the number shown is a frame
//! or two old and the viewer never stalls for it.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

/// Slots in flight: frames whose times may be pending at once.
const SLOTS: usize = 3;
/// Two timestamps, eight bytes each.
const BYTES: u64 = 16;

const FREE: u8 = 0;
const PENDING: u8 = 1;
const MAPPED: u8 = 2;

struct Slot {
    queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    readback: wgpu::Buffer,
    state: Arc<AtomicU8>,
}

/// Times render passes where the device has [`wgpu::Features::TIMESTAMP_QUERY`].
pub struct GpuTimer {
    slots: Vec<Slot>,
    /// The slot this frame writes, if one was free.
    current: Option<usize>,
    period_ns: f64,
    /// The latest pass time read back, milliseconds.
    pub last_ms: Option<f64>,
}

impl GpuTimer {
    /// A timer, or `None` where the device cannot write timestamps.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Option<Self> {
        if !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let slots = (0..SLOTS)
            .map(|_| {
                let buffer = |usage| {
                    device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some("treelod view pass timer"),
                        size: BYTES,
                        usage,
                        mapped_at_creation: false,
                    })
                };
                Slot {
                    queries: device.create_query_set(&wgpu::QuerySetDescriptor {
                        label: Some("treelod view pass timer"),
                        ty: wgpu::QueryType::Timestamp,
                        count: 2,
                    }),
                    resolved: buffer(wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC),
                    readback: buffer(wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ),
                    state: Arc::new(AtomicU8::new(FREE)),
                }
            })
            .collect();
        Some(Self { slots, current: None, period_ns: f64::from(queue.get_timestamp_period()), last_ms: None })
    }

    /// Reads the slots whose frames have finished (polling the device without waiting) and picks
    /// a free slot for this frame.
    pub fn begin_frame(&mut self, device: &wgpu::Device) {
        // A poll error (device lost) shows as no new time; the frame itself reports the loss.
        let _ = device.poll(wgpu::PollType::Poll);
        for slot in &self.slots {
            if slot.state.load(Ordering::Acquire) != MAPPED {
                continue;
            }
            let ticks = slot.readback.slice(..).get_mapped_range().ok().and_then(|mapped| {
                let tick = |at: usize| Some(u64::from_le_bytes(mapped.get(at..at + 8)?.try_into().ok()?));
                Some([tick(0)?, tick(8)?])
            });
            slot.readback.unmap();
            slot.state.store(FREE, Ordering::Release);
            if let Some([start, end]) = ticks
                && end > start
            {
                self.last_ms = Some((end - start) as f64 * self.period_ns * 1e-6);
            }
        }
        self.current = self.slots.iter().position(|slot| slot.state.load(Ordering::Acquire) == FREE);
    }

    /// The timestamp writes of this frame's pass (none if every slot is still in flight).
    pub fn writes(&self) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
        let slot = &self.slots[self.current?];
        Some(wgpu::RenderPassTimestampWrites {
            query_set: &slot.queries,
            beginning_of_pass_write_index: Some(0),
            end_of_pass_write_index: Some(1),
        })
    }

    /// Copies this frame's timestamps to its readback buffer (after the pass).
    pub fn resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        if let Some(slot) = self.current.map(|i| &self.slots[i]) {
            encoder.resolve_query_set(&slot.queries, 0..2, &slot.resolved, 0);
            encoder.copy_buffer_to_buffer(&slot.resolved, 0, &slot.readback, 0, BYTES);
        }
    }

    /// Asks for this frame's readback buffer to be mapped (after the submission).
    pub fn after_submit(&mut self) {
        if let Some(slot) = self.current.take().map(|i| &self.slots[i]) {
            slot.state.store(PENDING, Ordering::Release);
            let state = Arc::clone(&slot.state);
            slot.readback.slice(..).map_async(wgpu::MapMode::Read, move |result| {
                // A failed map frees the slot without a time.
                let next = if result.is_ok() { MAPPED } else { FREE };
                state.store(next, Ordering::Release);
            });
        }
    }
}

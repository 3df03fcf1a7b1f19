//! GPU time of a session's compute passes from timestamp queries, where the device has
//! [`wgpu::Features::TIMESTAMP_QUERY`]: wall time around a submission counts the driver, the
//! queue and the wait as well, so a pass time reported as GPU time must come from the GPU's
//! own clock.

/// Where a pass time comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PassTimeSource {
    /// The GPU's timestamps written at the beginning and end of each compute pass.
    GpuTimestamps,
    /// Wall time around each submission and its wait (the device has no timestamp queries).
    Wall,
}

impl PassTimeSource {
    /// The name a report prints: `gpu-timestamps` or `wall`.
    pub fn as_str(self) -> &'static str {
        match self {
            PassTimeSource::GpuTimestamps => "gpu-timestamps",
            PassTimeSource::Wall => "wall",
        }
    }
}

impl std::fmt::Display for PassTimeSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Seconds between two raw timestamps of one queue, `period_ns` nanoseconds per tick
/// ([`wgpu::Queue::get_timestamp_period`]); `None` when the end is before the beginning (a
/// counter that wrapped or was reset between them) or the period is not a positive finite
/// number, where no duration can be told.
pub fn timestamp_seconds(begin: u64, end: u64, period_ns: f32) -> Option<f64> {
    if end < begin || !(period_ns.is_finite() && period_ns > 0.0) {
        return None;
    }
    // Ticks as f64 lose nothing below 2^53, about 104 days of a 1 ns counter.
    Some((end - begin) as f64 * f64::from(period_ns) * 1e-9)
}

/// A query set of two timestamps (begin and end of a compute pass), the buffer they resolve
/// into and a mappable copy of it.
pub(super) struct PassTimer {
    queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    readback: wgpu::Buffer,
    period_ns: f32,
}

impl PassTimer {
    /// A timer on `device`, or `None` where the device was opened without timestamp queries.
    pub(super) fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Option<Self> {
        if !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let size = 2 * u64::from(wgpu::QUERY_SIZE);
        Some(Self {
            queries: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("render pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            }),
            resolved: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("render pass timestamps resolved"),
                size,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            readback: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("render pass timestamps readback"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            period_ns: queue.get_timestamp_period(),
        })
    }

    /// The writes a compute pass makes: its beginning and its end.
    pub(super) fn writes(&self) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(0),
            end_of_pass_write_index: Some(1),
        }
    }

    /// Records, after the timed pass, the copy of its two timestamps where
    /// [`PassTimer::read`] finds them.
    pub(super) fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        enc.resolve_query_set(&self.queries, 0..2, &self.resolved, 0);
        enc.copy_buffer_to_buffer(&self.resolved, 0, &self.readback, 0, self.resolved.size());
    }

    /// The GPU seconds of the last timed pass, once its submission is done; `None` where the
    /// timestamps tell no duration ([`timestamp_seconds`]).
    pub(super) fn read(&self, device: &wgpu::Device) -> Result<Option<f64>, String> {
        let slice = self.readback.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| format!("poll: {e}"))?;
        rx.recv()
            .map_err(|e| format!("timestamp read-back: {e}"))?
            .map_err(|e| format!("timestamp read-back: {e}"))?;
        let ticks: [u64; 2] = {
            let bytes = slice
                .get_mapped_range()
                .map_err(|e| format!("timestamp read-back: {e}"))?;
            std::array::from_fn(|k| {
                let mut word = [0u8; 8];
                word.copy_from_slice(&bytes[8 * k..8 * k + 8]);
                u64::from_le_bytes(word)
            })
        };
        self.readback.unmap();
        Ok(timestamp_seconds(ticks[0], ticks[1], self.period_ns))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_convert_with_the_queue_period() {
        // 1 ns ticks: a million ticks are a millisecond.
        let close = |got: Option<f64>, want: f64| {
            let got = got.unwrap();
            assert!(
                (got - want).abs() <= 1e-12 * want.max(1e-9),
                "{got} != {want}"
            );
        };
        close(timestamp_seconds(5, 1_000_005, 1.0), 1e-3);
        // 83.333 ns ticks (a 12 MHz counter): 12 million ticks are about a second.
        let s = timestamp_seconds(0, 12_000_000, 83.333_336).unwrap();
        assert!((s - 1.0).abs() < 1e-6, "{s}");
        // Equal stamps: a pass that took no measurable time.
        assert_eq!(timestamp_seconds(7, 7, 1.0), Some(0.0));
        // Counters near the top of u64 subtract without overflow.
        close(timestamp_seconds(u64::MAX - 10, u64::MAX, 2.0), 20e-9);
    }

    #[test]
    fn untellable_durations_are_none() {
        assert_eq!(timestamp_seconds(10, 9, 1.0), None);
        assert_eq!(timestamp_seconds(0, 10, 0.0), None);
        assert_eq!(timestamp_seconds(0, 10, -1.0), None);
        assert_eq!(timestamp_seconds(0, 10, f32::NAN), None);
        assert_eq!(timestamp_seconds(0, 10, f32::INFINITY), None);
    }

    #[test]
    fn sources_print_their_report_names() {
        assert_eq!(PassTimeSource::GpuTimestamps.to_string(), "gpu-timestamps");
        assert_eq!(PassTimeSource::Wall.as_str(), "wall");
    }
}

//! [`Gpu`]: the wgpu device and queue every stage is created from, with the helpers they share
//! (buffers, bind groups, dispatch grids, waiting and reading back, the error sink). The
//! bottom of the crate's module graph above `error`: it knows no stage and no context.

use std::sync::mpsc;
use std::sync::{Arc, Mutex};

use bytemuck::Pod;

use crate::error::GpuError;

/// Invocations per workgroup of every kernel (the `@workgroup_size` in the shaders): 256 is a
/// multiple of every vendor's SIMD width and within WebGPU's default limit.
pub(crate) const WORKGROUP_SIZE: u32 = 256;

/// Source of the per-device ids that tie a [`crate::GpuDecoder`] to its context.
static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// One opened adapter: device, queue, limits and the sink of wgpu's uncaptured errors.
/// Cloning shares the device (wgpu's handles are reference-counted).
#[derive(Clone)]
pub(crate) struct Gpu {
    /// Unique per opened device (a decoder's buffers belong to one device).
    pub(crate) id: u64,
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    pub(crate) info: wgpu::AdapterInfo,
    pub(crate) limits: wgpu::Limits,
    pub(crate) errors: Arc<Mutex<Vec<String>>>,
}

impl Gpu {
    /// Opens the first Vulkan adapter (a real GPU is preferred over a software one such as
    /// lavapipe). Honours `WGPU_BACKEND` / `VK_DRIVER_FILES`.
    pub(crate) fn open() -> Result<Self, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        // Only the Vulkan backend is compiled in; asking for others would find nothing.
        desc.backends &= wgpu::Backends::VULKAN;
        if desc.backends.is_empty() {
            desc.backends = wgpu::Backends::VULKAN;
        }
        let backends = "Vulkan".to_string();
        // Listing the adapters makes libwayland print a line on headless machines.
        let adapter = crate::quiet::without_wayland_noise(|| {
            let instance = wgpu::Instance::new(desc);
            pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: None,
                apply_limit_buckets: false,
            }))
        })
        .map_err(|_| GpuError::NoAdapter { backends })?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("kfuse fusion"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::RequestDevice {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;

        // Validation and out-of-memory errors would panic in wgpu's default handler; collect
        // them instead and turn them into GpuError::Device after the frame.
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&errors);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        let id = NEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Ok(Self { id, device, queue, info, limits, errors })
    }

    pub(crate) fn device_error(&self, during: &'static str, message: String) -> GpuError {
        GpuError::Device { adapter: self.info.name.clone(), during, message }
    }

    /// The errors wgpu reported since the last call, as one [`GpuError::Device`].
    pub(crate) fn check_errors(&self, during: &'static str) -> Result<(), GpuError> {
        let mut errors = self
            .errors
            .lock()
            .map_err(|_| self.device_error(during, "error handler poisoned".into()))?;
        if errors.is_empty() {
            return Ok(());
        }
        let message = errors.join("; ");
        errors.clear();
        Err(self.device_error(during, message))
    }

    /// A buffer of `bytes` (rounded up to whole words, at least 16).
    pub(crate) fn buffer(
        &self,
        label: &str,
        bytes: u64,
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.next_multiple_of(4).max(16),
            usage,
            mapped_at_creation: false,
        })
    }

    /// A storage buffer the stages read and write, which can be copied from and written to.
    pub(crate) fn storage(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        use wgpu::BufferUsages as U;
        self.buffer(label, bytes, U::STORAGE | U::COPY_SRC | U::COPY_DST)
    }

    /// A read-back buffer (mappable, a copy destination).
    pub(crate) fn read_back(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.buffer(label, bytes, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST)
    }

    /// The uniform buffer of a stage's parameter struct `T`.
    pub(crate) fn uniform<T: Pod>(&self, label: &str) -> wgpu::Buffer {
        use wgpu::BufferUsages as U;
        self.buffer(label, size_of::<T>() as u64, U::UNIFORM | U::COPY_DST)
    }

    /// A storage buffer holding `data`.
    pub(crate) fn upload<T: Pod>(&self, label: &str, data: &[T]) -> wgpu::Buffer {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let buffer = self.buffer(
            label,
            bytes.len() as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        write_padded(&self.queue, &buffer, bytes);
        buffer
    }

    /// Workgroups along x and y, and invocations per row, for `n` items of [`WORKGROUP_SIZE`].
    pub(crate) fn grid(&self, n: u32) -> Grid {
        self.grid_sized(n, WORKGROUP_SIZE)
    }

    /// [`Gpu::grid`] for a kernel of `workgroup` invocations per group.
    pub(crate) fn grid_sized(&self, n: u32, workgroup: u32) -> Grid {
        let groups = n.div_ceil(workgroup).max(1);
        let max_x = self.limits.max_compute_workgroups_per_dimension.max(1);
        let x = groups.min(max_x);
        let y = groups.div_ceil(x);
        Grid { x, y, stride: x * workgroup }
    }

    /// The bind group of `pipe`'s group 0 with `(binding, buffer)` entries.
    pub(crate) fn bind(
        &self,
        pipe: &wgpu::ComputePipeline,
        entries: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(binding, b)| wgpu::BindGroupEntry {
                binding: *binding,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipe.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Waits for `submission` and for `maps` read-back mappings announced on `mapped`.
    pub(crate) fn wait(
        &self,
        submission: wgpu::SubmissionIndex,
        mapped: &mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
        maps: usize,
    ) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::Wait { submission_index: Some(submission), timeout: None })
            .map_err(|e| self.device_error("waiting for a frame", e.to_string()))?;
        for _ in 0..maps {
            match mapped.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    return Err(self.device_error("mapping the read-back buffers", e.to_string()));
                }
                Err(e) => {
                    return Err(self.device_error("mapping the read-back buffers", e.to_string()));
                }
            }
        }
        self.check_errors("running a frame")
    }

    /// The first `bytes` of a mapped read-back buffer, which is unmapped afterwards.
    pub(crate) fn read_mapped<T: Pod>(
        &self,
        buffer: &wgpu::Buffer,
        bytes: u64,
    ) -> Result<Vec<T>, GpuError> {
        let v = {
            let view = buffer
                .get_mapped_range(0..bytes)
                .map_err(|e| self.device_error("reading back", e.to_string()))?;
            bytemuck::pod_collect_to_vec(&view)
        };
        buffer.unmap();
        Ok(v)
    }
}

/// A dispatch: workgroups along x and y, and invocations per row (the shaders' row stride).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Grid {
    pub(crate) x: u32,
    pub(crate) y: u32,
    pub(crate) stride: u32,
}

/// Writes `bytes` to the start of `buffer`; wgpu copies whole 4-byte words, so a tail of 1-3
/// bytes (an RGB image with an odd pixel count) is padded with zeros.
pub(crate) fn write_padded(queue: &wgpu::Queue, buffer: &wgpu::Buffer, bytes: &[u8]) {
    let aligned = bytes.len() / 4 * 4;
    if aligned > 0 {
        queue.write_buffer(buffer, 0, &bytes[..aligned]);
    }
    if aligned < bytes.len() {
        let mut tail = [0u8; 4];
        tail[..bytes.len() - aligned].copy_from_slice(&bytes[aligned..]);
        queue.write_buffer(buffer, aligned as u64, &tail);
    }
}

//! GPU context: instance, adapter, device and queue, chosen the way the user asked.
//! `WGPU_BACKEND` picks the backends and `WGPU_ADAPTER_NAME` an adapter by name (substring,
//! case-insensitive); tests and headless runs prefer the CPU adapter (lavapipe) so results do
//! not depend on whatever GPU a machine happens to have.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use crate::{Error, Result};

/// How to pick an adapter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AdapterPreference {
    /// The system's default (high performance where there is a choice).
    #[default]
    Default,
    /// A software (CPU) adapter when there is one: deterministic, used by tests.
    Cpu,
}

/// Everything the render core needs from the GPU.
pub struct GpuContext {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// GPU timestamp queries are available (frame times come from the GPU itself).
    pub timestamps: bool,
    /// Timestamps can be written inside render and compute passes too, so that the draws
    /// of one pass are timed apart ([`super::timing::PassSpans::mark`]).
    pub timestamps_inside_passes: bool,
    /// Indirect draws may start past instance 0 (the trees' layer then draws the
    /// billboards in batches from one buffer of draw arguments).
    pub indirect_first_instance: bool,
    /// Set when the device is lost (driver reset, GPU removed): the owner must recreate
    /// the context and everything made from it.
    pub lost: Arc<AtomicBool>,
    /// The last GPU error no error scope caught, kept for the UI instead of aborting.
    pub last_error: Arc<Mutex<Option<String>>>,
}

/// How wgpu sizes its device-memory blocks. A CPU adapter's (lavapipe's) device memory is
/// the process's own memory, and lavapipe touches a block's every page: wgpu's default
/// blocks of 128–256 MiB would make resident memory step by a whole block as targets come
/// and go (a method switch, a resize), and even its small ones (8–64 MiB) left the example
/// forest 116 MB of blocks' unused tails. A CPU adapter gets blocks of 4–8 MiB (anything
/// larger has its own); a GPU keeps the fast default.
pub fn memory_hints(device_type: wgpu::DeviceType) -> wgpu::MemoryHints {
    match device_type {
        wgpu::DeviceType::Cpu => wgpu::MemoryHints::Manual {
            suballocated_device_memory_block_size: 4 << 20..8 << 20,
        },
        _ => wgpu::MemoryHints::Performance,
    }
}

impl GpuContext {
    /// A context for offscreen rendering.
    pub fn headless(pref: AdapterPreference) -> Result<Self> {
        let instance = wgpu::Instance::new(instance_descriptor(None));
        let adapter = pollster::block_on(pick_adapter(&instance, None, pref))?;
        Self::from_adapter(instance, adapter)
    }

    /// A context whose adapter can present to `surface`.
    pub fn for_surface(
        instance: wgpu::Instance,
        surface: &wgpu::Surface<'_>,
        pref: AdapterPreference,
    ) -> Result<Self> {
        let adapter = pollster::block_on(pick_adapter(&instance, Some(surface), pref))?;
        Self::from_adapter(instance, adapter)
    }

    fn from_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter) -> Result<Self> {
        let info = adapter.get_info();
        let timestamps = adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let inside = wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES;
        let timestamps_inside_passes = timestamps && adapter.features().contains(inside);
        let mut required_features = wgpu::Features::empty();
        if timestamps {
            required_features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        if timestamps_inside_passes {
            required_features |= inside;
        }
        // Block-compressed textures (the BTF images in BC7) where the adapter has them;
        // without, the images are decoded on load (`btf::atlas`).
        let first_instance = wgpu::Features::INDIRECT_FIRST_INSTANCE;
        let indirect_first_instance = adapter.features().contains(first_instance);
        if indirect_first_instance {
            required_features |= first_instance;
        }
        let bc = wgpu::Features::TEXTURE_COMPRESSION_BC;
        if adapter.features().contains(bc) {
            required_features |= bc;
        }
        // Ask for what the adapter offers, within the WebGPU defaults' spirit: large
        // textures for supersampled reference frames, storage buffers in vertex shaders.
        let supported = adapter.limits();
        let required_limits = wgpu::Limits {
            max_texture_dimension_2d: supported.max_texture_dimension_2d.min(16384),
            max_texture_array_layers: supported.max_texture_array_layers,
            max_buffer_size: supported.max_buffer_size,
            max_storage_buffer_binding_size: supported.max_storage_buffer_binding_size,
            // The far trees' compute passes bind 10 storage buffers.
            max_storage_buffers_per_shader_stage: supported
                .max_storage_buffers_per_shader_stage
                .min(16),
            ..wgpu::Limits::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("canopy device"),
            required_features,
            required_limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: memory_hints(info.device_type),
            trace: wgpu::Trace::Off,
        }))
        .map_err(|source| Error::RequestDevice {
            adapter: format!("{} ({:?})", info.name, info.backend),
            source,
        })?;
        let lost = Arc::new(AtomicBool::new(false));
        let lost_flag = lost.clone();
        device.set_device_lost_callback(move |reason, message| {
            log::error!("GPU device lost ({reason:?}): {message}");
            lost_flag.store(true, Ordering::SeqCst);
        });
        let last_error = Arc::new(Mutex::new(None));
        let sink = last_error.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            log::error!("GPU error: {e}");
            if let Ok(mut slot) = sink.lock() {
                *slot = Some(e.to_string());
            }
        }));
        log::info!(
            "GPU: {} ({:?}, {:?}), timestamps: {} (inside passes: {}), BC textures: {}",
            info.name,
            info.backend,
            info.device_type,
            timestamps,
            timestamps_inside_passes,
            required_features.contains(bc)
        );
        Ok(Self {
            instance,
            adapter,
            device,
            queue,
            timestamps,
            timestamps_inside_passes,
            indirect_first_instance,
            lost,
            last_error,
        })
    }

    /// "name (backend)" of the adapter in use, for stats and logs.
    pub fn adapter_name(&self) -> String {
        let info = self.adapter.get_info();
        format!("{} ({:?})", info.name, info.backend)
    }

    /// Bytes of every buffer and texture wgpu holds on the device now (its allocator's
    /// report), or `None` where the backend keeps no report.
    pub fn device_allocated_bytes(&self) -> Option<u64> {
        self.device
            .generate_allocator_report()
            .map(|r| r.total_allocated_bytes)
    }

    /// True once the device has been lost.
    pub fn is_lost(&self) -> bool {
        self.lost.load(Ordering::SeqCst)
    }

    /// Takes the last uncaught GPU error, if any.
    pub fn take_error(&self) -> Option<String> {
        self.last_error.lock().ok().and_then(|mut e| e.take())
    }

    /// Runs `f` and turns any validation or out-of-memory error it raised into an `Error`
    /// instead of letting wgpu's default handler abort the process.
    pub fn checked<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T> {
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let value = f();
        let oom_err = pollster::block_on(oom.pop());
        let val_err = pollster::block_on(validation.pop());
        if let Some(e) = oom_err.or(val_err) {
            return Err(Error::Gpu(format!("{what}: {e}")));
        }
        Ok(value)
    }
}

/// Instance options: `WGPU_BACKEND` when set, else the primary backends (Vulkan, Metal,
/// DX12), so that probing OpenGL does not fill the terminal with EGL errors.
pub fn instance_descriptor(
    display: Option<Box<dyn wgpu::wgt::WgpuHasDisplayHandle>>,
) -> wgpu::InstanceDescriptor {
    let mut desc = match display {
        Some(d) => wgpu::InstanceDescriptor::new_with_display_handle_from_env(d),
        None => wgpu::InstanceDescriptor::new_without_display_handle_from_env(),
    };
    desc.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    desc
}

async fn pick_adapter(
    instance: &wgpu::Instance,
    surface: Option<&wgpu::Surface<'_>>,
    pref: AdapterPreference,
) -> Result<wgpu::Adapter> {
    let backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    let mut adapters = instance.enumerate_adapters(backends).await;
    if let Some(s) = surface {
        adapters.retain(|a| a.is_surface_supported(s));
    }
    let names = || {
        adapters
            .iter()
            .map(|a| format!("{} ({:?})", a.get_info().name, a.get_info().backend))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if let Ok(wanted) = std::env::var("WGPU_ADAPTER_NAME") {
        let wanted_lc = wanted.to_lowercase();
        let found = adapters
            .iter()
            .position(|a| a.get_info().name.to_lowercase().contains(&wanted_lc));
        return match found {
            Some(i) => Ok(adapters.swap_remove(i)),
            None => Err(Error::NoAdapter(format!(
                " matching WGPU_ADAPTER_NAME={wanted:?} (adapters present: {})",
                if adapters.is_empty() {
                    "none".to_string()
                } else {
                    names()
                }
            ))),
        };
    }
    if pref == AdapterPreference::Cpu
        && let Some(i) = adapters
            .iter()
            .position(|a| a.get_info().device_type == wgpu::DeviceType::Cpu)
    {
        return Ok(adapters.swap_remove(i));
    }
    let power_preference =
        wgpu::PowerPreference::from_env().unwrap_or(wgpu::PowerPreference::HighPerformance);
    match instance
        .request_adapter(&wgpu::RequestAdapterOptions {
            power_preference,
            force_fallback_adapter: false,
            compatible_surface: surface,
            apply_limit_buckets: false,
        })
        .await
    {
        Ok(a) => Ok(a),
        Err(e) => {
            if let Some(a) = adapters.into_iter().next() {
                Ok(a)
            } else {
                Err(Error::NoAdapter(format!(" ({e})")))
            }
        }
    }
}

//! Runs grid-gen's generated WGSL kernels through wgpu, headless: picks an adapter, loads
//! a generated shader (reading its `// entry:` header lines), uploads a batch of states,
//! dispatches (several dispatches, each with its own buffers, when a batch exceeds 65,535
//! workgroups or the adapter's buffer limits) and reads the results back.

pub mod bench;
mod header;
mod transpose;

use std::sync::Arc;
use std::time::{Duration, Instant};

pub use grid_gen::back::wgsl::EntryMeta;
pub use grid_gen::back::wgsl::{Precision, Strategy};
pub use header::{HeaderError, ShaderInfo};
use wgpu::util::DeviceExt;

/// What went wrong, with what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no WebGPU adapter found ({0}); on Debian or Ubuntu install Mesa's software Vulkan driver (lavapipe) with `apt-get install mesa-vulkan-drivers libvulkan1`, or a GPU's Vulkan driver"
    )]
    NoAdapter(String),
    #[error("no adapter's name contains `{wanted}` (WGPU_ADAPTER_NAME); available: {available}")]
    NoSuchAdapter { wanted: String, available: String },
    #[error("the adapter `{0}` has no SHADER_F64 feature, so it cannot run f64 kernels; generate with --precision f32")]
    NoF64(String),
    #[error("cannot open a device on `{adapter}`: {reason}")]
    Device { adapter: String, reason: String },
    #[error("not a grid-gen shader: {0}")]
    Header(#[from] HeaderError),
    #[error("the shader has no entry point `{entry}`; it has: {available}")]
    NoEntry { entry: String, available: String },
    #[error("wgpu rejected the shader: {0}")]
    Shader(String),
    #[error("wgpu rejected the `{entry}` pipeline: {reason}")]
    Pipeline { entry: String, reason: String },
    #[error("`{field}` has {found} values; {n} states of {per} entries need {expected}")]
    Length { field: &'static str, found: usize, n: usize, per: usize, expected: usize },
    #[error("`{0}` was empty when the batch was uploaded, so the batch has no room for it; upload the batch with it")]
    NotUploaded(&'static str),
    #[error("a thread panicked while it held this batch; upload it again")]
    Poisoned,
    #[error("the dispatch failed: {0}")]
    Dispatch(String),
}

/// A device on the first adapter (or the one whose name contains `WGPU_ADAPTER_NAME`),
/// with the adapter's own limits and, where the adapter has it, SHADER_F64.
pub struct Gpu {
    device: wgpu::Device,
    queue: wgpu::Queue,
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
    adapter: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    f64: bool,
    /// The adapter has TIMESTAMP_QUERY: [`Gpu::dispatch_timed`] reads the device's clock.
    timestamps: bool,
    /// How long to poll for finished work before blocking on the driver's fence
    /// (`GRID_GEN_WGPU_SPIN_US`, default [`SPIN`]).
    spin: Duration,
    /// The transposes between the host's state-major layout and the kernels'.
    transposer: transpose::Transposer,
}

/// A loaded shader: the module, what its header says, and its cooperative tables on
/// the device.
pub struct Shader {
    module: wgpu::ShaderModule,
    pub info: ShaderInfo,
    /// Bindings 6 (`prog`) and 7 (`konst`).
    tables: [wgpu::Buffer; 2],
}

/// One entry point's compute pipelines: one per stage, dispatched in order.
pub struct Kernel {
    pipelines: Vec<wgpu::ComputePipeline>,
    pub entry: EntryMeta,
    pub precision: Precision,
    pub nv: usize,
    /// Entries of q per state (nv + 1 with a floating base).
    pub nq: usize,
    /// Entries of `u` per state: nv, the actuated joints' count for the step kernels, or
    /// nv plus the forces for the kernels that take them.
    pub nu: usize,
    /// Time wgpu took to build the pipelines (some drivers, lavapipe among them, compile
    /// at the first dispatch instead).
    pub build_time: Duration,
    /// The shader's bindings 6 and 7.
    tables: [wgpu::Buffer; 2],
}

/// A chunk's transposes on the device, with the buffers they fill.
struct Moves {
    /// For each input given at upload: where its part of `stage` is copied, and the
    /// transpose from there into the input, joint-major.
    staged: [Option<(wgpu::Buffer, transpose::Move)>; 3],
    /// The outputs state-major, and the transpose into it from the kernel's `out`.
    out_states: wgpu::Buffer,
    to_states: transpose::Move,
}

struct Chunk {
    /// The batch's first state in this chunk, and how many it holds.
    start: usize,
    states: usize,
    /// `q`, `qd`, `u`, joint-major; [`Gpu::run_on`] copies new states into them.
    inputs: [wgpu::Buffer; 3],
    /// Host-writable copy source for `inputs`, back to back (state-major where the chunk
    /// has `moves`, joint-major otherwise), kept mapped between calls of [`Gpu::run_on`]
    /// so that new states go straight into it with no allocation.
    stage: wgpu::Buffer,
    /// The kernel's outputs, joint-major.
    out: wgpu::Buffer,
    /// Where the layouts are changed on the device (a chunk of [`DEVICE_TRANSPOSES`]
    /// values or more); without them the host transposes and `stage` and `read` hold
    /// joint-major values.
    moves: Option<Moves>,
    /// Mappable copy of the outputs.
    read: wgpu::Buffer,
    group: wgpu::BindGroup,
    groups: u32,
}

/// A batch uploaded for one kernel: dispatch it any number of times, read it back.
pub struct Batch<'k> {
    kernel: &'k Kernel,
    n: usize,
    chunks: Vec<Chunk>,
    /// Host memory the size of the largest chunk's staging or read buffer. Mapped memory
    /// can be uncached: one bulk copy through here, then the transpose in cached memory,
    /// is several times faster than reading or writing words there (measured on an H200
    /// through Vulkan, 2026-11-25).
    /// Words of 8 bytes, so that it can be read as the device's f32 or f64 words.
    host: std::sync::Mutex<Vec<u64>>,
}

fn layout_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    }
}

fn adapter_name(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {})", info.name, info.backend, info.driver)
}

impl Gpu {
    pub fn new() -> Result<Gpu, GpuError> {
        // Release-build flags in every build: wgpu's debug-build default adds DEBUG, with
        // which naga writes a source location into the SPIR-V of every pipeline by
        // counting lines from the top of the WGSL text for each statement, quadratic in the
        // file (a test binary spent minutes per Atlas kernel there; measured 2026-11-24).
        // WGPU_DEBUG=1 and WGPU_VALIDATION=1 still turn them on.
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.flags = wgpu::InstanceFlags::VALIDATION_INDIRECT_CALL;
        let instance = wgpu::Instance::new(desc.with_env());
        let adapter = match std::env::var("WGPU_ADAPTER_NAME") {
            Ok(wanted) if !wanted.is_empty() => {
                let adapters =
                    pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
                let lower = wanted.to_lowercase();
                let names: Vec<String> =
                    adapters.iter().map(|a| adapter_name(&a.get_info())).collect();
                match adapters
                    .into_iter()
                    .find(|a| a.get_info().name.to_lowercase().contains(&lower))
                {
                    Some(a) => a,
                    None if names.is_empty() => {
                        return Err(GpuError::NoAdapter("none enumerated".into()))
                    }
                    None => {
                        return Err(GpuError::NoSuchAdapter { wanted, available: names.join("; ") })
                    }
                }
            }
            _ => pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                ..Default::default()
            }))
            .map_err(|e| GpuError::NoAdapter(e.to_string()))?,
        };
        let info = adapter.get_info();
        let f64 = adapter.features().contains(wgpu::Features::SHADER_F64);
        // WebGPU's default limits, except the buffer sizes, which bound the batch. (With
        // all of lavapipe's own limits, its first dispatch of iiwa's fd_grad took 250 s
        // instead of 9: measured, cause not traced.)
        let best = adapter.limits();
        let limits = wgpu::Limits {
            max_storage_buffer_binding_size: best.max_storage_buffer_binding_size,
            max_buffer_size: best.max_buffer_size,
            ..wgpu::Limits::default()
        };
        let timestamps = adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let mut features = if f64 { wgpu::Features::SHADER_F64 } else { wgpu::Features::empty() };
        if timestamps {
            features |= wgpu::Features::TIMESTAMP_QUERY;
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("grid-gen"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device { adapter: adapter_name(&info), reason: e.to_string() })?;
        // Errors are caught with error scopes; anything else is a bug to report, not a
        // reason to abort the host program.
        device.on_uncaptured_error(Arc::new(|e| {
            eprintln!("grid-gen-wgpu: uncaptured wgpu error: {e}")
        }));
        use wgpu::BufferBindingType::{Storage, Uniform};
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("grid-gen"),
            entries: &[
                layout_entry(0, Uniform),
                layout_entry(1, Storage { read_only: true }),
                layout_entry(2, Storage { read_only: true }),
                layout_entry(3, Storage { read_only: true }),
                layout_entry(4, Storage { read_only: false }),
                layout_entry(5, Storage { read_only: false }),
                layout_entry(6, Storage { read_only: true }),
                layout_entry(7, Storage { read_only: true }),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("grid-gen"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let spin = std::env::var("GRID_GEN_WGPU_SPIN_US")
            .ok()
            .and_then(|v| v.trim().parse().ok())
            .map_or(SPIN, Duration::from_micros);
        let transposer = transpose::Transposer::new(&device)
            .map_err(|reason| GpuError::Pipeline { entry: "transpose".into(), reason })?;
        Ok(Gpu {
            transposer,
            device,
            queue,
            layout,
            pipeline_layout,
            adapter: info,
            limits,
            f64,
            timestamps,
            spin,
        })
    }

    /// The adapter's name, backend and driver.
    pub fn adapter(&self) -> String {
        adapter_name(&self.adapter)
    }

    pub fn has_f64(&self) -> bool {
        self.f64
    }

    /// Parses the header and creates the shader module (naga parses and validates it).
    pub fn load(&self, source: &str) -> Result<Shader, GpuError> {
        let info = ShaderInfo::parse(source)?;
        if info.precision == Precision::F64 && !self.f64 {
            return Err(GpuError::NoF64(self.adapter()));
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("grid-gen"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader(e.to_string()));
        }
        // Storage bindings cannot be empty: one zero word where a shader has no tables.
        let words: Vec<u8> = if info.prog.is_empty() {
            vec![0; 4]
        } else {
            info.prog.iter().flat_map(|w| w.to_le_bytes()).collect()
        };
        let values = if info.konst.is_empty() { vec![0.0] } else { info.konst.clone() };
        let init = |data: &[u8]| {
            self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("grid-gen tables"),
                contents: data,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let tables = [init(&words), init(&to_bytes(values, info.precision))];
        Ok(Shader { module, info, tables })
    }

    /// Builds the compute pipeline of one entry point.
    pub fn kernel(&self, shader: &Shader, entry: &str) -> Result<Kernel, GpuError> {
        let info = shader.info.entry(entry).ok_or_else(|| GpuError::NoEntry {
            entry: entry.to_string(),
            available: shader
                .info
                .entries
                .iter()
                .map(|e| e.entry.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        })?;
        let start = Instant::now();
        let mut pipelines = Vec::new();
        for k in 0..info.stages {
            let name = grid_gen::back::wgsl::stage_entry(entry, k, info.stages);
            let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
            let pipeline = self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(&name),
                layout: Some(&self.pipeline_layout),
                module: &shader.module,
                entry_point: Some(&name),
                compilation_options: Default::default(),
                cache: None,
            });
            if let Some(e) = pollster::block_on(scope.pop()) {
                return Err(GpuError::Pipeline { entry: name, reason: e.to_string() });
            }
            pipelines.push(pipeline);
        }
        Ok(Kernel {
            pipelines,
            entry: info.clone(),
            precision: shader.info.precision,
            nv: shader.info.nv,
            nq: shader.info.nq,
            nu: grid_gen::ir::KernelKind::parse(&info.kernel).map_or(shader.info.nv, |k| {
                let i = &shader.info;
                k.u_len(&grid_gen::ir::UPacking {
                    nv: i.nv,
                    nq: i.nq,
                    nu: i.nu,
                    forces: i.forces,
                    lambda: i.lambda,
                    active: i.active,
                    baumgarte: i.baumgarte,
                    contact_ref: i.contact_ref,
                    runtime_dt: i.runtime_dt,
                })
            }),
            build_time: start.elapsed(),
            tables: shader.tables.clone(),
        })
    }

    /// States per dispatch: at most 65,535 workgroups, and every buffer within the
    /// adapter's binding and buffer limits.
    fn chunk_states(&self, k: &Kernel) -> usize {
        let e = &k.entry;
        let word = k.precision.bytes() as u64;
        let widest = (e.outputs.max(e.scratch).max(k.nq).max(1)) as u64 * word;
        let bytes = self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size);
        let by_memory = (bytes / widest).max(1) as usize;
        let by_groups = self.limits.max_compute_workgroups_per_dimension as usize
            * e.states_per_workgroup as usize;
        by_memory.min(by_groups).max(1)
    }

    /// Uploads N states for `kernel`. Inputs are state-major (`q[s * nq + j]`, the others
    /// `[s * nv + j]`; nq = nv but with a floating base); `u` is q̈
    /// for rnea, rnea_grad and frame_acceleration, τ for fd and fd_grad, followed in each
    /// state by `fext` and λ when the shader's robot declares forces, and for the step
    /// kernels of a run-time step by its `dt` (`Kernel::nu` entries per state in all); a kernel that does not read `qd` or `u` ignores it (it may be
    /// empty). N = 0 is a no-op batch.
    pub fn upload<'k>(
        &self,
        kernel: &'k Kernel,
        q: &[f64],
        qd: &[f64],
        u: &[f64],
    ) -> Result<Batch<'k>, GpuError> {
        let n = q.len().checked_div(kernel.nq).unwrap_or(0);
        check_lengths(kernel, n, q, qd, u)?;
        let per = self.chunk_states(kernel);
        let mut chunks = Vec::new();
        let mut start = 0;
        while start < n {
            let m = per.min(n - start);
            chunks.push(self.chunk(kernel, start, m, [q, qd, u])?);
            start += m;
        }
        let largest = chunks.iter().map(|c| c.read.size().max(c.stage.size())).max().unwrap_or(0);
        let host = std::sync::Mutex::new(vec![0; largest.div_ceil(8) as usize]);
        Ok(Batch { kernel, n, chunks, host })
    }

    fn chunk(
        &self,
        k: &Kernel,
        start: usize,
        m: usize,
        inputs: [&[f64]; 3],
    ) -> Result<Chunk, GpuError> {
        let d = &self.device;
        let bytes = |x: Vec<f64>| to_bytes(x, k.precision);
        // An input the kernel does not read is one word: a binding cannot be empty.
        let soa = |x: &[f64], per: usize| -> Vec<f64> {
            if x.is_empty() {
                vec![0.0]
            } else {
                joint_major(x, per, start, m)
            }
        };
        let init = |data: Vec<u8>, usage| {
            d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: None,
                contents: &data,
                usage,
            })
        };
        let scope = d.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let mut params = vec![0u8; 16];
        params[..4].copy_from_slice(&(m as u32).to_le_bytes());
        let params = init(params, wgpu::BufferUsages::UNIFORM);
        let given = inputs;
        let [q, qd, u] = inputs;
        let inputs = [(q, k.nq), (qd, k.nv), (u, k.nu)].map(|(x, per)| {
            init(bytes(soa(x, per)), wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST)
        });
        let word = k.precision.bytes() as u64;
        let out_bytes = (k.entry.outputs * m).max(1) as u64 * word;
        // NaN everywhere, so a value the kernel fails to write cannot pass for a result.
        let out = init(
            bytes(vec![f64::NAN; (k.entry.outputs * m).max(1)]),
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let stage = d.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: inputs.iter().map(|b| b.size()).sum(),
            usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: true,
        });
        let scratch = d.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: (k.entry.scratch * m).max(1) as u64 * word,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let read = d.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: out_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let entries: Vec<wgpu::BindGroupEntry> = [
            &params,
            &inputs[0],
            &inputs[1],
            &inputs[2],
            &out,
            &scratch,
            &k.tables[0],
            &k.tables[1],
        ]
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
        .collect();
        let group = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.layout,
            entries: &entries,
        });
        let values = m * (k.nq + k.nv + k.nu + k.entry.outputs);
        let moves = (values >= DEVICE_TRANSPOSES).then(|| self.moves(k, m, given, &inputs, &out));
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Dispatch(format!(
                "cannot allocate the buffers of {m} states: {e}"
            )));
        }
        let groups = m.div_ceil(k.entry.states_per_workgroup as usize) as u32;
        Ok(Chunk { start, states: m, inputs, stage, out, moves, read, group, groups })
    }

    /// The device-side transposes of a chunk of `m` states and the buffers they fill.
    fn moves(
        &self,
        k: &Kernel,
        m: usize,
        given: [&[f64]; 3],
        inputs: &[wgpu::Buffer; 3],
        out: &wgpu::Buffer,
    ) -> Moves {
        let d = &self.device;
        let words = k.precision.bytes() / 4;
        let max_groups = self.limits.max_compute_workgroups_per_dimension;
        let out_states = d.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: out.size(),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let t = &self.transposer;
        let to_states = t.bind(d, out, &out_states, (k.entry.outputs, m), words, max_groups);
        let pers = [k.nq, k.nv, k.nu];
        let staged: [Option<(wgpu::Buffer, transpose::Move)>; 3] = std::array::from_fn(|j| {
            (!given[j].is_empty()).then(|| {
                let b = d.create_buffer(&wgpu::BufferDescriptor {
                    label: None,
                    size: inputs[j].size(),
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                let to_joints = t.bind(d, &b, &inputs[j], (m, pers[j]), words, max_groups);
                (b, to_joints)
            })
        });
        Moves { staged, out_states, to_states }
    }

    /// Runs the uploaded batch and waits for it to finish.
    pub fn dispatch(&self, batch: &Batch) -> Result<(), GpuError> {
        self.dispatch_with(batch, None, Io::None)
    }

    /// [`Gpu::dispatch`], and the time the device spent in the compute pass by its own
    /// clock (timestamps written at the start and end of the pass), which leaves out the
    /// host's submission and wait; `None` where the adapter has no TIMESTAMP_QUERY.
    pub fn dispatch_timed(&self, batch: &Batch) -> Result<Option<Duration>, GpuError> {
        if !self.timestamps || batch.chunks.is_empty() {
            self.dispatch(batch)?;
            return Ok(None);
        }
        let d = &self.device;
        let set = d.create_query_set(&wgpu::QuerySetDescriptor {
            label: None,
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let buffer = |usage| {
            d.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: 16,
                usage,
                mapped_at_creation: false,
            })
        };
        let resolve = buffer(wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC);
        let read = buffer(wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST);
        self.dispatch_with(batch, Some((&set, &resolve, &read)), Io::None)?;
        let maps = Maps::default();
        maps.map(&read, wgpu::MapMode::Read);
        self.wait(&maps)?;
        let ticks = {
            let view =
                read.slice(..).get_mapped_range().map_err(|e| GpuError::Dispatch(e.to_string()))?;
            let word =
                |k: usize| u64::from_le_bytes(view[8 * k..8 * k + 8].try_into().unwrap_or([0; 8]));
            word(1).saturating_sub(word(0))
        };
        read.unmap();
        Ok(Some(Duration::from_nanos(
            (ticks as f64 * self.queue.get_timestamp_period() as f64) as u64,
        )))
    }

    /// Encodes every stage over every chunk in one compute pass, with timestamps at its
    /// ends resolved into the given buffers when asked; with `io`, first the copies of new
    /// inputs from the staging buffers and last those of the outputs into the mappable
    /// buffers, which are mapped again (the staging buffers for writing) once the work is
    /// done. Submits once and waits.
    fn dispatch_with(
        &self,
        batch: &Batch,
        timestamps: Option<(&wgpu::QuerySet, &wgpu::Buffer, &wgpu::Buffer)>,
        io: Io,
    ) -> Result<(), GpuError> {
        if batch.chunks.is_empty() {
            return Ok(());
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        if io == Io::StagedInputs {
            for c in &batch.chunks {
                let mut offset = 0;
                for (j, input) in c.inputs.iter().enumerate() {
                    match &c.moves {
                        Some(moves) => {
                            if let Some((b, _)) = &moves.staged[j] {
                                encoder.copy_buffer_to_buffer(&c.stage, offset, b, 0, b.size());
                            }
                        }
                        None => {
                            encoder.copy_buffer_to_buffer(&c.stage, offset, input, 0, input.size())
                        }
                    }
                    offset += input.size();
                }
            }
        }
        {
            let timestamp_writes = timestamps.map(|(set, _, _)| wgpu::ComputePassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(0),
                end_of_pass_write_index: Some(1),
            });
            // wgpu orders dispatches that share a written buffer, so each stage sees the
            // scratch values of the one before.
            let mut pass = encoder
                .begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes });
            if io == Io::StagedInputs {
                for moves in batch.chunks.iter().filter_map(|c| c.moves.as_ref()) {
                    for (_, to_joints) in moves.staged.iter().flatten() {
                        self.transposer.encode(&mut pass, to_joints);
                    }
                }
            }
            for pipeline in &batch.kernel.pipelines {
                pass.set_pipeline(pipeline);
                for c in &batch.chunks {
                    pass.set_bind_group(0, &c.group, &[]);
                    pass.dispatch_workgroups(c.groups, 1, 1);
                }
            }
            if io != Io::None {
                self.encode_to_states(&mut pass, batch);
            }
        }
        if let Some((set, resolve, read)) = timestamps {
            encoder.resolve_query_set(set, 0..2, resolve, 0);
            encoder.copy_buffer_to_buffer(resolve, 0, read, 0, 16);
        }
        if io != Io::None {
            Self::encode_read_copies(&mut encoder, batch);
        }
        self.queue.submit([encoder.finish()]);
        let maps = Maps::default();
        if io != Io::None {
            for c in &batch.chunks {
                maps.map(&c.read, wgpu::MapMode::Read);
                if io == Io::StagedInputs {
                    maps.map(&c.stage, wgpu::MapMode::Write);
                }
            }
        }
        self.wait(&maps)?;
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Dispatch(e.to_string()));
        }
        Ok(())
    }

    /// Waits until the queue is empty and every mapping in `maps` is done: polling in a
    /// loop (one core busy) for up to `self.spin`, then blocking. A blocking wait sleeps on
    /// the driver's fence, and waking costs tens of microseconds, more than a small
    /// batch's work.
    fn wait(&self, maps: &Maps) -> Result<(), GpuError> {
        let start = Instant::now();
        let poll = |kind| self.device.poll(kind).map_err(|e| GpuError::Dispatch(e.to_string()));
        loop {
            let empty = poll(wgpu::PollType::Poll)?.is_queue_empty();
            if empty && maps.done() {
                return maps.result();
            }
            if start.elapsed() >= self.spin {
                poll(wgpu::PollType::wait_indefinitely())?;
                if !maps.done() {
                    return Err(GpuError::Dispatch("a buffer mapping never completed".into()));
                }
                return maps.result();
            }
            std::hint::spin_loop();
        }
    }

    /// The transposes of every chunk's outputs into state-major order.
    fn encode_to_states(&self, pass: &mut wgpu::ComputePass, batch: &Batch) {
        for moves in batch.chunks.iter().filter_map(|c| c.moves.as_ref()) {
            self.transposer.encode(pass, &moves.to_states);
        }
    }

    /// The copies of every chunk's outputs into its mappable buffer.
    fn encode_read_copies(encoder: &mut wgpu::CommandEncoder, batch: &Batch) {
        for c in &batch.chunks {
            let from = c.moves.as_ref().map_or(&c.out, |m| &m.out_states);
            encoder.copy_buffer_to_buffer(from, 0, &c.read, 0, c.read.size());
        }
    }

    /// Copies the results back: `out[s * outputs + k]`, value k of state s, in f64.
    pub fn read(&self, batch: &Batch) -> Result<Vec<f64>, GpuError> {
        let mut encoder = self.device.create_command_encoder(&Default::default());
        if batch.chunks.iter().any(|c| c.moves.is_some()) {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            self.encode_to_states(&mut pass, batch);
        }
        Self::encode_read_copies(&mut encoder, batch);
        self.queue.submit([encoder.finish()]);
        let maps = Maps::default();
        for c in &batch.chunks {
            maps.map(&c.read, wgpu::MapMode::Read);
        }
        self.wait(&maps)?;
        let mut out = vec![0.0; batch.n * batch.kernel.entry.outputs];
        Self::mapped_results(batch, &mut out)?;
        Ok(out)
    }

    /// The outputs in the batch's mapped read buffers (state-major, transposed on the
    /// device) into `out` in f64, unmapping them.
    fn mapped_results(batch: &Batch, out: &mut [f64]) -> Result<(), GpuError> {
        Self::mapped_results_timed(batch, out, &mut Phases::default())
    }

    /// [`Gpu::mapped_results`], adding the time of the bulk copies out of mapped memory
    /// and of the conversions to f64 to `phases`.
    fn mapped_results_timed(
        batch: &Batch,
        out: &mut [f64],
        phases: &mut Phases,
    ) -> Result<(), GpuError> {
        let k = batch.kernel;
        let outputs = k.entry.outputs;
        let mut host = batch.host.lock().map_err(|_| GpuError::Poisoned)?;
        for c in &batch.chunks {
            let t = Instant::now();
            let bytes = c.read.size() as usize;
            {
                let view = c
                    .read
                    .slice(..)
                    .get_mapped_range()
                    .map_err(|e| GpuError::Dispatch(e.to_string()))?;
                bytemuck::cast_slice_mut::<u64, u8>(&mut host[..])[..bytes].copy_from_slice(&view);
            }
            c.read.unmap();
            let t2 = Instant::now();
            phases.copy_out += t2 - t;
            let dst = &mut out[c.start * outputs..(c.start + c.states) * outputs];
            let joint_major = c.moves.is_none();
            match k.precision {
                Precision::F32 => {
                    let words: &[u32] = bytemuck::cast_slice(&host[..]);
                    unstage(words, dst, outputs, joint_major, |w| {
                        f32::from_bits(u32::from_le(w)) as f64
                    })
                }
                Precision::F64 => unstage(&host[..], dst, outputs, joint_major, |w| {
                    f64::from_bits(u64::from_le(w))
                }),
            }
            phases.convert_out += t2.elapsed();
        }
        Ok(())
    }

    /// Upload, dispatch and read back in one call, allocating the batch's buffers: for a
    /// one-off batch. A loop that runs the same kernel on new states of the same count
    /// should upload once and call [`Gpu::run_on`].
    pub fn run(
        &self,
        kernel: &Kernel,
        q: &[f64],
        qd: &[f64],
        u: &[f64],
    ) -> Result<Vec<f64>, GpuError> {
        let batch = self.upload(kernel, q, qd, u)?;
        self.dispatch_with(&batch, None, Io::ReadBack)?;
        let mut out = vec![0.0; batch.n * kernel.entry.outputs];
        Self::mapped_results(&batch, &mut out)?;
        Ok(out)
    }

    /// Runs an uploaded batch on new states (the batch's count, state-major as for
    /// [`Gpu::upload`]) and writes the results into `out` (`out[s * outputs + k]`, value k
    /// of state s): the states go into the batch's mapped staging buffer, then one
    /// submission copies them in, dispatches and copies the outputs out, with the same
    /// buffers and bind groups and no allocation. This is the call an MPC loop makes at
    /// each iteration.
    pub fn run_on(
        &self,
        batch: &Batch,
        q: &[f64],
        qd: &[f64],
        u: &[f64],
        out: &mut [f64],
    ) -> Result<(), GpuError> {
        self.run_on_timed(batch, q, qd, u, out).map(|_| ())
    }

    /// [`Gpu::run_on`], and how long each of its phases took, for `grid-gen bench`.
    fn run_on_timed(
        &self,
        batch: &Batch,
        q: &[f64],
        qd: &[f64],
        u: &[f64],
        out: &mut [f64],
    ) -> Result<Phases, GpuError> {
        let start = Instant::now();
        let mut phases = Phases::default();
        let k = batch.kernel;
        check_lengths(k, batch.n, q, qd, u)?;
        let outputs = k.entry.outputs;
        if out.len() != batch.n * outputs {
            return Err(GpuError::Length {
                field: "out",
                found: out.len(),
                n: batch.n,
                per: outputs,
                expected: batch.n * outputs,
            });
        }
        let fields = [("q", q, k.nq), ("qd", qd, k.nv), ("u", u, k.nu)];
        for c in &batch.chunks {
            let range = || c.stage.slice(..).get_mapped_range_mut();
            let mut view = match range() {
                Ok(view) => view,
                // A failed call left it unmapped: map it again before writing.
                Err(_) => {
                    let maps = Maps::default();
                    maps.map(&c.stage, wgpu::MapMode::Write);
                    self.wait(&maps)?;
                    range().map_err(|e| GpuError::Dispatch(e.to_string()))?
                }
            };
            let mut offset = 0;
            for (input, (field, x, per)) in c.inputs.iter().zip(fields) {
                let size = input.size() as usize;
                // An input the kernel does not read may be left empty.
                if !x.is_empty() {
                    let bytes = per * c.states * k.precision.bytes();
                    if bytes > size {
                        drop(view);
                        c.stage.unmap();
                        return Err(GpuError::NotUploaded(field));
                    }
                    let mut host = batch.host.lock().map_err(|_| GpuError::Poisoned)?;
                    let x = &x[c.start * per..(c.start + c.states) * per];
                    // State-major as given where the device transposes (`Moves::staged`).
                    let joint_major = c.moves.is_none();
                    match k.precision {
                        Precision::F32 => {
                            let words = bytemuck::cast_slice_mut::<u64, u32>(&mut host[..]);
                            stage(x, words, per, joint_major, |v| (v as f32).to_bits().to_le())
                        }
                        Precision::F64 => {
                            stage(x, &mut host[..], per, joint_major, |v| v.to_bits().to_le())
                        }
                    }
                    let staged = &bytemuck::cast_slice::<u64, u8>(&host[..])[..bytes];
                    view.slice(offset..offset + bytes).copy_from_slice(staged);
                }
                offset += size;
            }
            drop(view);
            c.stage.unmap();
        }
        let staged = Instant::now();
        phases.stage_in = staged - start;
        self.dispatch_with(batch, None, Io::StagedInputs)?;
        phases.submit_wait = staged.elapsed();
        Self::mapped_results_timed(batch, out, &mut phases)?;
        Ok(phases)
    }
}

/// States per block of the host's transposes between state-major arrays and the device's
/// joint-major buffers: 16 f32 words are one cache line of each joint-major row, and 16
/// states of up to a few hundred f64 values stay in the L1 cache (16 was 30 % faster than
/// 64 for iiwa's `fd_grad`, 105 outputs, on an EPYC, 2026-11-25).
const BLOCK: usize = 16;

/// The state-major `x` (`per` values a state) into `words`, each converted by `word`: in
/// the same order, or joint-major (`words[j * m + i]`, value j of state i, for m states)
/// in blocks of [`BLOCK`] states. The precision is matched once, outside the loops, so
/// that the in-order pass vectorises.
fn stage<W>(x: &[f64], words: &mut [W], per: usize, joint_major: bool, word: impl Fn(f64) -> W) {
    if !joint_major {
        for (w, &v) in words.iter_mut().zip(x) {
            *w = word(v);
        }
        return;
    }
    let m = x.len() / per.max(1);
    for block in (0..m).step_by(BLOCK) {
        for j in 0..per {
            for i in block..(block + BLOCK).min(m) {
                words[j * m + i] = word(x[i * per + j]);
            }
        }
    }
}

/// The way back: `words` (in order, or joint-major as [`stage`] writes them) into the
/// state-major `out` (`per` values a state), each converted by `value`.
fn unstage<W: Copy>(
    words: &[W],
    out: &mut [f64],
    per: usize,
    joint_major: bool,
    value: impl Fn(W) -> f64,
) {
    if !joint_major {
        for (o, &w) in out.iter_mut().zip(words) {
            *o = value(w);
        }
        return;
    }
    let m = out.len() / per.max(1);
    for block in (0..m).step_by(BLOCK) {
        for j in 0..per {
            for i in block..(block + BLOCK).min(m) {
                out[i * per + j] = value(words[j * m + i]);
            }
        }
    }
}

/// Values (inputs and outputs, over a chunk's states) from which the device, not the host,
/// transposes between the layouts. The host's transposes cost about 0.8 ns a value, the
/// device's four more dispatches about 10 µs whatever the size (an H200 through Vulkan,
/// iiwa and HyQ `fd_grad`, 2026-11-26): the device is faster from about 12,000 values
/// (iiwa's `fd_grad`, 126 values a state: host faster at 32 states, device at 256).
pub const DEVICE_TRANSPOSES: usize = 16_384;

/// How long [`Gpu`] polls for finished work before it blocks on the driver's fence, unless
/// `GRID_GEN_WGPU_SPIN_US` says otherwise (0: block at once).
pub const SPIN: Duration = Duration::from_millis(2);

/// Where the time of one [`Gpu::run_on`] goes: writing the states into the mapped staging
/// buffer (converted to the device's precision), the submission and the wait for it
/// (copies in, transposes, dispatches, copies out, mappings), the bulk copies out of mapped
/// memory, and the conversion to f64.
#[derive(Clone, Copy, Debug, Default)]
pub struct Phases {
    pub stage_in: Duration,
    pub submit_wait: Duration,
    pub copy_out: Duration,
    pub convert_out: Duration,
}

/// What a submission moves besides the dispatches.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Io {
    None,
    /// Copies the outputs into the mappable buffers and maps them.
    ReadBack,
    /// Also copies the inputs in from the staging buffers first and maps those again.
    StagedInputs,
}

/// Buffer mappings requested after a submission: how many there are, how many finished,
/// and the first error.
#[derive(Default)]
struct Maps {
    asked: std::cell::Cell<usize>,
    done: Arc<std::sync::atomic::AtomicUsize>,
    failed: Arc<std::sync::Mutex<Option<String>>>,
}

impl Maps {
    fn map(&self, buffer: &wgpu::Buffer, mode: wgpu::MapMode) {
        self.asked.set(self.asked.get() + 1);
        let (done, failed) = (self.done.clone(), self.failed.clone());
        buffer.slice(..).map_async(mode, move |r| {
            if let (Err(e), Ok(mut f)) = (r, failed.lock()) {
                f.get_or_insert(e.to_string());
            }
            done.fetch_add(1, std::sync::atomic::Ordering::AcqRel);
        });
    }

    fn done(&self) -> bool {
        self.done.load(std::sync::atomic::Ordering::Acquire) >= self.asked.get()
    }

    fn result(&self) -> Result<(), GpuError> {
        match self.failed.lock().ok().and_then(|f| f.clone()) {
            Some(e) => Err(GpuError::Dispatch(format!("cannot map a buffer: {e}"))),
            None => Ok(()),
        }
    }
}

/// States `start..start + m` of the state-major `x` (`per` entries each), joint-major as
/// the kernels read them: `x[j * m + i]`.
fn joint_major(x: &[f64], per: usize, start: usize, m: usize) -> Vec<f64> {
    (0..per).flat_map(|j| (0..m).map(move |i| x[(start + i) * per + j])).collect()
}

/// Checks that `q`, `qd` and `u` hold `n` states for `kernel`: q has nq entries per state,
/// `qd` nv and `u` the kernel's nu (q̈ for rnea, rnea_grad and frame_acceleration, τ for
/// fd and fd_grad, followed in each state by `fext` and λ when the shader's robot declares
/// forces); a kernel that does not read `qd` or `u` accepts it empty.
fn check_lengths(
    kernel: &Kernel,
    n: usize,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
) -> Result<(), GpuError> {
    // What the kernel reads, by its kind's inputs (an unknown name reads everything).
    use grid_gen::ir::{Input, KernelKind};
    let kind = KernelKind::parse(&kernel.entry.kernel);
    let takes = |i: Input| kind.is_none_or(|k| k.inputs().contains(&i));
    let uses_qd = takes(Input::Qd) || takes(Input::V);
    let uses_u = takes(Input::Qdd) || takes(Input::Tau) || takes(Input::TauActuated);
    let uses_u = uses_u || takes(Input::Q1);
    let check = |field: &'static str, x: &[f64], needed: bool, per: usize| {
        if (needed || !x.is_empty()) && x.len() != n * per {
            return Err(GpuError::Length { field, found: x.len(), n, per, expected: n * per });
        }
        Ok(())
    };
    check("q", q, true, kernel.nq)?;
    check("qd", qd, uses_qd, kernel.nv)?;
    check("u", u, uses_u, kernel.nu)
}

/// Values as the device's words in `precision`.
fn to_bytes(x: Vec<f64>, precision: Precision) -> Vec<u8> {
    match precision {
        Precision::F32 => x.into_iter().flat_map(|v| (v as f32).to_le_bytes()).collect(),
        Precision::F64 => x.into_iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

impl Batch<'_> {
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Dispatches (one per 65,535 workgroups or per buffer limit) the batch takes.
    pub fn dispatches(&self) -> usize {
        self.chunks.len()
    }
}

/// Why `eval --backend wgsl` failed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Generate(#[from] grid_gen::generate::GenerateError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Eval(#[from] grid_gen::eval::BackendEvalError<GpuError>),
}

/// `grid-gen eval --backend wgsl`: generates the WGSL of `model` with `options` and the
/// gradient formulation and solve of `routes` (whose kernel list is not read), runs every
/// kernel under `strategy` on `gpu`, and returns exactly the JSON of
/// [`grid_gen::eval::evaluate`] (same keys, model order).
pub fn evaluate(
    gpu: &Gpu,
    model: &grid_gen::Model,
    file: &grid_gen::eval::StatesFile,
    gravity: [f64; 3],
    routes: &grid_gen::ir::LowerOptions,
    options: &grid_gen::back::wgsl::WgslOptions,
    strategy: Strategy,
) -> Result<grid_gen::eval::EvalOutput, EvalError> {
    use grid_gen::ir::KernelKind;
    grid_gen::eval::check_states(model, file).map_err(grid_gen::eval::BackendEvalError::States)?;
    let mut kernels = vec![
        KernelKind::Rnea,
        KernelKind::RneaGrad,
        KernelKind::MassMatrix,
        KernelKind::Minv,
        KernelKind::FdGrad,
    ];
    kernels.extend(KernelKind::ALL.into_iter().filter(|k| k.is_frame() || k.is_lie()));
    let lower = grid_gen::ir::LowerOptions { kernels, ..routes.clone() };
    let module = grid_gen::ir::lower(model, gravity, &lower)
        .map_err(grid_gen::generate::GenerateError::from)?;
    let wgsl = grid_gen::back::wgsl::WgslOptions { strategies: vec![strategy], ..options.clone() };
    let source = grid_gen::back::wgsl::emit(&module, &wgsl)
        .map_err(grid_gen::generate::GenerateError::from)?;
    let shader = gpu.load(&source.contents)?;
    Ok(grid_gen::eval::evaluate_with(model, file, |kind, q, qd, u| {
        let kernel = gpu.kernel(&shader, &strategy.entry(kind.name()))?;
        gpu.run(&kernel, q, qd, u)
    })?)
}

/// The WGSL kernels of `module` under `strategy` on `gpu`, as a backend that
/// [`grid_gen::accuracy::measure`] runs next to the number formats (`accuracy --backend
/// wgsl`), labelled with the precision, strategy and adapter.
pub fn accuracy_backend<'a>(
    gpu: &'a Gpu,
    module: &grid_gen::ir::Module,
    options: &grid_gen::back::wgsl::WgslOptions,
    strategy: Strategy,
) -> Result<grid_gen::accuracy::Backend<'a>, EvalError> {
    let wgsl = grid_gen::back::wgsl::WgslOptions { strategies: vec![strategy], ..options.clone() };
    let source = grid_gen::back::wgsl::emit(module, &wgsl)
        .map_err(grid_gen::generate::GenerateError::from)?;
    let shader = gpu.load(&source.contents)?;
    let adapter = gpu.adapter();
    let short = adapter.split(" (").next().unwrap_or(&adapter);
    let label = format!("wgsl {} {} on {short}", options.precision.name(), strategy.name());
    Ok(grid_gen::accuracy::Backend {
        label,
        run: Box::new(move |kind, q, qd, u| {
            let kernel =
                gpu.kernel(&shader, &strategy.entry(kind.name())).map_err(|e| e.to_string())?;
            gpu.run(&kernel, q, qd, u).map_err(|e| e.to_string())
        }),
    })
}

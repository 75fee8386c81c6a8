//! The device-side transposes between the host's state-major arrays and the kernels'
//! joint-major buffers, so that the host only converts contiguous values.
//!
//! The kernels read and write joint-major (`x[j * m + i]`, value j of state i) so that
//! neighbouring invocations touch neighbouring words; callers hold states one after the
//! other. Transposing on the host cost about 0.8 ns per value on an H200's host (iiwa
//! `fd_grad`, N = 1024: 86 µs of a 241 µs round trip, 2026-11-26); on the device the same
//! move is one small dispatch in the pass that runs the kernel.

use wgpu::util::DeviceExt;

/// Invocations per workgroup of the transpose.
const WORKGROUP: u32 = 64;

/// `dst = srcᵀ`: `src` holds `rows × cols` elements of `words` 32-bit words each, row by
/// row; `dst` gets element (r, c) at `c * rows + r`. One invocation per element, reading
/// strided and writing contiguously; workgroups on a grid of up to 65,535 columns.
const SHADER: &str = r"
struct Shape { rows: u32, cols: u32, words: u32, pad: u32 }
@group(0) @binding(0) var<storage, read> src: array<u32>;
@group(0) @binding(1) var<storage, read_write> dst: array<u32>;
@group(0) @binding(2) var<uniform> shape: Shape;

@compute @workgroup_size(64)
fn transpose(@builtin(workgroup_id) wid: vec3<u32>,
             @builtin(num_workgroups) groups: vec3<u32>,
             @builtin(local_invocation_index) lane: u32) {
    let i = (wid.y * groups.x + wid.x) * 64u + lane;
    if (i >= shape.rows * shape.cols) {
        return;
    }
    let r = i % shape.rows;
    let c = i / shape.rows;
    let at = (r * shape.cols + c) * shape.words;
    for (var k = 0u; k < shape.words; k++) {
        dst[i * shape.words + k] = src[at + k];
    }
}
";

/// The transpose pipeline and its bind group layout, built once per device.
pub(crate) struct Transposer {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

/// One bound transpose: its buffers, its shape and its grid of workgroups.
pub(crate) struct Move {
    group: wgpu::BindGroup,
    grid: (u32, u32),
}

impl Transposer {
    /// The pipeline, or wgpu's reason for rejecting it.
    pub(crate) fn new(device: &wgpu::Device) -> Result<Transposer, String> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        use wgpu::BufferBindingType::{Storage, Uniform};
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("grid-gen transpose"),
            entries: &[
                crate::layout_entry(0, Storage { read_only: true }),
                crate::layout_entry(1, Storage { read_only: false }),
                crate::layout_entry(2, Uniform),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("grid-gen transpose"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("grid-gen transpose"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("grid-gen transpose"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("transpose"),
            compilation_options: Default::default(),
            cache: None,
        });
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(e.to_string()),
            None => Ok(Transposer { pipeline, layout }),
        }
    }

    /// A transpose of `src` (`rows × cols` elements of `words` words) into `dst`.
    pub(crate) fn bind(
        &self,
        device: &wgpu::Device,
        src: &wgpu::Buffer,
        dst: &wgpu::Buffer,
        (rows, cols): (usize, usize),
        words: usize,
        max_groups: u32,
    ) -> Move {
        let shape: Vec<u8> =
            [rows, cols, words, 0].iter().flat_map(|&v| (v as u32).to_le_bytes()).collect();
        let shape = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: &shape,
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: src.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: dst.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: shape.as_entire_binding() },
            ],
        });
        let groups = ((rows * cols) as u64).div_ceil(WORKGROUP as u64).max(1);
        let x = groups.min(max_groups as u64);
        Move { group, grid: (x as u32, groups.div_ceil(x) as u32) }
    }

    /// Encodes `m` into `pass`.
    pub(crate) fn encode(&self, pass: &mut wgpu::ComputePass, m: &Move) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &m.group, &[]);
        pass.dispatch_workgroups(m.grid.0, m.grid.1, 1);
    }
}

#[cfg(test)]
mod tests {
    /// The shader is valid WGSL for naga, whatever adapter the tests find.
    #[test]
    fn shader_validates() {
        let module = naga::front::wgsl::parse_str(super::SHADER).expect("parses");
        naga::valid::Validator::new(Default::default(), naga::valid::Capabilities::empty())
            .validate(&module)
            .expect("validates");
    }
}

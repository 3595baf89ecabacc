//! Which graphics adapters wgpu sees on this machine, and which one Burn's default wgpu device
//! comes up on: `trainer gpu-info` prints them, and a GPU check refuses a software adapter
//! (Mesa's lavapipe or llvmpipe) where a real GPU was expected.
//!
//! The choice is made by the runtime (cubecl-wgpu 0.11: the first API of Vulkan, DX12, OpenGL
//! with a non-CPU adapter, then the adapter wgpu returns for a high-performance request); this
//! module repeats that request on its own instance rather than reaching into the runtime.

use burn::tensor::wgpu::wgpu;
use cubecl::future::block_on;

/// One adapter as wgpu reports it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Adapter {
    /// The adapter's name, e.g. "NVIDIA H100 80GB HBM3" or "llvmpipe (LLVM 19.1.7, 256 bits)".
    pub name: String,
    /// Graphics API: Vulkan, Gl, …
    pub backend: String,
    /// DiscreteGpu, IntegratedGpu, VirtualGpu, Cpu or Other.
    pub device_type: String,
    /// Driver name and version information.
    pub driver: String,
}

impl Adapter {
    fn of(info: &wgpu::AdapterInfo) -> Self {
        Self {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
        }
    }

    /// A software rasteriser rather than a GPU: wgpu calls it a CPU device, or Mesa names it.
    pub fn is_software(&self) -> bool {
        let name = self.name.to_lowercase();
        self.device_type == "Cpu"
            || ["llvmpipe", "lavapipe", "swiftshader", "softpipe"]
                .iter()
                .any(|s| name.contains(s))
    }
}

impl std::fmt::Display for Adapter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({}, {}; driver {})",
            self.name, self.backend, self.device_type, self.driver
        )
    }
}

const CHAIN: [wgpu::Backend; 3] = [wgpu::Backend::Vulkan, wgpu::Backend::Dx12, wgpu::Backend::Gl];

fn instance(backend: wgpu::Backend) -> wgpu::Instance {
    wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: backend.into(),
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    })
}

/// Every adapter of each API in the runtime's chain, in enumeration order.
fn listed() -> Vec<(wgpu::Backend, Vec<Adapter>)> {
    CHAIN
        .iter()
        .map(|&b| {
            let found = block_on(instance(b).enumerate_adapters(b.into()));
            (b, found.iter().map(|a| Adapter::of(&a.get_info())).collect())
        })
        .collect()
}

/// Every adapter of every API in the runtime's chain, in enumeration order.
pub fn adapters() -> Vec<Adapter> {
    listed().into_iter().flat_map(|(_, a)| a).collect()
}

/// The adapter Burn's default wgpu device takes: on the first API of the chain that has a
/// non-CPU adapter (or, where none has, the first with any), wgpu's answer to a
/// high-performance request.
pub fn preferred() -> Option<Adapter> {
    let listed = listed();
    let backend = listed
        .iter()
        .find(|(_, a)| a.iter().any(|a| a.device_type != "Cpu"))
        .or_else(|| listed.iter().find(|(_, a)| !a.is_empty()))
        .map(|(b, _)| *b)?;
    let adapter = block_on(instance(backend).request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        force_fallback_adapter: false,
        compatible_surface: None,
        ..wgpu::RequestAdapterOptions::default()
    }))
    .ok()?;
    Some(Adapter::of(&adapter.get_info()))
}

/// Burn's reduction and product kernels on `device` at a training configuration's sizes: the
/// reductions a step makes that only Burn can make (a convolution's bias gradient sums
/// `[C, B·H·W]` over its second axis, its weight gradient is a product over B·H·W; a mean over
/// a whole `[B, 3, H, W]` batch), on tensors of ones whose sums are exact in f32. Returns what came out wrong (empty: all exact).
///
/// Burn 0.22.1 on Mesa's lavapipe gets these wrong once a reduction spans more than 65,535
/// workgroups (the row sums of a `[16, 65534]` tensor of ones: 65520, 0, 0, …), so training at
/// 256² there would be silently wrong; the trainer's own losses avoid the kernels
/// (`train::loss::row_sums`), but Burn's backward passes do not.
pub fn inexact_reductions(device: &burn::tensor::Device, batch: usize, size: usize) -> Vec<String> {
    use burn::tensor::Tensor;
    let n = batch * size * size;
    let mut wrong = Vec::new();
    let rows: Vec<f32> = Tensor::<2>::ones([4, n], device)
        .sum_dim(1)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap_or_default();
    if rows.len() != 4 || rows.iter().any(|&v| v != n as f32) {
        wrong.push(format!(
            "row sums of a [4, {n}] tensor of ones: {rows:?} (want {n} each)"
        ));
    }
    // A convolution's weight gradient is a product over B·H·W.
    let product: Vec<f32> = Tensor::<2>::ones([4, n], device)
        .matmul(Tensor::ones([n, 1], device))
        .into_data()
        .try_to_vec::<f32>()
        .unwrap_or_default();
    if product.len() != 4 || product.iter().any(|&v| v != n as f32) {
        wrong.push(format!(
            "product of a [4, {n}] and an [{n}, 1] tensor of ones: {product:?} (want {n} each)"
        ));
    }
    let m: Vec<f32> = Tensor::<4>::ones([batch, 3, size, size], device)
        .mean()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap_or_default();
    if m.first().is_none_or(|&v| (v - 1.0).abs() > 1e-6) {
        wrong.push(format!(
            "mean of a [{batch}, 3, {size}, {size}] tensor of ones: {m:?} (want 1)"
        ));
    }
    wrong
}

#[cfg(test)]
mod tests {
    use super::*;

    fn named(name: &str, device_type: &str) -> Adapter {
        Adapter {
            name: name.into(),
            backend: "Vulkan".into(),
            device_type: device_type.into(),
            driver: String::new(),
        }
    }

    #[test]
    fn software_rasterisers_are_told_from_gpus_by_type_and_by_name() {
        assert!(named("llvmpipe (LLVM 19.1.7, 256 bits)", "Cpu").is_software());
        // Mesa's drivers named, whatever type a loader reports.
        assert!(named("llvmpipe (LLVM 19.1.7, 256 bits)", "Other").is_software());
        assert!(named("Lavapipe", "VirtualGpu").is_software());
        assert!(named("SwiftShader Device (Subzero)", "Other").is_software());
        assert!(named("Some CPU adapter", "Cpu").is_software());
        assert!(!named("NVIDIA H100 80GB HBM3", "DiscreteGpu").is_software());
        assert!(!named("AMD Radeon Graphics (RADV GFX1103_R1)", "IntegratedGpu").is_software());
    }

    /// On any machine the preferred adapter is one of those listed (the same request, twice).
    #[test]
    fn the_preferred_gpu_adapter_is_one_of_those_listed() {
        let all = adapters();
        match preferred() {
            Some(p) => assert!(
                all.iter().any(|a| a.name == p.name && a.backend == p.backend),
                "{p} not in {all:?}"
            ),
            None => assert!(all.is_empty(), "adapters listed but none preferred: {all:?}"),
        }
    }
}

//! What the wgpu runtime on a device compiles kernels to, and what that device offers the
//! network beyond f32 (f16 arithmetic, tensor cores): `trainer gpu-info` prints it.
//!
//! The compiler is CubeCL's choice (cubecl-wgpu 0.11): SPIR-V on a Vulkan adapter when the
//! trainer is built with the `vulkan` feature and the adapter has the device-scope memory
//! model, buffer device addresses and SPIR-V 1.3 or later (`wgpu<spirv>`); WGSL through naga
//! otherwise (`wgpu<wgsl>`). Tensor cores are reachable only through cooperative-matrix
//! ("cmma") instructions, which only the SPIR-V path emits, and only for the exact input types
//! the driver lists: on NVIDIA's Vulkan driver f16, bf16 and 8-bit types, not f32.

use burn::tensor::Device;
use cubecl::ir::{ElemType, FloatKind};

/// The runtime of one CubeCL device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Runtime {
    /// `wgpu<spirv>` or `wgpu<wgsl>` (CubeCL's own name, which says which compiler serves it).
    pub name: &'static str,
    /// Whether the device does arithmetic in f16 (not just converts to and from it).
    pub f16: bool,
    /// The cooperative-matrix shapes the device runs, as `a×b→c m×n×k` (empty: none).
    pub cmma: Vec<String>,
}

impl Runtime {
    /// The runtime of `device`; `None` for a device that is not a CubeCL device (the CPU).
    pub fn of(device: &Device) -> Option<Self> {
        let client = match device.clone().inner().as_dispatch() {
            burn::backend::DispatchDevice::Cube(cube) => cube.client(),
            _ => return None,
        };
        let props = client.properties();
        let f16 = ElemType::Float(FloatKind::F16);
        Some(Self {
            name: client.name(),
            f16: props
                .features
                .types
                .elem
                .get(&f16)
                .is_some_and(|usage| usage.contains(cubecl::ir::features::TypeUsage::Arithmetic)),
            cmma: props
                .features
                .matmul
                .cmma
                .iter()
                .map(|c| format!("{}×{}→{} {}×{}×{}", c.a_type, c.b_type, c.cd_type, c.m, c.n, c.k))
                .collect(),
        })
    }

    /// Whether kernels reach this device as SPIR-V.
    pub fn is_spirv(&self) -> bool {
        self.name == "wgpu<spirv>"
    }
}

impl std::fmt::Display for Runtime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "runtime {}; f16 arithmetic: {}; ",
            self.name,
            if self.f16 { "yes" } else { "no" }
        )?;
        if self.cmma.is_empty() {
            let why = if self.is_spirv() {
                "the driver lists no cooperative-matrix type"
            } else {
                "only the SPIR-V path emits them"
            };
            write!(f, "cooperative-matrix (tensor-core) matmul: none ({why})")
        } else {
            write!(f, "cooperative-matrix (tensor-core) matmul: {}", self.cmma.join(", "))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The wgpu device's runtime is the compiler this build asks for: WGSL without the `vulkan`
    /// feature, one of the two with it, and exactly `MATEDIT_EXPECT_RUNTIME` where that is set
    /// (`.ci/run` sets it on lavapipe; Debian 12's lavapipe takes SPIR-V).
    #[test]
    fn the_gpu_runtime_is_the_compiler_the_build_asks_for() {
        let Some(device) = crate::rendering_layer::gpu::tests::device() else {
            return;
        };
        let r = Runtime::of(&device).expect("the wgpu device is a CubeCL device");
        if cfg!(not(feature = "vulkan")) {
            assert_eq!(r.name, "wgpu<wgsl>", "{r}");
        }
        assert!(matches!(r.name, "wgpu<wgsl>" | "wgpu<spirv>"), "{r}");
        if let Ok(want) = std::env::var("MATEDIT_EXPECT_RUNTIME") {
            assert_eq!(r.name, want, "{r}");
        }
        // The tensor-core shapes are only ever reported for the SPIR-V path.
        assert!(r.cmma.is_empty() || r.is_spirv(), "{r}");
        assert!(r.to_string().starts_with(&format!("runtime {}", r.name)));
    }

    /// Each of the line's cases, with no device: the shapes listed, or why there are none.
    #[test]
    fn the_gpu_runtime_line_names_each_tensor_core_shape_or_why_there_is_none() {
        let with = Runtime {
            name: "wgpu<spirv>",
            f16: true,
            cmma: vec!["f16×f16→f32 16×16×16".into(), "bf16×bf16→f32 16×8×16".into()],
        };
        assert_eq!(
            with.to_string(),
            "runtime wgpu<spirv>; f16 arithmetic: yes; cooperative-matrix (tensor-core) matmul: \
             f16×f16→f32 16×16×16, bf16×bf16→f32 16×8×16"
        );
        let spirv_none = Runtime {
            cmma: Vec::new(),
            ..with.clone()
        };
        assert!(
            spirv_none
                .to_string()
                .ends_with("none (the driver lists no cooperative-matrix type)")
        );
        let wgsl = Runtime {
            name: "wgpu<wgsl>",
            f16: false,
            cmma: Vec::new(),
        };
        assert!(!wgsl.is_spirv() && with.is_spirv());
        assert_eq!(
            wgsl.to_string(),
            "runtime wgpu<wgsl>; f16 arithmetic: no; cooperative-matrix (tensor-core) matmul: none \
             (only the SPIR-V path emits them)"
        );
    }

    #[test]
    fn the_cpu_device_has_no_gpu_runtime() {
        assert_eq!(Runtime::of(&Device::flex()), None);
    }
}

//! The device a run trains on: its name in manifests ([`DeviceName`]), opening it (one
//! process, or one rank of a data-parallel run: [`device_for`], [`device_for_rank`]), whether
//! it is a GPU ([`on_cube`]), what wgpu sees of the machine ([`adapter`]) and what the runtime
//! on a GPU compiles to and offers ([`runtime`]).

#[cfg(feature = "wgpu")]
pub mod adapter;
#[cfg(feature = "wgpu")]
pub mod runtime;

use crate::parallel::Ranks;
use anyhow::Result;
use burn::tensor::Device;
use matedit_contract::manifest::Named;

/// Whether `device` is a CubeCL (GPU) device. The few operations whose Burn 0.22.1 kernels are
/// missing or wrong there (the normal module's upsampling, the SSIM window) take a formulation
/// that runs correctly on it; the host keeps Burn's own, bit for bit.
pub fn on_cube(device: &burn::tensor::Device) -> bool {
    // CUDA is a CubeCL device too (its build is not possible on the development machine: README).
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    {
        matches!(
            device.clone().inner().as_dispatch(),
            burn::backend::DispatchDevice::Cube(_)
        )
    }
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    {
        let _ = device;
        false
    }
}

#[cfg(feature = "wgpu")]
/// The wgpu device (the first adapter wgpu prefers: a discrete GPU where there is one, Mesa's
/// lavapipe on a machine without), initialised once per process.
pub fn wgpu_device() -> Result<Device, String> {
    static DEVICE: std::sync::OnceLock<Result<Device, String>> = std::sync::OnceLock::new();
    DEVICE
        .get_or_init(|| {
            Device::wgpu_options().init().map_err(|e| {
                format!(
                    "no wgpu device could be opened ({e}); on a machine without a GPU install Mesa's \
                     software Vulkan driver (Debian: `apt-get install mesa-vulkan-drivers`)"
                )
            })
        })
        .clone()
}

#[cfg(feature = "wgpu")]
/// The wgpu device of the rank that takes GPU `index` of its machine (data-parallel training):
/// the `index`-th discrete GPU where wgpu sees several, and the default device where it sees
/// one or none (a scheduler that gives each task its own GPU shows it only that one). Also
/// what was chosen, for the run's log.
pub fn wgpu_device_at(index: usize) -> Result<(Device, String), String> {
    let discrete: Vec<adapter::Adapter> = adapter::adapters()
        .into_iter()
        .filter(|a| a.device_type == "DiscreteGpu" && a.backend == "Vulkan")
        .collect();
    if discrete.len() <= 1 {
        let why = match discrete.first() {
            Some(a) => format!("the only discrete GPU this task sees, {a}"),
            None => "the default adapter (no discrete GPU seen)".to_string(),
        };
        return wgpu_device().map(|d| (d, why));
    }
    let Some(a) = discrete.get(index) else {
        return Err(format!(
            "GPU {index} was asked for (MATEDIT_GPU, SLURM_LOCALID or the rank on this machine), but wgpu sees {} \
             discrete GPUs here",
            discrete.len()
        ));
    };
    let why = format!("discrete GPU {index} of {}, {a}", discrete.len());
    Device::wgpu_options()
        .device_kind(burn::tensor::DeviceKind::DiscreteGpu(index))
        .init()
        .map(|d| (d, why))
        .map_err(|e| format!("cannot open discrete GPU {index}: {e}"))
}

/// The Burn device of a run, with autodiff. A GPU device that this build has but the machine
/// lacks is an error that says so.
pub fn device_for(name: &str) -> Result<Device> {
    check_device_name(name).map_err(|e| anyhow::anyhow!(e))?;
    match name {
        #[cfg(feature = "wgpu")]
        "wgpu" => Ok(wgpu_device().map_err(|e| anyhow::anyhow!(e))?.autodiff()),
        #[cfg(feature = "cuda")]
        "cuda" => Ok(Device::cuda(0).autodiff()),
        _ => Ok(Device::flex().autodiff()),
    }
}

/// Which GPU of its machine a rank takes: `MATEDIT_GPU`, else Slurm's `SLURM_LOCALID`, else
/// the rank among those on its machine.
pub fn gpu_index(ranks: &Ranks) -> Result<usize> {
    for var in ["MATEDIT_GPU", "SLURM_LOCALID"] {
        if let Ok(v) = std::env::var(var) {
            return v
                .trim()
                .parse()
                .map_err(|_| anyhow::anyhow!("{var} = {v:?}: expected a GPU index (0, 1, …)"));
        }
    }
    Ok(ranks.local_rank())
}

/// [`device_for`] for one rank of a data-parallel run: on a GPU, the rank's own (see
/// [`gpu_index`]); with the choice, for the log.
pub fn device_for_rank(name: &str, ranks: &Ranks) -> Result<(Device, String)> {
    check_device_name(name).map_err(|e| anyhow::anyhow!(e))?;
    match name {
        #[cfg(feature = "wgpu")]
        "wgpu" if ranks.size() > 1 || std::env::var_os("MATEDIT_GPU").is_some() => {
            let (d, why) = wgpu_device_at(gpu_index(ranks)?).map_err(|e| anyhow::anyhow!(e))?;
            Ok((d.autodiff(), why))
        }
        #[cfg(feature = "cuda")]
        "cuda" if ranks.size() > 1 => {
            let k = gpu_index(ranks)?;
            Ok((Device::cuda(k).autodiff(), format!("CUDA device {k}")))
        }
        _ => {
            let _ = ranks;
            Ok((device_for(name)?, String::new()))
        }
    }
}

/// A device a run trains on, by its name in manifests and on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeviceName {
    /// Burn's flex CPU backend.
    Cpu,
    /// Burn's wgpu backend (a build with `--features wgpu`).
    Wgpu,
    /// Burn's CUDA backend (a build with `--features cuda`).
    Cuda,
}

impl Named for DeviceName {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("cpu", DeviceName::Cpu),
        ("wgpu", DeviceName::Wgpu),
        ("cuda", DeviceName::Cuda),
    ];
    fn refusal(name: &str) -> String {
        let names: Vec<&str> = Self::NAMES.iter().map(|(n, _)| *n).collect();
        format!("unknown device {name:?} ({})", names.join(", "))
    }
}

impl DeviceName {
    /// Whether this build can train on it, and if not, why.
    pub fn check_built(self) -> std::result::Result<(), String> {
        let missing = |feature: &str, what: &str| {
            Err(format!(
                "this build has no {what} backend: build the trainer with `--features {feature}`"
            ))
        };
        match self {
            DeviceName::Cpu => Ok(()),
            DeviceName::Wgpu if cfg!(feature = "wgpu") => Ok(()),
            DeviceName::Wgpu => missing("wgpu", "wgpu (Vulkan, Metal, DX12)"),
            DeviceName::Cuda if cfg!(feature = "cuda") => Ok(()),
            DeviceName::Cuda => missing("cuda", "CUDA"),
        }
    }
}

/// Whether this build can train on the device `name`, and if not, why.
pub fn check_device_name(name: &str) -> std::result::Result<(), String> {
    DeviceName::from_name(name)
        .ok_or_else(|| DeviceName::refusal(name))?
        .check_built()
}

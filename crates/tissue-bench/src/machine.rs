//! What the numbers were measured on: CPU, threads, commit, adapter, peak memory.

use serde::Serialize;

/// The machine and the code a run measured.
#[derive(Debug, Clone, Serialize)]
pub struct Machine {
    /// `model name` of the first processor in `/proc/cpuinfo`, or "unknown".
    pub cpu_model: String,
    /// Logical processors listed in `/proc/cpuinfo` (0 when it is absent).
    pub cpu_logical_processors: usize,
    /// Threads in rayon's global pool (the CPU path's parallelism).
    pub rayon_threads: usize,
    /// `git rev-parse HEAD` at run time, or "unknown".
    pub git_commit: String,
    /// `std::env::consts::OS` and `ARCH`.
    pub os: String,
}

impl Machine {
    /// Reads the machine's description.
    pub fn detect() -> Self {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let cpu_model = cpuinfo
            .lines()
            .find_map(|line| {
                let (key, value) = line.split_once(':')?;
                (key.trim() == "model name").then(|| value.trim().to_owned())
            })
            .unwrap_or_else(|| "unknown".to_owned());
        let cpu_logical_processors = cpuinfo
            .lines()
            .filter(|line| line.split(':').next().map(str::trim) == Some("processor"))
            .count();
        Self {
            cpu_model,
            cpu_logical_processors,
            rayon_threads: rayon::current_num_threads(),
            git_commit: git_commit(),
            os: format!("{} {}", std::env::consts::OS, std::env::consts::ARCH),
        }
    }
}

fn git_commit() -> String {
    std::process::Command::new("git")
        .args(["rev-parse", "HEAD"])
        .output()
        .ok()
        .filter(|out| out.status.success())
        .and_then(|out| String::from_utf8(out.stdout).ok())
        .map(|s| s.trim().to_owned())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unknown".to_owned())
}

/// The GPU adapter a run used, as wgpu describes it.
#[derive(Debug, Clone, Serialize)]
pub struct Adapter {
    /// Adapter name, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)".
    pub name: String,
    /// Graphics backend, e.g. "Vulkan".
    pub backend: String,
    /// "DiscreteGpu", "Cpu", ...
    pub device_type: String,
    /// Driver name.
    pub driver: String,
    /// Driver version string.
    pub driver_info: String,
    /// Whether the adapter offers timestamp queries: the bench then opens its
    /// device with them and times each kernel of the per-stage breakdown by
    /// them (the solve and tracking timings stay wall clock on every adapter).
    pub timestamp_queries: bool,
}

impl Adapter {
    /// Describes `adapter`.
    pub fn of(adapter: &wgpu::Adapter) -> Self {
        let info = adapter.get_info();
        Self {
            name: info.name,
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: info.driver,
            driver_info: info.driver_info,
            timestamp_queries: adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY),
        }
    }
}

/// Peak resident memory of this process so far (`VmHWM` in
/// `/proc/self/status`), in bytes; `None` where the file is absent.
pub fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line
        .trim_start_matches("VmHWM:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib * 1024)
}

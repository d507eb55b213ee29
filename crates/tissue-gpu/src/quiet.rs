//! Opening the graphics API without its drivers' chatter: Mesa's Vulkan
//! device-selection layer prints `error: XDG_RUNTIME_DIR is invalid or not
//! set in the environment.` to standard error whenever it looks for a
//! display and finds none, as on every headless machine, though nothing is
//! wrong. [`instance_and_adapters`] (and [`crate::adapter_from_env`])
//! capture what the drivers print while the instance opens and lists its
//! adapters, and pass it on as `info`
//! log lines (target `tissue_gpu::driver`): shown with `RUST_LOG=info` or
//! more, and printed as it comes, uncaptured, when that level is on.

/// The log target of what the drivers print while adapters are listed.
pub const DRIVER_LOG: &str = "tissue_gpu::driver";

/// A wgpu instance honouring `WGPU_BACKEND` and the other `wgpu` variables,
/// and the adapters it lists, with what the drivers print meanwhile turned
/// into log lines (see the module's doc).
pub fn instance_and_adapters() -> (wgpu::Instance, Vec<wgpu::Adapter>) {
    hushed(|| {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle().with_env());
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        (instance, adapters)
    })
}

/// Held while [`hushed`] captures standard error: a process may capture
/// it once at a time, so captures from threads in parallel wait their
/// turn.
#[cfg(unix)]
static CAPTURE: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs `f` with the process's standard error captured, then logs each
/// captured line at `info` on [`DRIVER_LOG`]. Where that level is on, or
/// the capture cannot start (something else in the process holds one),
/// `f` runs with standard error as it is.
#[cfg(unix)]
pub(crate) fn hushed<T>(f: impl FnOnce() -> T) -> T {
    use std::io::Read;
    if log::log_enabled!(target: DRIVER_LOG, log::Level::Info) {
        return f();
    }
    let _turn = CAPTURE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let Ok(mut capture) = gag::BufferRedirect::stderr() else {
        return f();
    };
    let out = f();
    let mut said = String::new();
    // A capture that cannot be read back loses only the drivers' chatter.
    let _ = capture.read_to_string(&mut said);
    drop(capture);
    for line in said.lines().filter(|l| !l.trim().is_empty()) {
        log::info!(target: DRIVER_LOG, "{line}");
    }
    out
}

/// Elsewhere no driver is known to print unasked: `f` as it is.
#[cfg(not(unix))]
pub(crate) fn hushed<T>(f: impl FnOnce() -> T) -> T {
    f()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn what_is_printed_while_hushed_does_not_reach_standard_error() {
        // Only one capture of a process's standard error may be active; a
        // second in the same process at the same time is refused, which is
        // how this test sees the first one was on.
        let inside = hushed(|| gag::BufferRedirect::stderr().is_err());
        assert!(inside, "standard error was not captured inside `hushed`");
        // Other tests' `hushed` wait while this holds the turn.
        let _turn = CAPTURE
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let after = gag::BufferRedirect::stderr();
        assert!(after.is_ok(), "the capture outlived `hushed`");
    }
}

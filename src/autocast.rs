//! Mixed precision through libtorch's autocast, on CPU as on CUDA. `tch` exposes only CUDA's fp16 autocast, so the
//! device-generic switches of ATen (`at::autocast::set_autocast_enabled` and `set_autocast_dtype`, exported by
//! `libtorch_cpu`) are called directly. Inside an [`Autocast`] scope, matrix products and convolutions run in the
//! chosen 16-bit type while weights, gradients and the optimiser stay in fp32 (what `torch.autocast` does).
use tch::Device;

/// ATen's `c10::DeviceType` and `c10::ScalarType` codes (both `int8_t` enums).
const DEVICE_CPU: i8 = 0;
const DEVICE_CUDA: i8 = 1;
const BFLOAT16: i8 = 15;

// SAFETY of the declarations: each name is the exported symbol of the ATen function with exactly these argument
// types (`c10::DeviceType` and `c10::ScalarType` are `enum class : int8_t`, passed by value like `int8_t`).
unsafe extern "C" {
    #[link_name = "_ZN2at8autocast20set_autocast_enabledEN3c1010DeviceTypeEb"]
    fn set_autocast_enabled(device: i8, enabled: bool);
    #[link_name = "_ZN2at8autocast19is_autocast_enabledEN3c1010DeviceTypeE"]
    fn is_autocast_enabled(device: i8) -> bool;
    #[link_name = "_ZN2at8autocast18set_autocast_dtypeEN3c1010DeviceTypeENS1_10ScalarTypeE"]
    fn set_autocast_dtype(device: i8, dtype: i8);
    #[link_name = "_ZN2at8autocast18get_autocast_dtypeEN3c1010DeviceTypeE"]
    fn get_autocast_dtype(device: i8) -> i8;
    #[link_name = "_ZN2at8autocast17increment_nestingEv"]
    fn increment_nesting() -> i32;
    #[link_name = "_ZN2at8autocast17decrement_nestingEv"]
    fn decrement_nesting() -> i32;
    #[link_name = "_ZN2at8autocast11clear_cacheEv"]
    fn clear_cache();
}

/// A bf16 autocast scope on one device for the current thread; dropping it restores the previous state.
#[must_use = "autocast lasts as long as the guard"]
pub struct Autocast {
    device: i8,
    was_enabled: bool,
    was_dtype: i8,
}

impl Autocast {
    /// Starts bf16 autocast for operations on `device` (CPU or CUDA).
    pub fn bf16(device: Device) -> Autocast {
        let device = if device.is_cuda() { DEVICE_CUDA } else { DEVICE_CPU };
        // SAFETY: plain calls into ATen's thread-local autocast state with valid codes.
        unsafe {
            let guard =
                Autocast { device, was_enabled: is_autocast_enabled(device), was_dtype: get_autocast_dtype(device) };
            set_autocast_dtype(device, BFLOAT16);
            set_autocast_enabled(device, true);
            increment_nesting();
            guard
        }
    }

    /// Whether bf16 autocast is on for `device` in this thread.
    pub fn active(device: Device) -> bool {
        let device = if device.is_cuda() { DEVICE_CUDA } else { DEVICE_CPU };
        // SAFETY: a read of ATen's thread-local autocast state.
        unsafe { is_autocast_enabled(device) && get_autocast_dtype(device) == BFLOAT16 }
    }
}

impl Drop for Autocast {
    fn drop(&mut self) {
        // SAFETY: restores the state read in `bf16`; the cast cache is cleared when the outermost scope ends, as
        // `torch.autocast` does.
        unsafe {
            if decrement_nesting() == 0 {
                clear_cache();
            }
            set_autocast_enabled(self.device, self.was_enabled);
            set_autocast_dtype(self.device, self.was_dtype);
        }
    }
}

/// Runs `f` with autocast off on CPU and CUDA (what `torch.autocast(enabled=False)` does), for operations that
/// must not run in bf16: oneDNN has no bf16 LSTM on CPUs without bf16 instructions, where it fails to build its
/// kernel instead of falling back. Inputs made inside an autocast scope may be bf16: cast them to fp32 first.
pub fn full_precision<T>(f: impl FnOnce() -> T) -> T {
    let _restore = Suspended::new();
    f()
}

/// Autocast switched off on both devices until dropped, which restores what was on.
struct Suspended {
    was_enabled: [(i8, bool); 2],
}

impl Suspended {
    fn new() -> Suspended {
        // SAFETY: reads and writes of ATen's thread-local autocast state with valid device codes.
        unsafe {
            let was_enabled = [DEVICE_CPU, DEVICE_CUDA].map(|d| (d, is_autocast_enabled(d)));
            for (d, _) in was_enabled {
                set_autocast_enabled(d, false);
            }
            Suspended { was_enabled }
        }
    }
}

impl Drop for Suspended {
    fn drop(&mut self) {
        for (d, on) in self.was_enabled {
            // SAFETY: restores the state read in `new`.
            unsafe { set_autocast_enabled(d, on) };
        }
    }
}

//! The allocator settings of the `ntg` binary, shared with the benches so
//! that they time what `ntg` runs. The binary and each bench declare
//! mimalloc as their `#[global_allocator]` (a library cannot) and call
//! [`keep_freed_memory`] first.

/// mimalloc's `mi_option_purge_delay`: its place in mimalloc 3's
/// `mi_option_e` (libmimalloc-sys names no constant for it; the test
/// below checks the index by the option's default, 1000 ms, and its
/// neighbour's).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Keeps memory that tensors freed for the next tensors instead of handing
/// it back to the kernel, unless the user set `MIMALLOC_PURGE_DELAY`.
///
/// By default mimalloc returns freed pages to the kernel a second later; a
/// training step frees and reallocates the same large buffers at every
/// operation, so the kernel zeroed the same (transparent huge) pages again
/// and again: 12-17% of the paper-profile runs' CPU time was system time
/// (`clear_page_erms`, page faults). Keeping the pages measured 6-13%
/// faster on an object-collection video run, same losses to the last digit
/// (docs/results/speed-2026-11-29.md); the resident size stays at the
/// run's peak instead of shrinking between steps.
pub fn keep_freed_memory() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one of mimalloc's runtime options, an integer; any
        // value is valid for it (-1: never purge).
        #[allow(unsafe_code)]
        unsafe {
            libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1)
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_purge_delay_index_names_the_purge_delay_option() {
        // SAFETY: reads one of mimalloc's integer options.
        #[allow(unsafe_code)]
        let read = || unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
            return; // the user's value, not the default, would be read
        }
        assert_eq!(read(), 1000, "mimalloc 3's default purge delay (options.c)");
        keep_freed_memory();
        assert_eq!(read(), -1);
        // Three places on, `mi_option_os_tag`, default 100: untouched.
        #[allow(unsafe_code)]
        let os_tag = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY + 3) };
        assert_eq!(os_tag, 100, "mi_option_os_tag's default");
    }
}

//! Shared memory up front: iceoryx2 maps its segments from `/dev/shm` (a tmpfs), whose pages are
//! allocated only when first written. A segment larger than the free space is created without
//! complaint and the process dies of SIGBUS later, when a renderer's buffers fill it. So before
//! creating services the daemon checks that `/dev/shm` can hold what they pre-allocate, and
//! refuses with an error that says how much is needed instead.

use std::path::Path;

/// Where POSIX shared memory lives on Linux.
pub const SHM_DIR: &str = "/dev/shm";
/// Allowance for iceoryx2's management data and per-sample headers, per service (measured:
/// 2-60 kB per service, docs/ipc.md "Quality of service").
pub const PER_SERVICE_OVERHEAD_BYTES: usize = 128 * 1024;

/// `/dev/shm` cannot hold the services about to be created.
#[derive(Debug, thiserror::Error)]
#[error(
    "shared memory: {dir} has {free_mib:.1} MiB free but {what} need about {need_mib:.1} MiB \
     ({detail}); enlarge it (e.g. `mount -o remount,size=512M {dir}`, or `--shm-size` for a \
     container) or publish less (fewer subscribers, a coarser voxel size)"
)]
pub struct ShmTooSmall {
    dir: String,
    what: String,
    need_mib: f64,
    free_mib: f64,
    detail: String,
}

/// Free bytes of the file system holding `dir` (for an unprivileged process), if known.
fn free_bytes(dir: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs only writes into `st`; `path` is a valid NUL-terminated string.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: as above.
    let rc = unsafe { libc::statvfs(path.as_ptr(), &mut st) };
    (rc == 0).then(|| st.f_bavail as u64 * st.f_frsize as u64)
}

/// Checks that `dir` can hold `services` (name, pre-allocated bytes) and `reserved` bytes the
/// daemon's other services may still take there. Unknown free space passes.
pub fn check(
    dir: &Path,
    what: &str,
    services: &[(&str, usize)],
    reserved: usize,
) -> Result<usize, ShmTooSmall> {
    let need = services
        .iter()
        .map(|(_, b)| b + PER_SERVICE_OVERHEAD_BYTES)
        .sum::<usize>();
    let Some(free) = free_bytes(dir) else {
        return Ok(need);
    };
    if (need + reserved) as u64 <= free {
        return Ok(need);
    }
    let mib = |b: usize| b as f64 / (1024.0 * 1024.0);
    let mut detail: Vec<String> = services
        .iter()
        .map(|(name, b)| format!("{name} {:.1} MiB", mib(*b)))
        .collect();
    if reserved > 0 {
        detail.push(format!(
            "the daemon's other services {:.1} MiB",
            mib(reserved)
        ));
    }
    Err(ShmTooSmall {
        dir: dir.display().to_string(),
        what: what.to_string(),
        need_mib: mib(need + reserved),
        free_mib: free as f64 / (1024.0 * 1024.0),
        detail: detail.join(", "),
    })
}

/// What the status, event and control services pre-allocate (the daemon's own services).
pub fn daemon_services() -> Vec<(&'static str, usize)> {
    vec![
        ("status", hydrometra_ipc::status::shared_memory_bytes()),
        // Events and control: small fixed segments (the event service's, measured, 238 kB).
        ("events and control", 256 * 1024),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_need_beyond_the_free_space_names_the_services_and_the_sizes() {
        let free = free_bytes(Path::new("/tmp")).expect("statvfs /tmp");
        let too_much = free as usize + 1;
        let e = check(
            Path::new("/tmp"),
            "the scene's services",
            &[("flow", too_much)],
            0,
        )
        .expect_err("more than the free space");
        let text = e.to_string();
        assert!(
            text.contains("/tmp") && text.contains("flow") && text.contains("MiB free"),
            "{text}"
        );
        assert!(check(Path::new("/tmp"), "x", &[("status", 1024)], 0).is_ok());
    }
}

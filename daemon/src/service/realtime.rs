//! Real-time scheduling (SCHED_FIFO) for the simulation thread (which publishes status) and the
//! rig I/O thread, so a busy desktop or a compile on the training PC does not delay the 1 kHz
//! loop. Both threads sleep between
//! ticks, so they cannot starve the machine.

/// Puts the calling thread under SCHED_FIFO at `priority` (1..=99); 0 leaves it as it is.
/// Returns an error message when the system refuses (no CAP_SYS_NICE or RLIMIT_RTPRIO too low).
pub fn set_current_thread_fifo(priority: u8) -> Result<(), String> {
    if priority == 0 {
        return Ok(());
    }
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: pthread_self() is the calling thread; `param` is a valid sched_param.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!(
            "cannot use SCHED_FIFO priority {priority}: {} (grant it with LimitRTPRIO= in the \
             systemd unit, or set loop.realtime_priority = 0)",
            std::io::Error::from_raw_os_error(rc)
        ))
    }
}

/// Applies [`set_current_thread_fifo`] and logs the outcome once per thread.
pub fn apply(thread: &str, priority: u8) {
    match set_current_thread_fifo(priority) {
        Ok(()) if priority > 0 => tracing::debug!(thread, priority, "SCHED_FIFO"),
        Ok(()) => {}
        Err(e) => tracing::warn!(thread, "{e}; running at normal priority"),
    }
}

/// Puts the calling thread back under normal scheduling (SCHED_OTHER): for threads that inherit
/// SCHED_FIFO but must never preempt the real-time loop (the scene thread and its helpers).
pub fn set_current_thread_normal() -> Result<(), String> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pthread_self() is the calling thread; `param` is a valid sched_param.
    let rc =
        unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_OTHER, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!(
            "cannot leave real-time scheduling: {}",
            std::io::Error::from_raw_os_error(rc)
        ))
    }
}

/// Sleeps until `CLOCK_MONOTONIC` reads `deadline_ns` (returns at once if it has passed). An
/// absolute deadline needs no clock read before the sleep, and the wake-up does not drift by
/// the time between such a read and the system call.
pub fn sleep_until_monotonic_ns(deadline_ns: u64) {
    const NS_PER_S: u64 = 1_000_000_000;
    let deadline = libc::timespec {
        tv_sec: (deadline_ns / NS_PER_S) as libc::time_t,
        tv_nsec: (deadline_ns % NS_PER_S) as libc::c_long,
    };
    // clock_nanosleep returns the error number; with TIMER_ABSTIME a signal just means "again".
    // SAFETY: `deadline` is a valid timespec; no remainder is asked for with an absolute time.
    while unsafe {
        libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &deadline,
            std::ptr::null_mut(),
        )
    } == libc::EINTR
    {}
}

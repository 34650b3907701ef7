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

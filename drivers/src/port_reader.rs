//! Waiting for the rig's bytes: one edge-triggered `epoll_wait` and one `read` per chunk.
//!
//! Why not serialport's `read` (`ppoll`, then a blocking `read`): when `ppoll` finds no input,
//! the tty layer first waits for its flip-buffer work (`n_tty_poll` -> `tty_buffer_flush_work`),
//! and right after a sample that work is often still finishing (on the other core, or preempted
//! by the real-time I/O thread it just woke): a second sleep and wake-up for every 250 Hz
//! sample. An edge-triggered epoll does not ask the tty before it sleeps; it wakes when the line
//! discipline has received bytes, and the read that follows finds them there.

use std::io::{self, ErrorKind};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::time::Duration;

/// Reads a serial port's input as it arrives, waiting at most `timeout` per call. Owns an epoll
/// instance watching the port; create it after opening the port and drop it before closing it.
pub(crate) struct PortReader {
    epoll: OwnedFd,
    port_fd: RawFd,
    timeout_ms: i32,
    /// The last read filled the buffer: bytes may be left that no new edge will announce.
    more: bool,
}

fn check(rc: libc::c_int, what: &str) -> io::Result<libc::c_int> {
    if rc < 0 {
        let e = io::Error::last_os_error();
        Err(io::Error::new(e.kind(), format!("{what}: {e}")))
    } else {
        Ok(rc)
    }
}

impl PortReader {
    /// Watches `port`; `timeout` (rounded up to whole ms) bounds each [`PortReader::read`].
    pub(crate) fn new(port: &impl AsRawFd, timeout: Duration) -> io::Result<Self> {
        let port_fd = port.as_raw_fd();
        // Reads return at once with what the line discipline holds (VMIN = VTIME = 0) instead of
        // blocking for a byte; O_NONBLOCK would do the same but also change the port's writes.
        // SAFETY: termios is plain data that tcgetattr fills; the descriptor is open.
        let mut termios: libc::termios = unsafe { std::mem::zeroed() };
        check(
            // SAFETY: `termios` is a valid, writable termios; the descriptor is open.
            unsafe { libc::tcgetattr(port_fd, &mut termios) },
            "tcgetattr",
        )?;
        termios.c_cc[libc::VMIN] = 0;
        termios.c_cc[libc::VTIME] = 0;
        check(
            // SAFETY: `termios` is a valid termios for this descriptor.
            unsafe { libc::tcsetattr(port_fd, libc::TCSANOW, &termios) },
            "tcsetattr",
        )?;
        // SAFETY: epoll_create1 takes no pointers; the descriptor it returns is ours to own.
        let epoll = unsafe {
            OwnedFd::from_raw_fd(check(
                libc::epoll_create1(libc::EPOLL_CLOEXEC),
                "epoll_create1",
            )?)
        };
        let mut event = libc::epoll_event {
            // Hang-ups and errors are always reported.
            events: (libc::EPOLLIN | libc::EPOLLET) as u32,
            u64: 0,
        };
        // Bytes already waiting make the port ready at once.
        check(
            // SAFETY: both descriptors are open; `event` is a valid epoll_event.
            unsafe { libc::epoll_ctl(epoll.as_raw_fd(), libc::EPOLL_CTL_ADD, port_fd, &mut event) },
            "epoll_ctl",
        )?;
        let timeout_ms = timeout
            .as_micros()
            .div_ceil(1000)
            .clamp(1, i32::MAX as u128) as i32;
        Ok(Self {
            epoll,
            port_fd,
            timeout_ms,
            more: false,
        })
    }

    /// Waits up to the timeout for input and reads it into `buf`: `Ok(0)` when none came,
    /// an error of kind `BrokenPipe` when the device hung up (unplugged, pty closed), `Interrupted`
    /// on a signal, another error when the read failed.
    pub(crate) fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if !self.more {
            let mut event = libc::epoll_event { events: 0, u64: 0 };
            // SAFETY: `event` has room for the one event asked for.
            let n =
                unsafe { libc::epoll_wait(self.epoll.as_raw_fd(), &mut event, 1, self.timeout_ms) };
            match n {
                n if n < 0 => return Err(io::Error::last_os_error()),
                0 => return Ok(0),
                _ => {}
            }
            if event.events & (libc::EPOLLHUP | libc::EPOLLERR) as u32 != 0 {
                return Err(io::Error::new(ErrorKind::BrokenPipe, "the device hung up"));
            }
        }
        // SAFETY: `buf` is valid for `buf.len()` writable bytes; the descriptor is open.
        let n = unsafe { libc::read(self.port_fd, buf.as_mut_ptr().cast(), buf.len()) };
        if n < 0 {
            self.more = false;
            return Err(io::Error::last_os_error());
        }
        let n = n as usize;
        self.more = n == buf.len();
        Ok(n)
    }
}

//! Connections per peer: tonic has no setting for how many TCP connections one remote host
//! may hold open, so one host could take every file descriptor the learner has (each
//! connection may then open `max_concurrent_streams` calls). [`LimitedIncoming`] wraps the
//! listener: a connection beyond `max_connections_per_peer` from the same address, or beyond
//! `max_connections` in all, is closed as it is accepted and counted. Accept errors (the
//! process is out of descriptors) are reported once a second and retried after a pause instead
//! of ending the server.

use std::collections::HashMap;
use std::future::Future;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tonic::transport::server::{Connected, TcpConnectInfo};

/// The limits and what they refused.
#[derive(Debug)]
pub struct PeerLimits {
    /// The server's name in the refusal ledger ([`crate::refusals`]).
    server: &'static str,
    per_peer: usize,
    total: usize,
    live: Mutex<HashMap<IpAddr, usize>>,
    /// Connections closed at once: their host held `per_peer` already.
    pub refused_per_peer: AtomicU64,
    /// Connections closed at once: `total` were open.
    pub refused_total: AtomicU64,
}

impl PeerLimits {
    /// Limits of the server named `server` in the refusal ledger (`fleet`, `env_rpc`).
    pub fn new(server: &'static str, per_peer: usize, total: usize) -> Arc<Self> {
        Arc::new(Self {
            server,
            per_peer: per_peer.max(1),
            total: total.max(1),
            live: Mutex::new(HashMap::new()),
            refused_per_peer: AtomicU64::new(0),
            refused_total: AtomicU64::new(0),
        })
    }

    /// Open connections: in all, and of `ip`.
    pub fn open(&self, ip: IpAddr) -> (usize, usize) {
        let live = self.live.lock().unwrap_or_else(|e| e.into_inner());
        (live.values().sum(), live.get(&ip).copied().unwrap_or(0))
    }

    /// A place for a connection from `ip`, or `None` when a limit is reached.
    fn admit(self: &Arc<Self>, ip: IpAddr) -> Option<Slot> {
        let mut live = self.live.lock().unwrap_or_else(|e| e.into_inner());
        if live.values().sum::<usize>() >= self.total {
            self.refused_total.fetch_add(1, Ordering::Relaxed);
            return None;
        }
        let n = live.entry(ip).or_insert(0);
        if *n >= self.per_peer {
            self.refused_per_peer.fetch_add(1, Ordering::Relaxed);
            return None;
        }
        *n += 1;
        Some(Slot { limits: self.clone(), ip })
    }
}

/// A connection's place, given back when the connection is dropped.
#[derive(Debug)]
struct Slot {
    limits: Arc<PeerLimits>,
    ip: IpAddr,
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut live = self.limits.live.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = live.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                live.remove(&self.ip);
            }
        }
    }
}

/// An admitted connection.
#[derive(Debug)]
pub struct LimitedStream {
    inner: TcpStream,
    _slot: Slot,
}

impl Connected for LimitedStream {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.inner.connect_info()
    }
}

impl AsyncRead for LimitedStream {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl AsyncWrite for LimitedStream {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_write_vectored(mut self: Pin<&mut Self>, cx: &mut Context<'_>, bufs: &[io::IoSlice<'_>]) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// The listener's connections within `limits` (see the module doc), for
/// `serve_with_incoming`. Never yields an error.
#[derive(Debug)]
pub struct LimitedIncoming {
    listener: TcpListener,
    limits: Arc<PeerLimits>,
    /// After an accept error: no accept before this sleep ends.
    pause: Option<Pin<Box<tokio::time::Sleep>>>,
    last_report: Option<Instant>,
    name: &'static str,
}

impl LimitedIncoming {
    /// `name` prefixes the reports (`coadapt-grpc learner`).
    pub fn new(listener: TcpListener, limits: Arc<PeerLimits>, name: &'static str) -> Self {
        Self { listener, limits, pause: None, last_report: None, name }
    }

    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }
}

impl tokio_stream::Stream for LimitedIncoming {
    type Item = io::Result<LimitedStream>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        loop {
            if let Some(p) = self.pause.as_mut() {
                ready!(p.as_mut().poll(cx));
                self.pause = None;
            }
            match ready!(self.listener.poll_accept(cx)) {
                Ok((stream, peer)) => match self.limits.admit(peer.ip()) {
                    Some(slot) => {
                        // Small frames (acknowledgements, polls) must not wait for Nagle.
                        let _ = stream.set_nodelay(true);
                        return Poll::Ready(Some(Ok(LimitedStream { inner: stream, _slot: slot })));
                    }
                    None => {
                        // Logged (first per peer), counted and summarised by the ledger.
                        let (all, of_peer) = self.limits.open(peer.ip());
                        let (reason, why) = if all >= self.limits.total {
                            ("connections_total", format!("connection closed as accepted: {all} open in all, the most this server keeps"))
                        } else {
                            (
                                "connections_per_peer",
                                format!("connection closed as accepted: {of_peer} open from this host, the most per host"),
                            )
                        };
                        crate::refusals::record(self.limits.server, reason, Some(peer.ip()), &why, crate::refusals::Notice::Log);
                    }
                },
                Err(e) => {
                    self.report(&format!("accepting a connection: {e}; pausing 50 ms"));
                    self.pause = Some(Box::pin(tokio::time::sleep(Duration::from_millis(50))));
                }
            }
        }
    }
}

impl LimitedIncoming {
    /// At most one report a second: a flood must not become a flood of log lines.
    fn report(&mut self, what: &str) {
        if self.last_report.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
            self.last_report = Some(Instant::now());
            coadapt_log::logln!("{}: {what}", self.name);
        }
    }
}

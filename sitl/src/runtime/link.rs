//! The host side of a running bus: a pseudo-terminal or a TCP socket, behind one small interface.

use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::os::fd::{AsFd, BorrowedFd};
use std::path::PathBuf;
use std::time::Instant;

use super::pty::{self, Pty};

/// What a bus thread talks to.
#[derive(Debug)]
pub enum Link {
    Pty(PtyLink),
    Tcp(TcpLink),
}

/// A pty, replaced by a new one on reconnect; optionally a stable symlink to its slave.
#[derive(Debug)]
pub struct PtyLink {
    pty: Option<Pty>,
    symlink: Option<PathBuf>,
    baud: u32,
    last_path: PathBuf,
}

/// A TCP listener serving one client at a time.
#[derive(Debug)]
pub struct TcpLink {
    listener: Option<TcpListener>,
    client: Option<TcpStream>,
    addr: SocketAddr,
}

impl PtyLink {
    pub fn open(baud: u32, symlink: Option<PathBuf>) -> io::Result<PtyLink> {
        let pty = Pty::open(baud)?;
        if let Some(link) = &symlink {
            pty::replace_symlink(link, pty.path())?;
        }
        let last_path = pty.path().to_path_buf();
        Ok(PtyLink {
            pty: Some(pty),
            symlink,
            baud,
            last_path,
        })
    }
}

impl TcpLink {
    pub fn bind(addr: SocketAddr) -> io::Result<TcpLink> {
        let listener = TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        Ok(TcpLink {
            listener: Some(listener),
            client: None,
            addr,
        })
    }

    /// Accept a waiting client if there is none.
    fn accept(&mut self) {
        if self.client.is_some() {
            return;
        }
        let Some(listener) = &self.listener else {
            return;
        };
        if let Ok((stream, peer)) = listener.accept()
            && stream.set_nonblocking(true).is_ok()
        {
            let _ = stream.set_nodelay(true);
            tracing::info!(%peer, "TCP client connected");
            self.client = Some(stream);
        }
    }
}

impl Link {
    /// The path (or address) a host should open.
    pub fn path(&self) -> PathBuf {
        match self {
            Link::Pty(link) => link
                .symlink
                .clone()
                .unwrap_or_else(|| link.last_path.clone()),
            Link::Tcp(link) => PathBuf::from(link.addr.to_string()),
        }
    }

    /// The TCP address, if this is a TCP link.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        match self {
            Link::Pty(_) => None,
            Link::Tcp(link) => Some(link.addr),
        }
    }

    /// Descriptor to poll for incoming bytes (or an incoming TCP client).
    pub fn poll_fd(&self) -> Option<BorrowedFd<'_>> {
        match self {
            Link::Pty(link) => link.pty.as_ref().map(Pty::master_fd),
            Link::Tcp(link) => match (&link.client, &link.listener) {
                (Some(client), _) => Some(client.as_fd()),
                (None, Some(listener)) => Some(listener.as_fd()),
                (None, None) => None,
            },
        }
    }

    /// The host's bit rate as the link knows it (a pty stores it; TCP has none).
    pub fn host_baud(&self) -> Option<u32> {
        match self {
            Link::Pty(link) => link.pty.as_ref().and_then(Pty::host_baud),
            Link::Tcp(_) => None,
        }
    }

    /// Read everything available; `on_chunk(read_at, bytes)` gets each chunk with the instant its `read()`
    /// returned. Returns false if nothing could be read.
    pub fn read_available(
        &mut self,
        buffer: &mut [u8],
        mut on_chunk: impl FnMut(Instant, &[u8]),
    ) -> bool {
        let mut any = false;
        if let Link::Tcp(link) = self {
            link.accept();
        }
        loop {
            let result = match self {
                Link::Pty(link) => match link.pty.as_mut() {
                    Some(pty) => pty.read(buffer),
                    None => return any,
                },
                Link::Tcp(link) => match link.client.as_mut() {
                    Some(client) => client.read(buffer),
                    None => return any,
                },
            };
            let read_at = Instant::now();
            match result {
                Ok(0) => {
                    if let Link::Tcp(link) = self {
                        tracing::info!("TCP client disconnected");
                        link.client = None;
                    }
                    return any;
                }
                Ok(n) => {
                    any = true;
                    on_chunk(read_at, &buffer[..n]);
                }
                Err(error) if error.kind() == io::ErrorKind::Interrupted => {}
                Err(error) => {
                    if error.kind() != io::ErrorKind::WouldBlock
                        && let Link::Tcp(link) = self
                    {
                        link.client = None;
                    }
                    return any;
                }
            }
        }
    }

    /// Hand bytes to the host; what the host side cannot take now is lost (like a UART overrun).
    pub fn write(&mut self, bytes: &[u8]) -> usize {
        let result = match self {
            Link::Pty(link) => match link.pty.as_mut() {
                Some(pty) => pty.write(bytes),
                None => return 0,
            },
            Link::Tcp(link) => match link.client.as_mut() {
                Some(client) => client.write(bytes),
                None => return 0,
            },
        };
        match result {
            Ok(n) => n,
            Err(error) => {
                if error.kind() != io::ErrorKind::WouldBlock
                    && let Link::Tcp(link) = self
                {
                    link.client = None;
                }
                0
            }
        }
    }

    /// The device disappears: the pty is closed (the host reads EOF/EIO) or the TCP client and listener
    /// are closed.
    pub fn disconnect(&mut self) {
        match self {
            Link::Pty(link) => {
                if let (Some(symlink), Some(pty)) = (&link.symlink, &link.pty) {
                    pty::remove_symlink_to(symlink, pty.path());
                }
                link.pty = None;
            }
            Link::Tcp(link) => {
                link.client = None;
                link.listener = None;
            }
        }
    }

    /// The device reappears: a new pty (the symlink now points at it) or a new listener on the same address.
    pub fn reconnect(&mut self) -> io::Result<PathBuf> {
        match self {
            Link::Pty(link) => {
                if link.pty.is_none() {
                    let pty = Pty::open(link.baud)?;
                    if let Some(symlink) = &link.symlink {
                        pty::replace_symlink(symlink, pty.path())?;
                    }
                    link.last_path = pty.path().to_path_buf();
                    link.pty = Some(pty);
                }
            }
            Link::Tcp(link) => {
                if link.listener.is_none() {
                    let listener = TcpListener::bind(link.addr)?;
                    listener.set_nonblocking(true)?;
                    link.listener = Some(listener);
                }
            }
        }
        Ok(self.path())
    }

    /// Remove the symlink (at shutdown).
    pub fn close(&mut self) {
        if let Link::Pty(link) = self
            && let (Some(symlink), Some(pty)) = (&link.symlink, &link.pty)
        {
            pty::remove_symlink_to(symlink, pty.path());
        }
        self.disconnect();
    }
}

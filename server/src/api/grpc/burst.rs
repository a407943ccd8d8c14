//! A gRPC connection's writes gathered into bursts. One HTTP/2 connection carries many
//! subscriptions; a change wakes each subscription's task, and each queues a frame and
//! wakes the connection's task, which would write what is queued so far: a change to 100
//! subscribers of one connection went out in about twenty `writev`s. Here the first write
//! after the connection went quiet waits once behind the tasks already runnable (the
//! connection's task goes to the back of the run queue), so the frames of one change
//! leave together. A lone answer waits only for the tasks ready before it.

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tonic::transport::server::Connected;

/// Where a connection is between bursts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Everything written was flushed: the next write starts a burst.
    Quiet,
    /// The burst's first write gave way once; the next goes to the socket.
    Yielded,
    /// Writing a burst, until it is flushed.
    Writing,
}

/// A connection whose writes leave in bursts (see the module).
pub(crate) struct Burst<T> {
    inner: T,
    state: State,
}

impl<T> Burst<T> {
    pub(crate) fn new(inner: T) -> Self {
        Burst {
            inner,
            state: State::Quiet,
        }
    }
}

impl<T> Burst<T> {
    /// Whether this write gives way first: the first of a burst does, once.
    fn gives_way(&mut self, cx: &mut Context<'_>) -> bool {
        match self.state {
            State::Quiet => {
                self.state = State::Yielded;
                // Woken while running: the task is queued behind the runnable ones.
                cx.waker().wake_by_ref();
                true
            }
            State::Yielded | State::Writing => {
                self.state = State::Writing;
                false
            }
        }
    }
}

impl<T: Connected> Connected for Burst<T> {
    type ConnectInfo = T::ConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.inner.connect_info()
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for Burst<T> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_read(cx, buf)
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for Burst<T> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        if this.gives_way(cx) {
            return Poll::Pending;
        }
        Pin::new(&mut this.inner).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        if this.gives_way(cx) {
            return Poll::Pending;
        }
        Pin::new(&mut this.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let flushed = Pin::new(&mut this.inner).poll_flush(cx);
        if flushed.is_ready() && this.state == State::Writing {
            this.state = State::Quiet;
        }
        flushed
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::task::{Wake, Waker};

    use super::*;

    struct Count(AtomicUsize);

    impl Wake for Count {
        fn wake(self: Arc<Self>) {
            self.0.fetch_add(1, Ordering::Relaxed);
        }
    }

    #[tokio::test]
    async fn a_bursts_first_write_gives_way_once_and_the_rest_go_through() {
        use tokio::io::AsyncReadExt;
        let (ours, mut theirs) = tokio::io::duplex(1024);
        let mut burst = Burst::new(ours);
        let count = Arc::new(Count(AtomicUsize::new(0)));
        let waker = Waker::from(count.clone());
        let mut cx = Context::from_waker(&waker);
        let mut write =
            |burst: &mut Burst<_>, bytes: &[u8]| Pin::new(burst).poll_write(&mut cx, bytes);
        assert!(
            write(&mut burst, b"a").is_pending(),
            "the first write gives way"
        );
        assert_eq!(
            count.0.load(Ordering::Relaxed),
            1,
            "and asks to be polled again"
        );
        assert!(matches!(write(&mut burst, b"a"), Poll::Ready(Ok(1))));
        assert!(matches!(write(&mut burst, b"b"), Poll::Ready(Ok(1))));
        let mut cx = Context::from_waker(&waker);
        assert!(Pin::new(&mut burst).poll_flush(&mut cx).is_ready());
        // Flushed: the next write starts a burst.
        let mut cx = Context::from_waker(&waker);
        assert!(Pin::new(&mut burst).poll_write(&mut cx, b"c").is_pending());
        assert!(matches!(
            Pin::new(&mut burst).poll_write(&mut cx, b"c"),
            Poll::Ready(Ok(1))
        ));
        assert_eq!(count.0.load(Ordering::Relaxed), 2);
        let mut read = [0u8; 3];
        theirs.read_exact(&mut read).await.expect("read");
        assert_eq!(&read, b"abc", "nothing written twice, nothing lost");
    }
}

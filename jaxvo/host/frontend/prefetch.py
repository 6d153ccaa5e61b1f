"""Host input and output beside the per-frame work: frames read ahead on a small thread
pool, images written behind on one thread (host only).

Decoding a 640x480 frame (a JPEG or PNG colour image and a 16-bit PNG depth image) takes
milliseconds, and encoding a mask or overlay PNG a few more; ``cv2.imread``, ``cv2.imwrite``
and numpy's array arithmetic release the GIL, so on a second core this work runs while the
main thread computes the grid flow and the device step runs, instead of adding to them.

* :func:`read_ahead` hands out the frames of a sequence in order, each as a future whose
  ``result()`` returns the frame or raises the error reading it raised, so a caller drops an
  unreadable frame where it is, exactly as when it reads ``seq[i]`` itself.
* :class:`BackgroundWriter` runs output calls on one thread in the order given; closing it
  (also when the run is interrupted) waits until every call has run.

Both are bounded: a few frames read ahead, a few calls waiting to be written, so memory
stays flat when the disk or the decoder is slower than the frames.
"""

from __future__ import annotations

import contextlib
import queue
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Self, TypeVar

T = TypeVar("T")

# Frames read beyond the one being used, and the threads reading them. Two threads keep a
# 2-core machine's spare core busy through a slow frame; four decoded frames ride out a
# stall of the disk without holding much memory.
READ_AHEAD = 4
READ_WORKERS = 2


def read_ahead(
    read: Callable[[int], T],
    indices: Iterable[int],
    *,
    ahead: int = READ_AHEAD,
    workers: int = READ_WORKERS,
) -> Iterator[tuple[int, Future]]:
    """Read items ahead of their use on a thread pool, handing them out in order.

    Example::

        with contextlib.closing(read_ahead(seq.__getitem__, range(len(seq)))) as reads:
            for i, frame in reads:
                try:
                    frame = frame.result()   # the frame, or the error seq[i] raised
                except InputError:
                    ...                       # drop it and go on

    Args:
      read: ``read(index)`` returns the item (e.g. ``seq.__getitem__``); it is called from
        the pool's threads, so it must be safe to call from several threads at once.
      indices: the indices, in the order they are wanted.
      ahead: items read beyond the one handed out last; 0 reads each on the calling thread
        when it is handed out (no thread).
      workers: threads reading.
    Returns:
      an iterator of ``(index, future)`` in the order of ``indices``; ``future.result()``
      returns ``read(index)`` or raises what it raised. Closing the iterator (or dropping
      it) cancels the reads not yet started.
    """
    indices = iter(indices)
    if ahead <= 0 or workers <= 0:
        for i in indices:
            yield i, _call_now(read, i)
        return
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="jaxvo-read")
    pending: deque[tuple[int, Future]] = deque()
    try:
        while True:
            # keep `ahead` reads going beyond the item handed out next
            while len(pending) <= ahead:
                i = next(indices, None)
                if i is None:
                    break
                pending.append((i, pool.submit(read, i)))
            if not pending:
                return
            yield pending.popleft()
    finally:
        for _, fut in pending:
            fut.cancel()
        # reads already started finish on their own (a few ms); nothing waits for them
        pool.shutdown(wait=False, cancel_futures=True)


def _call_now(fn: Callable[[int], T], i: int) -> Future:
    """A finished future holding ``fn(i)`` or the exception it raised."""
    fut: Future = Future()
    try:
        fut.set_result(fn(i))
    except Exception as exc:  # noqa: BLE001 (handed to the caller through the future)
        fut.set_exception(exc)
    return fut


class BackgroundWriter:
    """Runs output calls (encode and write an image) on one thread, in order, behind the caller.

    :meth:`submit` returns at once unless ``limit`` calls are already waiting; then it waits
    for room, so a disk slower than the frames bounds memory instead of filling it. A call
    that raises stops the writing: the calls after it are dropped and its exception is
    raised again by the next :meth:`submit` or by :meth:`close` (e.g. ``OSError`` for a full
    disk, which the CLI reports as one line).

    :meth:`close` (or leaving the ``with`` block, also by an exception or Ctrl-C) waits until
    every call submitted has run, so an interrupted run keeps every image it computed.

    Args:
      limit: calls waiting at most.
    """

    def __init__(self, *, limit: int = 8):
        self._queue: queue.Queue = queue.Queue(maxsize=max(int(limit), 1))
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._work, name="jaxvo-write", daemon=True)
        self._thread.start()
        self._closed = False

    def submit(self, fn: Callable[..., object], *args) -> None:
        """Queue ``fn(*args)``; it runs after every call submitted before it.

        Raises:
          the exception an earlier call raised; ``RuntimeError`` after :meth:`close`.
        """
        if self._closed:
            raise RuntimeError("BackgroundWriter.submit after close")
        self._raise_error()
        self._queue.put((fn, args))

    def close(self) -> None:
        """Wait until every submitted call has run, then stop the thread.

        Raises:
          the exception a call raised, if one did and it was not raised yet.
        """
        if not self._closed:
            self._closed = True
            self._queue.put(None)
            self._thread.join()
        self._raise_error()

    def _raise_error(self) -> None:
        error, self._error = self._error, None
        if error is not None:
            raise error

    def _work(self) -> None:
        failed = False
        while (item := self._queue.get()) is not None:
            if failed:
                continue  # drain what was queued behind the failure, so submit never blocks
            fn, args = item
            try:
                fn(*args)
            except BaseException as exc:  # noqa: BLE001 (raised again on the caller's thread)
                self._error, failed = exc, True

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
            return
        # the images computed so far are still written; the exception under way wins
        with contextlib.suppress(Exception):
            self.close()

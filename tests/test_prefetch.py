"""Reading ahead and writing behind: order, errors in place, bounds, and nothing lost when
the work is interrupted."""

import threading
import time

import numpy as np
import pytest

from jaxvo.errors import InputError
from jaxvo.host.frontend.prefetch import BackgroundWriter, read_ahead


class SlowReader:
    """``read(i)``: returns ``10 * i`` after a random pause (so reads finish out of order),
    raises InputError for indices in ``bad``; counts the reads started."""

    def __init__(self, bad=(), seed=0):
        self.bad = set(bad)
        self.pauses = np.random.default_rng(seed).uniform(0, 0.01, 1000)
        self.started = 0
        self.threads = set()
        self.lock = threading.Lock()

    def __call__(self, i):
        with self.lock:
            self.started += 1
            self.threads.add(threading.get_ident())
        time.sleep(self.pauses[i])
        if i in self.bad:
            raise InputError(f"cannot read frame {i}")
        return 10 * i


def outcomes(reads):
    """``[(index, value or 'error message')]`` as a caller handling errors in place sees them."""
    seen = []
    for i, fut in reads:
        try:
            seen.append((i, fut.result()))
        except InputError as exc:
            seen.append((i, str(exc)))
    return seen


@pytest.mark.parametrize("ahead, workers", [(0, 2), (1, 1), (4, 2), (6, 3)])
def test_items_come_in_order_with_each_error_in_its_place(ahead, workers):
    indices = [3, 0, 7, 1, 2, 9, 4, 8, 5, 6]
    reader = SlowReader(bad=(7, 2, 6))
    got = outcomes(read_ahead(reader, indices, ahead=ahead, workers=workers))
    expected = [(i, f"cannot read frame {i}" if i in (7, 2, 6) else 10 * i) for i in indices]
    assert got == expected
    assert reader.started == len(indices)  # each read exactly once


def test_no_thread_without_read_ahead():
    reader = SlowReader()
    assert outcomes(read_ahead(reader, range(5), ahead=0)) == [(i, 10 * i) for i in range(5)]
    assert reader.threads == {threading.get_ident()}


def test_reading_runs_at_most_ahead_items_beyond_the_one_in_use():
    reader, ahead = SlowReader(), 3
    consumed = 0
    for _, fut in read_ahead(reader, range(40), ahead=ahead, workers=2):
        fut.result()
        consumed += 1
        time.sleep(0.005)  # a consumer slower than the readers: they must wait for it
        assert reader.started <= consumed + ahead
    assert consumed == 40


def test_closing_the_reader_stops_reading():
    reader, ahead = SlowReader(), 3
    reads = read_ahead(reader, range(200), ahead=ahead, workers=2)
    for k, (_, fut) in enumerate(reads):
        fut.result()
        if k == 1:
            break
    reads.close()
    time.sleep(0.05)  # reads already started may finish; none may start
    assert reader.started <= 2 + ahead


def test_the_writer_runs_every_call_in_order_and_close_waits_for_them():
    done = []

    def slow_append(x):
        time.sleep(0.002)
        done.append(x)

    with BackgroundWriter(limit=3) as w:
        for k in range(30):
            w.submit(slow_append, k)
        assert len(done) < 30  # the calls run behind the caller...
    assert done == list(range(30))  # ...and leaving the block waited for every one


def test_an_interrupted_run_still_writes_everything_submitted():
    done = []
    with pytest.raises(KeyboardInterrupt), BackgroundWriter() as w:
        for k in range(5):
            w.submit(lambda k=k: (time.sleep(0.01), done.append(k)))
        raise KeyboardInterrupt
    assert done == list(range(5))


def test_a_failed_write_is_raised_on_the_callers_thread_and_stops_the_rest():
    done = []
    gate = threading.Event()

    def fail():
        raise OSError(28, "No space left on device")

    w = BackgroundWriter(limit=8)
    w.submit(gate.wait)
    w.submit(fail)
    w.submit(done.append, 1)  # queued behind the failure: dropped
    gate.set()
    with pytest.raises(OSError, match="No space left"):
        w.close()
    assert done == []
    with pytest.raises(RuntimeError):
        w.submit(done.append, 2)

    w = BackgroundWriter()
    w.submit(fail)
    time.sleep(0.05)
    with pytest.raises(OSError):  # the next submit says so, before the run goes on
        w.submit(done.append, 3)
    w.close()


def test_submit_waits_for_room_when_the_queue_is_full():
    gate = threading.Event()
    w = BackgroundWriter(limit=1)
    w.submit(gate.wait)  # running, blocked
    w.submit(lambda: None)  # waiting: the queue is full now
    third = threading.Thread(target=w.submit, args=(lambda: None,))
    third.start()
    third.join(0.2)
    assert third.is_alive()  # held back while the disk is "slow"
    gate.set()
    third.join(5)
    assert not third.is_alive()
    w.close()

"""The fork pool (pipeline.core.parallel): the workers see the shared work without pickling it, and the
results are the one-process results in order."""

import threading

import pytest

from pipeline.core import parallel

pytestmark = pytest.mark.skipif(not parallel.can_fork(), reason="forked workers: Linux only")


def _square_plus(shared, k):
    lock, offset = shared          # a lock cannot be pickled: the workers inherit it
    with lock:
        return k * k + offset


def test_fork_map_is_the_serial_map_with_unpicklable_shared_work():
    shared = (threading.Lock(), 7)
    assert parallel.fork_map(_square_plus, shared, 9, jobs=2) == [_square_plus(shared, k) for k in range(9)]
    assert parallel._SHARED is None


def test_fork_imap_yields_in_order_and_async_waits_for_all():
    shared = (threading.Lock(), 1)
    assert list(parallel.fork_imap(_square_plus, shared, 6, jobs=2, chunksize=4)) == [1, 2, 5, 10, 17, 26]
    result = parallel.fork_map_async(_square_plus, shared, 5, jobs=2)
    assert parallel._SHARED is None            # the workers forked already: the caller goes on
    assert result() == [1, 2, 5, 10, 17]


def _send_back(shared):
    send, value = shared
    send.send(value * 2)
    send.close()


def test_fork_process_runs_beside_and_sends_back():
    receive, send = parallel.pipe()
    proc = parallel.fork_process(_send_back, (send, 21))
    send.close()
    assert receive.recv() == 42
    proc.join()
    assert proc.exitcode == 0


def test_a_worker_cannot_fork_again():
    assert parallel.fork_map(lambda shared, k: parallel.can_fork(), None, 2, jobs=2) == [False, False]

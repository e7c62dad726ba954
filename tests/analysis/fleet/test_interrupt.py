"""The quiet Ctrl-C of a local fleet (analysis/fleet/interrupt.py): what it changes and gives back.
The end-to-end check (a real Ctrl-C to the process group) is tests/analysis/fleet/test_fleet.py."""
import logging
import threading

from dynid.analysis.fleet import interrupt


class _Nanny:
    pid = None

    def __init__(self):
        self.told = False

    def close_gracefully(self):
        self.told = True


class _Cluster:
    def __init__(self):
        self.workers = {"a": _Nanny(), "b": _Nanny()}


def test_teardown_quietens_dasks_loggers_and_gives_their_levels_back():
    child = logging.getLogger("tornado.application")
    child.setLevel(logging.ERROR)               # Dask's configuration gives it a level of its own
    other = logging.getLogger("dynid")
    level_other = other.level
    cluster, former = _Cluster(), {}
    interrupt.stop_after_interrupt(cluster, former)
    try:
        assert child.level == logging.CRITICAL and logging.getLogger("distributed").level == logging.CRITICAL
        assert other.level == level_other                          # not Dask's: untouched
        assert all(n.told for n in cluster.workers.values())      # no nanny restarts its worker
    finally:
        interrupt.restore_logs(former)
    assert child.level == logging.ERROR


def test_not_available_off_the_main_thread():
    seen = []
    t = threading.Thread(target=lambda: seen.append(interrupt.available()))
    t.start()
    t.join()
    assert seen == [False]

"""dynid.threads: one BLAS thread inside, the user's setting outside and when they chose one."""
import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")

from dynid.threads import single_blas_thread, with_single_blas_thread  # noqa: E402


def blas_threads():
    import scipy.linalg  # noqa: F401  (its own OpenBLAS, beside numpy's)
    return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]


def test_one_thread_inside_and_restored_after(monkeypatch):
    for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
              "DYNID_BLAS_THREADS"):
        monkeypatch.delenv(v, raising=False)
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        with single_blas_thread():
            assert blas_threads() and all(n == 1 for n in blas_threads())
        assert blas_threads() == before

        @with_single_blas_thread
        def inside():
            return blas_threads()
        assert all(n == 1 for n in inside())
        assert blas_threads() == before


def test_the_users_choice_is_kept(monkeypatch):
    monkeypatch.setenv("DYNID_BLAS_THREADS", "0")
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        with single_blas_thread():
            assert blas_threads() == before


def test_the_public_functions_run_with_one_blas_thread(monkeypatch):
    """`dynid.identify` (resolved on first use) and `dynid.diagnose` run as the command line does."""
    import dynid
    import dynid.analysis.diagnosis.selection as selection
    import dynid.analysis.identify as identify_module
    for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
              "DYNID_BLAS_THREADS"):
        monkeypatch.delenv(v, raising=False)
    seen = []
    monkeypatch.setattr(identify_module, "identify", lambda *a, **k: seen.append(blas_threads()))
    monkeypatch.setattr(selection, "diagnose", lambda *a, **k: seen.append(blas_threads()))
    monkeypatch.setattr(identify_module, "as_robot", lambda r: r)
    monkeypatch.setattr(identify_module, "as_experiments", lambda d, r: [d])
    cached = dynid.__dict__.pop("identify", None)
    try:
        with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
            before = blas_threads()
            dynid.identify("data", "robot")
            dynid.diagnose("data", "robot")
            assert blas_threads() == before
    finally:
        dynid.__dict__.pop("identify", None)
        if cached is not None:
            dynid.__dict__["identify"] = cached
    assert len(seen) == 2 and all(n == 1 for threads in seen for n in threads)

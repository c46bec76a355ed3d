"""DebouncedJob, the background machinery of the live metrics and the heat map: edits in a
burst give one computation on the newest state, a result overtaken by a newer request is
never shown, a failure is a message, and a closed job takes no more work."""

from __future__ import annotations

import threading

import pytest

from sweepedit.app.background import DebouncedJob

pytestmark = pytest.mark.gui


class _Recorder:
    """compute() for a DebouncedJob: records what it was given and in which thread; holds
    on while `gate` is clear, so a test can edit during a computation."""

    def __init__(self) -> None:
        self.payloads: list[object] = []
        self.threads: set[str] = set()
        self.gate = threading.Event()
        self.gate.set()
        self.started = threading.Event()

    def __call__(self, payload: object) -> object:
        self.payloads.append(payload)
        self.threads.add(threading.current_thread().name)
        self.started.set()
        self.gate.wait(10)
        if payload == "broken":
            raise ValueError("no such thing")
        return ("result", payload)


def _job(compute, delay_ms: int = 50) -> tuple[DebouncedJob, list, list, list]:
    job = DebouncedJob(compute, delay_ms, "test-job")
    finished, failed, busy = [], [], []
    job.finished.connect(finished.append)
    job.failed.connect(failed.append)
    job.busy.connect(busy.append)
    return job, finished, failed, busy


def test_a_burst_of_edits_is_one_computation_of_the_newest_state(qtbot) -> None:
    compute = _Recorder()
    job, finished, failed, busy = _job(compute)
    try:
        for i in range(10):
            job.request(lambda i=i: i)
            qtbot.wait(5)
        assert job.running
        qtbot.waitUntil(lambda: not job.running, timeout=5000)
        assert compute.payloads == [9] and finished == [("result", 9)] and failed == []
        assert busy == [True, False]
        assert threading.current_thread().name not in compute.threads
    finally:
        job.shutdown()


def test_a_result_overtaken_by_an_edit_is_not_shown(qtbot) -> None:
    compute = _Recorder()
    job, finished, failed, _ = _job(compute, delay_ms=10)
    try:
        compute.gate.clear()
        job.request(lambda: "old", delay=False)
        assert compute.started.wait(5)
        job.request(lambda: "new")  # while "old" is being computed
        qtbot.wait(50)
        compute.gate.set()
        qtbot.waitUntil(lambda: not job.running, timeout=5000)
        # "old" ran to its end, unreported; "new" ran after it and is what is shown.
        assert compute.payloads == ["old", "new"] and finished == [("result", "new")]
        assert failed == []
    finally:
        job.shutdown()


def test_a_failure_is_one_message_and_the_job_goes_on(qtbot) -> None:
    compute = _Recorder()
    job, finished, failed, _ = _job(compute)
    try:
        job.request(lambda: "broken", delay=False)
        qtbot.waitUntil(lambda: not job.running, timeout=5000)
        assert failed == ["ValueError: no such thing"] and finished == []
        job.request(lambda: "fine", delay=False)
        qtbot.waitUntil(lambda: not job.running, timeout=5000)
        assert finished == [("result", "fine")]
    finally:
        job.shutdown()


def test_cancel_and_shutdown_drop_pending_work(qtbot) -> None:
    compute = _Recorder()
    job, finished, _, _ = _job(compute, delay_ms=100)
    job.request(lambda: "dropped")
    job.cancel()
    assert not job.running
    qtbot.wait(250)
    assert compute.payloads == [] and finished == []
    job.shutdown()
    job.request(lambda: "after", delay=False)
    qtbot.wait(100)
    assert compute.payloads == [] and not job.running


def test_the_gui_thread_gets_the_gil_back_within_half_a_millisecond(window) -> None:
    """The window shortens Python's switch interval (5 ms), which the GUI thread would
    otherwise wait after every call that released the GIL beside a busy worker thread."""
    import sys

    from sweepedit.app.worker import GUI_SWITCH_INTERVAL_S, favour_gui_thread

    assert GUI_SWITCH_INTERVAL_S <= 0.001
    assert sys.getswitchinterval() == pytest.approx(GUI_SWITCH_INTERVAL_S, rel=0.05)
    before = sys.getswitchinterval()
    try:
        sys.setswitchinterval(0.0001)  # someone chose a shorter one: it is kept
        favour_gui_thread()
        assert sys.getswitchinterval() == pytest.approx(0.0001, rel=0.05)
        sys.setswitchinterval(0.005)
        favour_gui_thread()
        assert sys.getswitchinterval() == pytest.approx(GUI_SWITCH_INTERVAL_S, rel=0.05)
    finally:
        sys.setswitchinterval(before)

"""The one process pool: independent calls (the files of a batch, the cases of an experiment, the
later windows of a long recording) in this process, in worker processes, or as Ray tasks, their
results yielded as they finish.

Workers are fresh interpreters (``spawn``) started with ``threads`` BLAS/OpenMP threads each and
blind to a terminal's ^C. They do not run the caller's ``__main__`` again (a script that fills a
long recording without an ``if __name__ == "__main__"`` guard is not re-run in each worker): the
calls are functions of importable modules. Calls and results travel pickled by value (a tensor's
bytes, never a shared-memory handle); a call may send messages back while it runs (:func:`report`). A worker that dies (SIGKILL, as the out-of-memory killer sends) costs
only its call: the call is tried once more in a new worker, then handed to ``died``, and the rest
go on. Closing the generator (or an exception in it: Ctrl-C) stops at once: queued calls are not
started, running ones get SIGTERM (their writes finish or roll back), and no worker is left.
"""
from __future__ import annotations

import multiprocessing
import os
import pickle
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

#: seconds a stopped worker gets to finish a write before it is killed
STOP_GRACE = 1.5
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
_CALL: dict = {"conn": None, "index": None, "lock": threading.Lock()}   # in a worker: the call


def imap(func: Callable, args: list[tuple], kwargs: list[dict] | None = None, *,
         workers: int = 1, ray_address: str | None = None, threads: int = 1,
         died: Callable[[int, str], Any] | None = None,
         retried: Callable[[int, Any, str], Any] | None = None,
         cleanup: Callable[[int], None] | None = None) -> Iterator[tuple[int, Any]]:
    """``(i, func(*args[i], **kwargs[i]))`` for every call, in the order the calls finish.

    ``workers``: worker processes (1: in this process); ``ray_address``: Ray tasks of one CPU
    each instead (``"auto"``, ``"local"`` or a cluster address; ``pip install torchfill[ray]``).
    ``died(i, how)``: the result of a call whose worker died twice (None: nothing is yielded);
    ``retried(i, result, how)``: the result of a call that succeeded after its first worker
    died (default: as it is); ``cleanup(i)``: undo what a call that did not finish may have left (its outputs)."""
    kwargs = kwargs or [{}] * len(args)
    if ray_address is not None:
        yield from _ray(func, args, kwargs, ray_address)
    elif workers <= 1 or len(args) <= 1:
        for i, (a, k) in enumerate(zip(args, kwargs)):
            yield i, func(*a, **k)
    else:
        pool = Processes(func, min(workers, len(args)), threads, died=died, cleanup=cleanup,
                         retried=retried)
        try:
            yield from pool.run(list(zip(args, kwargs)))
        finally:
            pool.close()


def _ray(func, args, kwargs, address: str) -> Iterator[tuple[int, Any]]:
    """The calls as Ray tasks. Connects to ``address`` unless Ray is already initialized in this
    process: ``"local"`` always starts a new Ray here (``ray.init(address=None)`` would instead
    join a cluster named by ``RAY_ADDRESS`` or left by ``ray start``), ``"auto"`` joins the
    running one."""
    try:
        import ray
    except ImportError:
        raise ValueError("--ray needs Ray: pip install 'torchfill[ray]'") from None
    started = not ray.is_initialized()
    if started:
        ray.init(address=address, log_to_driver=False)
    remote = ray.remote(num_cpus=1)(_call)
    pending = [remote.remote(i, func, a, k) for i, (a, k) in enumerate(zip(args, kwargs))]
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
    finally:
        if started:
            ray.shutdown()


def _call(i: int, func, a: tuple, k: dict) -> tuple[int, Any]:
    return i, func(*a, **k)


def report(message: Any) -> bool:
    """Inside a call that a worker process runs: send ``message`` to the caller's ``report``
    (see :meth:`Processes.run`); elsewhere nothing. Whether it was sent."""
    with _CALL["lock"]:                       # any thread of the call may report
        if _CALL["conn"] is None:
            return False
        _CALL["conn"].send_bytes(pickle.dumps(("report", _CALL["index"], message),
                                              pickle.HIGHEST_PROTOCOL))
    return True


class Processes:
    """``n`` worker processes fed one call at a time through a pipe each: :meth:`launch` starts
    them (they import in the background; a thread may launch them), :meth:`run` feeds them,
    :meth:`close` ends every one (:func:`imap` does all three)."""

    def __init__(self, func, n: int, threads: int, *, died=None, cleanup=None,
                 retried=None) -> None:
        self.func, self.n, self.threads = func, n, threads
        self.died, self.cleanup = died, cleanup or (lambda i: None)
        self.retried = retried or (lambda i, result, how: result)
        self.ctx = multiprocessing.get_context("spawn")
        self.lock = threading.Lock()
        self.closed = False
        self.idle: list[tuple] = []
        self.busy: dict[int, tuple] = {}            # pid -> (process, conn, index, attempt)
        self.started: list[tuple] = []              # every worker, whatever its state
        self.first_death: dict[int, str] = {}

    def start(self) -> tuple:
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()     # first: starting it unblocks SIGINT (_no_sigint)
        parent, child = self.ctx.Pipe()
        with _THREADS_ENV, _threads_env(self.threads), _no_sigint(), _no_main():
            proc = self.ctx.Process(target=_worker, args=(child, self.func), daemon=True)
            proc.start()
        child.close()
        self.started.append((proc, parent))
        return proc, parent

    def launch(self) -> None:
        """Start the workers not started yet (none once closed)."""
        with self.lock:
            while not self.closed and len(self.started) < self.n:
                self.idle.append(self.start())

    def run(self, calls, report: Callable[[int, Any], Any] | None = None
            ) -> Iterator[tuple[int, Any]]:
        """``(i, func(*a, **k))`` for ``(a, k) = calls[i]``, as they finish; ``calls`` is read
        when a call is handed out (it may build its arguments then). ``report(i, message)``
        receives what call ``i`` sends with :func:`report`. Closing the generator ends the
        workers (as :meth:`close`)."""
        queue = deque((i, 1) for i in range(len(calls)))
        self.report = report or (lambda i, message: None)
        try:
            self.launch()
            while queue or self.busy:
                self._hand_out(queue, calls)
                yield from self._collect(queue)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """End every worker (see :func:`_stop`); the calls under way are cleaned up."""
        with self.lock:
            self.closed = True
        # a worker handed a call a moment ago may be in neither list: all go
        _stop([w for w in self.started if w not in self.idle], self.idle)
        self.started, self.idle = [], []
        for proc, conn, i, attempt in self.busy.values():
            self.cleanup(i)
        self.busy = {}

    def _hand_out(self, queue: deque, calls: list[tuple]) -> None:
        while queue and self.idle:
            proc, conn = self.idle.pop()
            i, attempt = queue.popleft()
            try:
                conn.send_bytes(pickle.dumps((i, *calls[i]), pickle.HIGHEST_PROTOCOL))
            except OSError:                         # died while idle: replace it
                proc.join()
                queue.appendleft((i, attempt))
                self.idle.append(self.start())
                continue
            self.busy[proc.pid] = (proc, conn, i, attempt)

    def _collect(self, queue: deque) -> Iterator[tuple[int, Any]]:
        from multiprocessing.connection import wait

        handles = [h for proc, conn, *_ in self.busy.values() for h in (conn, proc.sentinel)]
        ready = set(wait(handles))
        for pid in list(self.busy):
            proc, conn, i, attempt = self.busy[pid]
            if conn not in ready and proc.sentinel not in ready:
                continue
            try:
                reply = pickle.loads(conn.recv_bytes()) if conn in ready else None
            except (EOFError, OSError):
                reply = None
            if reply is not None and reply[0] == "report":
                self.report(i, reply[2])
                continue
            del self.busy[pid]
            if reply is not None:
                self.idle.append((proc, conn))
                result = reply[2]
                if i in self.first_death:
                    result = self.retried(i, result, self.first_death[i])
                yield i, result
                continue
            if proc.is_alive():                     # its pipe broke: make sure it is gone
                proc.kill()
            proc.join()
            conn.close()
            self.first_death.setdefault(i, death(proc.exitcode))
            self.cleanup(i)
            if attempt < 2:
                queue.appendleft((i, attempt + 1))
            if queue and len(self.idle) + len(self.busy) < self.n:
                self.idle.append(self.start())
            if attempt >= 2 and self.died is not None:
                result = self.died(i, death(proc.exitcode))
                if result is not None:
                    yield i, result


def _stop(running: list[tuple], idle: list[tuple]) -> None:
    """End every worker: idle ones are told to leave, running ones get SIGTERM (a write in
    progress finishes or rolls back), whatever is left after ``STOP_GRACE`` seconds is killed."""
    for proc, conn in idle:
        try:
            conn.send_bytes(pickle.dumps(None))
        except OSError:
            pass
    for proc, conn in running:
        if proc.exitcode is None:
            proc.terminate()
    deadline = time.monotonic() + STOP_GRACE
    everyone = running + idle
    for proc, conn in everyone:
        if proc.exitcode is None:
            proc.join(max(0.0, deadline - time.monotonic()))
    for proc, conn in everyone:
        if proc.exitcode is None:
            proc.kill()
            proc.join()
        try:
            conn.close()
        except OSError:
            pass


def death(code) -> str:
    """How a worker ended, from its exit code."""
    if code is None:
        return "no reply"
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"killed by {name}" + (", out of memory?" if name == "SIGKILL" else "")
    return f"exit status {code}"


def _worker(conn, func) -> None:
    """A worker process: run the calls it is sent until told to stop (None or SIGTERM)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def on_term(signum, frame):
        raise SystemExit(128 + signum)               # unwinds: temporary files are removed
    signal.signal(signal.SIGTERM, on_term)
    try:
        while True:
            try:
                call = pickle.loads(conn.recv_bytes())
            except (EOFError, OSError):
                return
            if call is None:
                return
            i, a, k = call
            with _CALL["lock"]:
                _CALL.update(conn=conn, index=i)
            result = func(*a, **k)
            with _CALL["lock"]:
                _CALL["conn"] = None
            try:
                conn.send_bytes(pickle.dumps(("done", i, result), pickle.HIGHEST_PROTOCOL))
            except OSError:
                return
    except SystemExit as stop:        # unwound (temporary files removed): skip the slow teardown
        os._exit(stop.code if isinstance(stop.code, int) else 1)


@contextmanager
def _no_sigint():
    """Block SIGINT in this thread while a worker starts: the worker inherits the blocked signal
    (and then ignores it), so it never sees a terminal's ^C; a ^C that arrives meanwhile waits
    and reaches this process once the worker has started, or at once in another thread that
    does not block it (ignoring it here instead lost it: a batch ran on)."""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


_THREADS_ENV = threading.Lock()         # one worker start at a time changes the environment
_STARTING = threading.local()           # this thread starts a worker (see _no_main)
_PATCH = threading.Lock()


@contextmanager
def _no_main():
    """Leave ``__main__`` out of what a worker started in this thread prepares from (see the
    module notes): multiprocessing's spawn would otherwise run the caller's script in the worker
    (as ``__mp_main__``) before the first call. Other threads' processes are left alone."""
    from multiprocessing import spawn

    with _PATCH:
        if not getattr(spawn.get_preparation_data, "_torchfill", False):
            real = spawn.get_preparation_data

            def preparation_data(name):
                data = real(name)
                if getattr(_STARTING, "active", False):
                    data.pop("init_main_from_path", None)
                    data.pop("init_main_from_name", None)
                return data
            preparation_data._torchfill = True
            spawn.get_preparation_data = preparation_data
    _STARTING.active = True
    try:
        yield
    finally:
        _STARTING.active = False


@contextmanager
def _threads_env(threads: int):
    """The BLAS/OpenMP thread variables set to ``threads`` for processes started inside (read
    when a worker starts), then restored."""
    saved = {k: os.environ.get(k) for k in THREAD_VARS}
    os.environ.update({k: str(threads) for k in THREAD_VARS})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

"""Clean interrupts: SIGINT/SIGTERM end a command with one line, exit 130/143, no partial output.

Python runs signal handlers only between bytecodes of the main thread, which
may be inside a long native call (an XLA computation, a LibRaw decode) for
seconds; raising ``KeyboardInterrupt`` there unwinds through JAX and emcee
threads, prints tracebacks and can crash the interpreter at teardown. So
the handler is a watcher thread instead: the C-level signal handler writes
the signal number to a socket (``signal.set_wakeup_fd``), the thread wakes at
once, removes the temporaries of atomic writes in flight
(:func:`jkatana.io.atomic.remove_live`), terminates child processes (decoding
pools, Dask workers), prints one line and leaves with ``os._exit`` (128 +
the signal number, the shell's convention) without running interpreter
teardown. Finished outputs are complete files (atomic renames), so nothing
partial remains. Meanwhile the main thread, should it finish or fail first,
waits (:func:`hold_if_exiting`) and the process's output is closed after the
one line, so no traceback follows it.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import threading

_INSTALLED = False
_SOCKETS: tuple = ()  # the wakeup socket pair, kept open for the process's life


def _children_terminate() -> None:
    try:
        import psutil
    except ImportError:  # pragma: no cover
        return
    try:
        kids = psutil.Process().children(recursive=True)
    except psutil.Error:
        return
    for k in kids:
        try:
            k.terminate()
        except psutil.Error:
            pass
    _, alive = psutil.wait_procs(kids, timeout=2.0)
    for k in alive:
        try:
            k.kill()
        except psutil.Error:
            pass


_EXITING = threading.Event()


def _silence() -> None:
    """Point this process's stdout and stderr at /dev/null: after the one line, nothing else is
    printed while the exit proceeds (the main thread may still be running, e.g. seeing its decoding
    pool vanish)."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        for fd in (1, 2):
            os.dup2(null, fd)
    except OSError:
        pass


def _exit_on(signum: int, command: str) -> None:
    from jkatana.io.atomic import remove_live

    _EXITING.set()
    remove_live()
    name = signal.Signals(signum).name
    try:
        sys.stdout.flush()
        sys.stderr.write(f"\njkatana {command}: interrupted ({name}); nothing partial was written\n")
        sys.stderr.flush()
    except Exception:  # noqa: BLE001 - stderr may be closed; the exit status still tells
        pass
    _silence()
    _children_terminate()
    remove_live()
    os._exit(128 + signum)


def hold_if_exiting() -> None:
    """In the main thread: if an interrupt is being handled, wait for its exit instead of returning
    (or unwinding into a traceback, or starting interpreter teardown under running threads)."""
    import time

    while _EXITING.is_set():
        time.sleep(0.1)


def install(command: str) -> None:
    """Route SIGINT and SIGTERM of this (main-thread) process to the clean exit; idempotent."""
    global _INSTALLED, _SOCKETS
    if _INSTALLED or threading.current_thread() is not threading.main_thread():
        return
    rsock, wsock = socket.socketpair()
    wsock.setblocking(False)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: None)  # a Python handler keeps the C handler (and the wakeup fd) active
    signal.set_wakeup_fd(wsock.fileno(), warn_on_full_buffer=False)

    def watch():
        while True:
            data = rsock.recv(1)
            if data and data[0] in (signal.SIGINT, signal.SIGTERM):
                _exit_on(data[0], command)

    threading.Thread(target=watch, name="jkatana-interrupt", daemon=True).start()
    _INSTALLED = True
    _SOCKETS = (rsock, wsock)


__all__ = ["install", "hold_if_exiting"]

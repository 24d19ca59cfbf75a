"""A service process's own facts: its id at each start, how it waits for its launcher to exit, and the exit code
that ends the run instead of a restart."""

from __future__ import annotations

import os
import threading
import time
import uuid


# The exit code of a service stopped by an error that a restart would only repeat (a teacher rule that raises, an
# env info key a Step cannot carry): the launcher ends the run with the error instead of restarting the service.
TERMINAL_EXIT = 78


class TerminalError(Exception):
    """An error that stops the run: its message (one line, naming what failed) is the run's error."""


def set_from_handler(event: threading.Event) -> None:
    """Set `event` from a signal handler. Not directly: a handler that interrupted `event.wait()` in the same
    thread would deadlock on the Event's internal lock; a helper thread takes it once the waiter lets go."""
    threading.Thread(target=event.set, name="signal-set", daemon=True).start()


def wait_for_exit(pid: int) -> None:
    """Return once process `pid` has exited. Sleeps in the kernel on a pidfd (readable when the process ends), so
    a service waiting on its launcher never wakes while it lives; where pidfds are missing (Linux < 5.3), it
    looks every 0.5 s instead."""
    import select

    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return
    except (AttributeError, OSError):
        fd = None
    if fd is not None:
        try:
            poller = select.poll()
            poller.register(fd, select.POLLIN)
            while not poller.poll():  # (an empty answer only after EINTR)
                pass
        finally:
            os.close(fd)
        return
    while True:
        time.sleep(0.5)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        except PermissionError:
            continue


def new_incarnation(service: str) -> str:
    """A process's own id, new at every start (Step.incarnation, Weights.incarnation, Ingest.learner)."""
    return f"{service}-{os.getpid()}-{uuid.uuid4().hex[:8]}"

"""Process-level settings every service applies once it has started.

:func:`freeze_startup_heap` moves everything alive after start-up (modules, models, the corridor, the
service's own tables) into Python's permanent generation (``gc.freeze``), so the cyclic garbage collector's
full collections scan only what the service allocated since. A full collection of a started service's heap
paused it 31-33 ms (``bench/fuzz_bench.py``), longer than the 50 ms budget for one input allows
once the input's own work is added; frozen, the pause is that of the service's recent objects only. Objects
frozen this way are never collected, which is right for what a service keeps until it exits.
"""

from __future__ import annotations

import gc


def freeze_startup_heap() -> int:
    """Collect, then freeze every surviving object (``gc.freeze``); the number of objects frozen."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def stop_on_ctrl_c() -> None:
    """Make SIGINT raise KeyboardInterrupt in this process even when it started with SIGINT ignored.

    A process started from a background job of a non-interactive shell (``make test &``, a CI step, ``nohup``)
    inherits SIGINT *ignored*, and Python then installs no KeyboardInterrupt handler: a supervisor's SIGINT
    (``iea up`` stopping its services, a test stopping ``iea up``) was silently dropped and the process lived
    on until SIGKILL. Every CLI that stops on KeyboardInterrupt calls this first.
    """
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():  # only the main thread may set handlers
        signal.signal(signal.SIGINT, signal.default_int_handler)

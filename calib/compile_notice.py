"""Say so when numba compiles: never a silent minute on a command's first run after an install.

numba compiles a kernel on its first call and caches the machine code beside the source (`cache=True`),
so only the first run after an install (or after a kernel's source changed) pays for it. numba calls
`init` on its first use in a process (the `numba_extensions` entry point in pyproject.toml); `init`
listens to numba's compile events, which fire on cache misses only, and writes one line to stderr for
the first kernel of each module it compiles (kernels called from a kernel, and numba's own overloads,
compile inside their caller and are not counted) and, when the process ends, the total time spent.
"""

from __future__ import annotations

import atexit
import sys
import threading
import time

_lock = threading.Lock()
_modules: set[str] = set()
_depth = 0
_started = 0.0
_total = {"seconds": 0.0, "kernels": 0}


def init() -> None:
    """Register the listener (numba's extension entry point; numba calls it once per process)."""
    from numba.core import event

    class Notice(event.Listener):
        def on_start(self, ev):
            global _depth, _started
            with _lock:
                outermost = _depth == 0
                _depth += 1
                if not outermost:   # numba's own overloads, compiled inside the kernel that uses them
                    return
                _started = time.perf_counter()
                module = getattr(ev.data["dispatcher"].py_func, "__module__", "?")
                _total["kernels"] += 1
                first = module not in _modules
                _modules.add(module)
                if first and len(_modules) == 1:
                    atexit.register(_summary)
            if first:
                print(f"stereodic: compiling the numba kernels of {module} (once after an install; later "
                      "runs load them from the cache)", file=sys.stderr, flush=True)

        def on_end(self, ev):
            global _depth
            with _lock:
                _depth -= 1
                if _depth == 0:
                    _total["seconds"] += time.perf_counter() - _started

    event.register("numba:compile", Notice())


def _summary() -> None:
    k, m = _total["kernels"], len(_modules)
    print(f"stereodic: compiled {k} numba kernel{'s' * (k != 1)} of {m} module{'s' * (m != 1)} in "
          f"{_total['seconds']:.0f} s; they are cached now", file=sys.stderr, flush=True)

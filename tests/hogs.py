"""Bounded CPU hogs: the busy lab PC of issue 30 (a report, a second analysis, a browser beside the recording).

``Hogs(n)`` starts ``n`` processes that each burn a core — ``while True: pass`` (kind ``"spin"``) or a numpy
matrix product in a loop (kind ``"matmul"``: memory traffic too, one BLAS thread each) — at the *same*
scheduling priority as the recorder: they are not niced, because a lab PC's other programs are not either.

Bounded three ways, so a crashed test cannot leave them running: each hog ends itself at a wall-clock deadline
(``limit_s``), carries a CPU-time rlimit a little above it (the kernel kills it with SIGXCPU/SIGKILL), and asks
the kernel to SIGKILL it when the process that started it dies (Linux ``PR_SET_PDEATHSIG``). ``stop()`` (a
fixture's finaliser, or leaving the ``with`` block) kills them by pid.

While they run, a sampler thread reads ``/proc/loadavg`` twice a second: the instantaneous number of runnable
tasks (its 4th field) and the 1-minute load average, so a result can say what load it was measured at (the
1-minute average lags: over a 5 s cell it barely moves; the runnable count is the load seen now).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

from daq.priority import base_nice

_SPIN = "import time\nend = time.monotonic() + {limit}\nwhile time.monotonic() < end:\n    pass\n"
_MATMUL = (
    "import time\nimport numpy as np\nend = time.monotonic() + {limit}\n"
    "a = np.random.default_rng(0).standard_normal((256, 256))\n"
    "while time.monotonic() < end:\n    a = np.tanh(a @ a)\n"  # tanh keeps the values finite
)
#: one BLAS/OpenMP thread per hog: n hogs are n busy threads, as the count says
_ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")}


def _bound_child(cpu_s: int, nice: int):
    """preexec_fn: a CPU-time rlimit and death with the parent (PR_SET_PDEATHSIG = 1), both enforced by the kernel,
    and the priority the test process *started* at: a session earlier in the same process raised its thread to
    nice -5 (daq/priority.py), which a child would inherit -- hogs above the lab's other programs, and a loaded
    cell failing for a reason no lab PC has (seen: 5 cells of the matrix in one in-place ``make test``)."""

    def setup() -> None:
        import ctypes
        import resource

        try:
            os.setpriority(os.PRIO_PROCESS, 0, nice)  # lowering one's priority is always permitted
        except OSError:
            pass

        resource.setrlimit(resource.RLIMIT_CPU, (cpu_s, cpu_s + 5))
        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)
        except OSError:  # not glibc: the deadline and the rlimit still bound it
            pass

    return setup


def read_load() -> tuple[int, float]:
    """(runnable tasks now, 1-minute load average) from /proc/loadavg; (0, getloadavg) where it is absent."""
    try:
        with open("/proc/loadavg") as f:
            parts = f.read().split()
        return int(parts[3].split("/")[0]), float(parts[0])
    except OSError:
        return 0, os.getloadavg()[0]


@dataclass
class LoadSeen:
    """What the sampler saw while the hogs ran: runnable tasks (mean, max) and the 1-minute average at the end."""

    runnable_mean: float = 0.0
    runnable_max: int = 0
    loadavg_1m: float = 0.0
    samples: int = 0

    def as_dict(self) -> dict:
        return {"runnable_mean": round(self.runnable_mean, 2), "runnable_max": self.runnable_max,
                "loadavg_1m": round(self.loadavg_1m, 2), "samples": self.samples}  # fmt: skip


@dataclass
class Hogs:
    """``n`` bounded CPU hogs; use as a context manager or call :meth:`start` / :meth:`stop`."""

    n: int
    limit_s: float = 120.0  # each hog's own wall-clock deadline
    kind: str = "spin"  # "spin" or "matmul"
    period_s: float = 0.5  # the load sampler's period
    procs: list[subprocess.Popen] = field(default_factory=list)
    seen: LoadSeen = field(default_factory=LoadSeen)
    _stop: threading.Event = field(default_factory=threading.Event)
    _sampler: threading.Thread | None = None
    _runnable: list[int] = field(default_factory=list)
    started: int = 0  # how many hogs were ever started (a caller can check its load really ran)

    def start(self) -> Hogs:
        if self.kind not in ("spin", "matmul"):
            raise ValueError(f"kind {self.kind!r}: spin or matmul")
        code = (_SPIN if self.kind == "spin" else _MATMUL).format(limit=float(self.limit_s))
        env = {**os.environ, **_ONE_THREAD}
        for _ in range(self.n):
            self.procs.append(subprocess.Popen(
                [sys.executable, "-c", code], env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL, preexec_fn=_bound_child(int(self.limit_s) + 10, base_nice()),
            ))  # fmt: skip
        self.started += self.n
        self._stop.clear()
        self._sampler = threading.Thread(target=self._sample, name="hogs-load", daemon=True)
        self._sampler.start()
        return self

    def _sample(self) -> None:
        while not self._stop.wait(self.period_s):
            runnable, avg = read_load()
            self._runnable.append(runnable)
            self.seen = LoadSeen(sum(self._runnable) / len(self._runnable), max(self._runnable), avg, len(self._runnable))

    def alive(self) -> int:
        return sum(p.poll() is None for p in self.procs)

    def stop(self) -> LoadSeen:
        """Kill every hog (by its pid) and the sampler; returns the load seen. Safe to call twice."""
        self._stop.set()
        for p in self.procs:
            if p.poll() is None:
                p.kill()
        for p in self.procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:  # pragma: no cover - SIGKILL does not wait on the process
                pass
        self.procs.clear()
        if self._sampler is not None:
            self._sampler.join(timeout=2)
            self._sampler = None
        if not self.seen.samples:  # too short for the sampler: one reading now
            runnable, avg = read_load()
            self.seen = LoadSeen(float(runnable), runnable, avg, 1)
        return self.seen

    def __enter__(self) -> Hogs:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


if __name__ == "__main__":  # `python tests/hogs.py N SECONDS`: hogs for a manual run (bench/test_under_load.sh)
    n, secs = int(sys.argv[1]), float(sys.argv[2])

    def _interrupt(*_):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _interrupt)  # a kill by pid still stops the hogs (and PDEATHSIG would anyway)
    with Hogs(n, limit_s=secs) as h:
        try:
            time.sleep(secs)
        except KeyboardInterrupt:
            pass
    print(f"{n} hogs for {secs:g} s: load seen {h.seen.as_dict()}")


def sim_devices_wake_precisely() -> bool:
    """Whether a sending thread here can set its timer slack to 1 ns (drivers/sim/timing.py, D129): a container's seccomp
    profile or another OS may refuse ``prctl``, and the simulated devices then send up to the default 50 µs late, which
    D129 measured as up to 1.23 samples of offset scatter at 16384 Hz. The offset tests' one-sample bar needs it."""
    import threading

    from drivers.sim.timing import SLACK_NS, precise_wakeups, timer_slack_ns

    got: list[bool] = []
    t = threading.Thread(target=lambda: got.append(precise_wakeups() and timer_slack_ns() == SLACK_NS))
    t.start()
    t.join()
    return bool(got and got[0])

"""The live view as a lossy side channel (architecture.md: "a slow viewer drops display data, never samples").

:class:`ViewLane` is one more fan-out subscriber with a *small* queue: when the viewer (or the rerun
encoder behind it) falls behind, the fan-out drops the view's blocks and counts them — the log writer
and the near-live analysis never wait. Results (hits, driver events, ``/analysis/*``) reach it through
:meth:`ViewLane.offer`, a ``put_nowait`` into its own bounded queue that counts what it had to drop.
One thread does all the rerun logging (:class:`~daq.view.logger.ViewLogger`). The drops are shown in
the view as a text-log entry (``/log/daq``) as they happen and reported at the end as a
``view_overrun`` event (:meth:`ViewLane.overrun_event`, written to ``/daq/events`` by a session).

Where the view goes (:func:`open_view`):

* ``serve``: the bundled ``rerun`` CLI as a child process, ``rerun --serve-web --bind 127.0.0.1``: gRPC
  proxy and web viewer both on 127.0.0.1 only. (The in-process ``rr.serve_web_viewer`` of rerun-sdk 0.41
  has no bind address and listens on 0.0.0.0 — measured with ``ss -ltn`` — so it is not used; the
  in-process gRPC server could be bound with ``rr.GrpcServerSink(bind_ip="127.0.0.1")``.)
* ``connect``: ``RecordingStream.connect_grpc(url)`` to a viewer someone already runs.
* ``save``: an ``.rrd`` file (tests, benchmarks).

``spawn`` is never used (dependency-notes §3: it fails without a display).
"""

from __future__ import annotations

import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import rerun as rr

from analysis.errors import RuntimeFailure
from daq.children import pdeathsig
from daq.fanout import END, FanOut, Subscription
from daq.log import layout
from daq.view import recording as R
from daq.view.logger import ViewLogger, ViewSetup
from drivers.blocks import SampleBlock, coalesce

HOST = "127.0.0.1"


class ViewError(RuntimeFailure):
    """The view cannot be opened (one line: what, and how to fix it)."""


@dataclass
class ViewTarget:
    """An opened view: the recording stream, how to reach it, and the viewer process we started (if any)."""

    rec: rr.RecordingStream
    kind: str  # serve | connect | save
    url: str = ""  # gRPC url (serve, connect) or file path (save)
    web_url: str = ""  # browser address (serve)
    process: subprocess.Popen | None = None
    sink_delay_s: float = 0.0  # a deliberately slow viewer sink (tests, benchmarks)
    queue_blocks: int | None = None  # the view's queue in blocks (None: about a second of the session's blocks)

    def close(self, stop_viewer: bool = True) -> None:
        self.rec.flush()
        self.rec.disconnect()
        if stop_viewer and self.process is not None:
            _stop_group(self.process)


def rerun_cli() -> str:
    """The bundled ``rerun`` executable (next to the interpreter in a venv, which need not be on PATH)."""
    exe = Path(sys.executable).parent / "rerun"
    if exe.exists():
        return str(exe)
    found = shutil.which("rerun")
    if found is None:
        raise ViewError("the rerun CLI was not found next to python or on PATH; install rerun-sdk in this environment")
    return found


def _server_binary() -> str:
    """The viewer binary itself: the ``rerun`` script is a Python wrapper that runs it as a *child*, which
    would outlive a terminated wrapper."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / "rerun"
        if exe.is_file() and os.access(exe, os.X_OK):
            return str(exe)
    except ImportError:
        pass
    return rerun_cli()


def _stop_group(proc: subprocess.Popen) -> None:
    """Stop the viewer we started and anything it started (its own process group)."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return int(s.getsockname()[1])


def _wait_port(port: int, proc: subprocess.Popen, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ViewError(
                f"the rerun viewer server exited at start-up (code {proc.returncode}); run '{rerun_cli()} --serve-web' to see why"
            )
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex((HOST, port)) == 0:
                return
        time.sleep(0.05)
    raise ViewError(f"the rerun viewer server did not listen on {HOST}:{port} within {timeout:.0f} s")


def open_view(kind: str, where: str | None = None, web_port: int | None = None, grpc_port: int | None = None,
              memory_limit: str = "512MiB") -> ViewTarget:  # fmt: skip
    """``kind``: ``serve`` (start a local web viewer), ``connect`` (``where`` = gRPC url) or ``save`` (``where`` = path)."""
    rec = R.new_recording()
    bp = R.blueprint()
    if kind == "save":
        if not where:
            raise ViewError("view: save needs a path")
        rec.save(where, default_blueprint=bp)
        return ViewTarget(rec, kind, url=str(where))
    if kind == "connect":
        if not where:
            raise ViewError("view: --connect needs a url such as rerun+http://127.0.0.1:9876/proxy")
        rec.connect_grpc(where, default_blueprint=bp)
        return ViewTarget(rec, kind, url=where)
    if kind != "serve":
        raise ViewError(f"view: unknown kind {kind!r} (serve, connect or save)")
    g, w = grpc_port or _free_port(), web_port or _free_port()
    env = {**os.environ, "RERUN_TELEMETRY": "0"}
    cmd = [_server_binary(), "--serve-web", "--bind", HOST, "--port", str(g), "--web-viewer-port", str(w),
           "--server-memory-limit", memory_limit, "--hide-welcome-screen"]  # fmt: skip
    # its own session (stopped as a group), and PDEATHSIG: it dies with us even when we are SIGKILLed (daq/children.py)
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                            start_new_session=True, preexec_fn=pdeathsig)  # fmt: skip
    try:
        _wait_port(g, proc)
        _wait_port(w, proc)
    except ViewError:
        _stop_group(proc)
        raise
    url = f"rerun+http://{HOST}:{g}/proxy"
    rec.connect_grpc(url, default_blueprint=bp)
    from urllib.parse import quote

    return ViewTarget(rec, kind, url=url, web_url=f"http://{HOST}:{w}/?url={quote(url, safe='')}", process=proc)


class ViewLane:
    """Fan-out subscriber + result tee → one rerun logging thread. Never blocks its producers."""

    name = "view"
    #: where :meth:`finish` reports a ``view_overrun`` (the session's log, through the results router)
    report_sink = None

    def __init__(
        self, fan: FanOut, setup: ViewSetup, rec: rr.RecordingStream, maxsize: int = 16, result_maxsize: int = 4096,
        sink_delay_s: float = 0.0, report_every_s: float = 1.0, results_every_s: float = 0.5, frame_s: float = 0.25,
    ) -> None:  # fmt: skip
        self.sub: Subscription = fan.subscribe("view", maxsize=maxsize)
        self.sub.high_water = max(1, maxsize // 4)  # ends a frame early (_rest_of_frame)
        self.results: queue.Queue = queue.Queue(maxsize=max(1, result_maxsize))
        self.dropped_results = 0
        self.logged_blocks = 0
        self.frames = 0  # wake-ups that drew blocks
        self.sink_delay_s = sink_delay_s  # a deliberately slow viewer sink (tests, benchmarks)
        self.report_every_s = report_every_s
        self.results_every_s = results_every_s  # results go to rerun in batches: one send_columns per entity and batch
        # at most one wake-up per frame: a serial device delivers 256 blocks a second, and waking the view for each
        # cost more (GIL hand-offs with the reader, writer and analysis threads) than drawing them; what arrives
        # within a frame is joined (_coalesced). Raw envelopes and results go out every 0.5 s anyway, so a 0.25 s
        # frame delays nothing on screen. The wait is on an event the fan-out sets when the queue is a quarter full
        # (or the source ends), not a sleep (_rest_of_frame).
        self.frame_s = frame_s
        self.rec = rec
        self.view = ViewLogger(rec, setup)
        self.error: str | None = None
        self.thread_cpu_s = 0.0  # CPU of the view's own Python thread (rerun's encoder threads are not in it)
        self._results_done = threading.Event()
        self._abandon = threading.Event()
        self._reported = (0, 0)
        self._thread = threading.Thread(target=self._main, name="view", daemon=True)

    def start(self) -> ViewLane:
        self._thread.start()
        return self

    def offer(self, topic: str, obj: dict) -> None:
        """Tee a result (hit, driver event, analysis output) to the view; dropped and counted when full."""
        try:
            self.results.put_nowait((topic, obj))
        except queue.Full:
            self.dropped_results += 1

    def sink(self, inner=None):
        """An analysis-lane sink that forwards to ``inner`` (the log) first and then offers to the view."""

        def tee(topic: str, obj: dict, log_time_ns: int | None) -> None:
            if inner is not None:
                inner(topic, obj, log_time_ns)
            self.offer(topic, obj)

        return tee

    def finish(self, deadline: float) -> None:
        """The Lane protocol's end: ``drain_s`` = 2 s to catch up (never past ``deadline``), then the overrun note."""
        self.join(min(2.0, max(0.0, deadline - time.monotonic())))
        ev = self.overrun_event()
        if ev is not None and self.report_sink is not None:
            self.report_sink(layout.EVENTS_TOPIC, ev, None)

    def join(self, drain_s: float = 2.0) -> None:
        """Call after the fan-out closed and every result producer finished. The view gets ``drain_s`` to
        catch up; what it has not shown by then is dropped and counted (the session does not wait on it)."""
        self._results_done.set()
        self._thread.join(drain_s)
        if self._thread.is_alive():
            self._abandon.set()
            self.sub.wake.set()
            self._thread.join(10.0)

    @property
    def dropped(self) -> bool:
        return bool(self.sub.dropped_blocks or self.dropped_results)

    def overrun_event(self) -> dict | None:
        """The ``view_overrun`` event for ``/daq/events`` (None when the view kept up)."""
        if not self.dropped:
            return None
        return {"kind": "view_overrun", "count": self.sub.dropped_samples, "blocks": self.sub.dropped_blocks,
                "results": self.dropped_results,
                "message": f"the view fell behind and did not show {self.sub.dropped_blocks} blocks ({self.sub.dropped_samples} "
                           f"samples) and {self.dropped_results} results; recording and analysis unaffected"}  # fmt: skip

    # --- thread -----------------------------------------------------------------------------------
    def _main(self) -> None:
        c0 = time.thread_time()
        try:
            self._loop()
        finally:
            self.thread_cpu_s = time.thread_time() - c0

    def _loop(self) -> None:
        ended = False
        last_report = last_results = time.monotonic()
        try:
            while True:
                if self._abandon.is_set():
                    ended = self._discard()
                    break
                if not ended:
                    try:
                        item = self.sub.get(timeout=0.05)
                    except queue.Empty:
                        item = None
                    if item is END:
                        ended = True
                    elif item is not None:
                        frame0 = time.monotonic()
                        self.frames += 1
                        for blk in self._coalesced(item):
                            if blk is END:
                                ended = True
                                break
                            self.view.block(blk)
                        if self.sink_delay_s:
                            time.sleep(self.sink_delay_s)
                        if not ended:
                            self._rest_of_frame(frame0)
                now = time.monotonic()
                if ended or now - last_results >= self.results_every_s:
                    self._drain_results()
                    last_results = now
                if now - last_report >= self.report_every_s:
                    self._report_drops()
                    last_report = now
                if ended and self._results_done.is_set() and self.results.empty():
                    break
                if ended:
                    time.sleep(0.01)
            self.view.finish()
            self._report_drops(final=True)
        except Exception as exc:  # the view is optional: say so, keep draining, never take the session down
            self.error = f"{type(exc).__name__}: {exc}"
            while not ended and self.sub.get() is not END:
                pass
        finally:
            try:
                self.rec.flush()
            except Exception:
                pass

    def _rest_of_frame(self, frame0: float) -> None:
        """Let blocks queue until the frame (``frame_s`` from ``frame0``) is over, or until the queue is a quarter
        full (the fan-out sets ``sub.wake`` then) or the view is abandoned: a serial device's start-up backlog
        arrives at thousands of blocks a second, and a timed wait alone dropped it (measured: 187 blocks)."""
        sub = self.sub
        sub.wake.clear()
        rest = self.frame_s - (time.monotonic() - frame0)
        if rest > 0 and sub.queue.qsize() < sub.high_water and not self._abandon.is_set():
            sub.wake.wait(rest)

    def _coalesced(self, first: SampleBlock, most: int = 256) -> list:
        """``first`` and whatever else is queued already (up to ``most``), contiguous blocks of one stream
        joined: small device blocks (64 samples over serial: 256 a second) cost the view per call, not per
        sample. END, if queued, comes last."""
        got: list[SampleBlock] = [first]
        end = False
        for _ in range(most):
            try:
                item = self.sub.queue.get_nowait()
            except queue.Empty:
                break
            if item is END:
                end = True
                break
            got.append(item)
        self.logged_blocks += len(got)
        return [*coalesce(got, max_samples=1 << 30), *([END] if end else [])]

    def _discard(self) -> bool:
        """Drop (and count) everything still queued for the view: it took too long after the end."""
        while True:
            try:
                item = self.sub.queue.get_nowait()
            except queue.Empty:
                break
            if item is not END:
                self.sub.dropped_blocks += 1
                self.sub.dropped_samples += item.n_samples
                self.sub.dropped_ranges.append((item.stream, item.first_index, item.end_index))
        while True:
            try:
                self.results.get_nowait()
            except queue.Empty:
                return True
            self.dropped_results += 1

    def _drain_results(self) -> None:
        by: dict[str, list[dict]] = {}
        for _ in range(10000):
            try:
                topic, obj = self.results.get_nowait()
            except queue.Empty:
                break
            by.setdefault(topic, []).append(obj)
        for topic in sorted(by, key=lambda t: t != layout.MODAL_TOPIC):  # energies first: the RQ-FEP pairs with them
            self.view.results(topic, by[topic])

    def _report_drops(self, final: bool = False) -> None:
        now = (self.sub.dropped_samples, self.dropped_results)
        if now == self._reported:
            return
        self._reported = now
        R.log_text(self.rec, R.LOG_DAQ, self.view.t_now,
                   f"view fell behind{' (final)' if final else ''}: {self.sub.dropped_blocks} display blocks ({now[0]} samples) "
                   f"and {now[1]} results not shown so far; the recording is complete", "WARN")  # fmt: skip


def start_view_lane(fan: FanOut, rig, streams: dict[str, tuple[str, ...]], sample_rate: float, target: ViewTarget,
                    maxsize: int = 64) -> ViewLane:  # fmt: skip
    """The view lane for a session or replay of ``rig`` (None rig: raw channels and results only)."""
    setup = ViewSetup.from_rig(rig, streams, sample_rate) if rig is not None else ViewSetup(streams, sample_rate)
    size = target.queue_blocks if target.queue_blocks is not None else maxsize
    return ViewLane(fan, setup, target.rec, maxsize=size, sink_delay_s=target.sink_delay_s).start()

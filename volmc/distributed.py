"""Rendering on a Dask cluster (``volmc render --workers N`` or ``--scheduler ADDRESS``).

Dask (``dask[distributed]``, the optional extra ``volmc[dask]``) does the scheduling; volmc
only cuts the work and merges it. A task is one chunk of the render (``render.chunk_schedule``:
consecutive batches, ranges of the global sample index on which the counter RNG and the
samplers are keyed, about CHUNK_SAMPLES samples). The worker renders the chunk into an empty
film (``render.render_chunk``) and returns its sums of sample values and of their squares
(float64 RGBA; 64 bytes per pixel) with the counts it made. The host adds the chunks to its film
in schedule order, exactly as a local render adds its own chunks, so the image is the local
render's bit for bit.

A task is keyed by its chunk, and the host takes each chunk's result once, in order: a
task whose worker dies is run again by Dask (the scheduler reassigns the tasks of a lost
worker; ``retries`` covers exceptions), and no range is counted twice or lost. Workers
build the scene's backend once per render (cached by a token in the worker process) from
the scene the host sends them once (``hold``: recoverable when a worker dies).

Progress, Ctrl-C (stop after the batch being merged; outstanding tasks are cancelled) and
checkpoints work as for a local render (render.py).

Failures are bounded and keep the work (docs/cluster.md): connecting to a scheduler has one
deadline for the whole handshake (``connect``), a render waits a bounded time for a worker
(``ClusterChunks``), and a cluster that fails mid-render (a task killed its workers too
often, the scheduler died) raises ``ClusterError`` carrying the merged samples, which the
driver has checkpointed first.
"""

import contextlib
import signal
import threading
import time
import uuid
import warnings

import numpy as np

from .params import COUNTER_NAMES
from .scene.errors import SceneError, VolmcError

#: Backends built in this (worker) process: {token: backend} of the render in progress.
_WORKER_BACKENDS = {}
#: One chunk at a time per worker process: a worker with several threads (dask-worker's
#: default) would otherwise run chunks at once on the one backend, whose buffers, kernel
#: arguments and counters are not shared safely. One volmc backend already uses every core.
_WORKER_LOCK = threading.Lock()


class ClusterError(VolmcError):
    """The Dask cluster failed: no worker joined in time, a chunk's task failed (Dask's
    KilledWorker: it killed its workers too often), the scheduler went away. ``reason`` says
    what happened; ``result`` is what was rendered before it (the driver's RenderResult,
    marked partial, whose samples the driver has also checkpointed if asked to; from
    ``volmc.render`` a RenderedImage), or None if nothing was. file, key: as VolmcError's."""

    def __init__(self, reason, result=None, file="dask", key="client", message=None):
        super().__init__(file, key, message or reason)
        self.reason, self.result = reason, result

    def __reduce__(self):
        return self.__class__, (self.reason, self.result, self.file, self.key, self.message)


def worker_timeout():
    """Seconds a render waits for a worker to join the scheduler, and for one to come back
    while the cluster has none: Dask's connect timeout (``distributed.comm.timeouts.connect``,
    30 s unless configured, e.g. DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=5s)."""
    import dask
    from dask.utils import parse_timedelta
    return float(parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s"))


def describe(exc):
    """One line for an exception of the cluster: its type and its message."""
    text = " ".join(str(exc).split())
    name = type(exc).__name__
    return f"{name}: {text}" if text else name


def render_task(scene, token, backend, device, chunk, lanes=None, albedo=False):
    """Runs on a worker: ``render.render_chunk`` of ``chunk`` with the backend of render
    ``token`` (built on first use in this process, at the client's lane width ``lanes``).
    Returns (sum, sum_sq) float64 [h, w, 3] of the chunk and the counts int64 [N_COUNTERS]
    it made. albedo: the sums hold the albedo AOV too (film.py)."""
    with _WORKER_LOCK:
        return _render_task(scene, token, backend, device, chunk, lanes, albedo)


def _render_task(scene, token, backend, device, chunk, lanes, albedo):
    from .backends import make_backend
    from .render import render_chunk
    be = _WORKER_BACKENDS.get(token)
    if be is None:
        _WORKER_BACKENDS.clear()   # one render at a time per worker process
        # The worker holds the scene and its backend: its own memory is the one to check
        # (the client checks the film alone).
        from .memory import check_memory
        try:
            check_memory(scene, backend, device, albedo=albedo)
        except SceneError as e:
            import socket
            raise SceneError(e.file, e.key, f"on the Dask worker at {socket.gethostname()}: "
                                            f"{e.message}") from None
        be = make_backend(backend, scene, device, lanes=lanes, albedo=albedo)
        be.warm_up()
        _WORKER_BACKENDS[token] = be
    before = np.asarray(be.counter_totals(), np.int64).copy()
    w, h = scene.camera.resolution
    part = render_chunk(be, w, h, chunk)
    return part.sum, part.sum_sq, np.asarray(be.counter_totals(), np.int64) - before


class ClusterChunks:
    """The chunks of a render run as tasks on a Dask client's workers; iterating adds each
    chunk's sums to the film in schedule order and yields its samples per pixel (the
    protocol of render.LocalChunks)."""

    def __init__(self, client, scene, backend, device, film, chunks, lanes=None, albedo=False):
        from .backends.base import techniques
        self.client, self.scene, self.film = client, scene, film
        self.backend, self.device, self.lanes = backend, device, lanes
        self.albedo = albedo
        self.name = f"{backend} on dask"
        self.techniques = techniques(scene)
        if lanes is not None:
            self.techniques["lanes"] = str(lanes)
        self.tasks = chunks
        self.token = uuid.uuid4().hex
        self.counts = np.zeros(len(COUNTER_NAMES), np.int64)
        self.futures = []
        self.scene_future = None
        #: Called while a chunk is awaited; True stops the iteration (the driver's Ctrl-C
        #: flag), so a first Ctrl-C works while the cluster has no worker to run the chunk.
        self.stopping = lambda: False

    def warm_up(self):
        """Waits (at most ``worker_timeout()``; Ctrl-C raises KeyboardInterrupt) for a worker
        on the scheduler, then sends the scene to the workers and submits every task, the
        earlier chunks at higher priority (the host merges in order, and what it merged is
        what a failure keeps; workers build their backends as their first task starts).
        ClusterError if no worker comes."""
        timeout = worker_timeout()
        try:
            self.client.wait_for_workers(1, timeout=timeout)
        except TimeoutError:
            raise ClusterError(f"no worker joined the Dask scheduler within {timeout:g} s "
                               "(distributed.comm.timeouts.connect); start one with "
                               "'dask worker ADDRESS'") from None
        except Exception as e:   # the scheduler went away
            raise ClusterError(f"the Dask cluster failed before the render started "
                               f"({describe(e)})") from e
        # Held until close(), so it outlives every task.
        self.scene_future = hold(self.client, self.scene, "volmc-scene")
        self.futures = [
            self.client.submit(render_task, self.scene_future, self.token, self.backend,
                               self.device, r, self.lanes, self.albedo,
                               key=f"volmc-{self.token}-{i}",
                               retries=3, pure=False, priority=len(self.tasks) - i)
            for i, r in enumerate(self.tasks)]

    def __iter__(self):
        """Merges the chunks in order. Stops early (returns) when ``stopping()``; raises
        ClusterError when a chunk's task failed (after its retries, or KilledWorker), the
        client lost the scheduler, or the cluster had no worker for ``worker_timeout()``
        seconds: the chunks merged before stay in the film."""
        for i, (fut, chunk) in enumerate(zip(self.futures, self.tasks)):
            try:
                if not self._await(fut):
                    return
                s, sq, counts = fut.result()
            except ClusterError:
                raise
            except SceneError as e:
                if i == 0:   # a worker's one-line error (its memory), before any work
                    raise
                # After merged chunks (a worker that joined later refused): the work is kept
                # as for any failure of the cluster.
                raise ClusterError(f"a worker refused a chunk ({e})") from e
            except Exception as e:   # Dask's KilledWorker, CancelledError, CommClosedError...
                raise ClusterError(_failure(e)) from e
            fut.release()   # the merged chunk's arrays can go
            self.film.sum += s
            self.film.sum_sq += sq
            self.counts += counts
            yield sum(n for _, n in chunk)

    def counter_totals(self):
        return self.counts

    def _await(self, fut, poll=0.25, every=2.0):
        """Waits for ``fut`` to finish (done, failed or cancelled): True, or False when
        ``stopping()``. Every ``every`` seconds it asks the scheduler for its workers; none
        for ``worker_timeout()`` seconds is a ClusterError (a task waits for ever else)."""
        done = threading.Event()
        fut.add_done_callback(lambda _: done.set())
        last_check = lonely_since = time.monotonic()
        while not fut.done():
            if self.stopping():
                return False
            done.wait(poll)
            now = time.monotonic()
            if now - last_check >= every and not fut.done():
                last_check = now
                if self.client.status in ("closing", "closed"):
                    break   # fut.result() says why (cancelled with the client)
                if self.client.scheduler_info().get("workers"):
                    lonely_since = now
                elif now - lonely_since >= worker_timeout():
                    raise ClusterError(f"the Dask cluster has had no worker for "
                                       f"{worker_timeout():g} s (distributed.comm.timeouts."
                                       "connect)")
        return True

    def close(self):
        """Cancels the tasks not merged yet (after Ctrl-C, or at the end: a no-op). Quiet
        when the cluster is gone already: nothing is left to cancel there."""
        pending = [f for f in self.futures if not f.done()]
        if pending and self.client.status not in ("closing", "closed"):
            try:
                self.client.cancel(pending)
            except Exception:
                pass
        self.scene_future = None


def _failure(exc):
    """The ClusterError reason for an exception of a chunk's future."""
    name = type(exc).__name__
    if name == "KilledWorker":
        first = " ".join(str(exc).split()).split(". ")[0][:200]
        return f"the workers running a chunk of the render kept dying (Dask's KilledWorker: " \
               f"{first})"
    if name in ("CancelledError", "FutureCancelledError", "FuturesCancelledError"):
        why = getattr(exc, "reason", None) or "cancelled"
        if "connection" in str(why) or "connection" in str(exc):
            return "the client lost its connection to the Dask scheduler"
        return f"the render's tasks were cancelled on the Dask scheduler ({why})"
    if name == "CommClosedError" or isinstance(exc, OSError):
        return f"the client lost its connection to the Dask scheduler ({describe(exc)[:200]})"
    return f"a task of the render failed ({describe(exc)[:200]})"


def hold(client, data, name):
    """A future of ``data`` on the cluster that survives the loss of workers: a task that
    returns it, under a key of its own (``name``-random). The scheduler keeps the task's
    spec, so if every worker holding the result dies the task is run again. Data sent with
    client.scatter is not recoverable: the active memory manager may trim its replicas to
    one, and losing that worker then fails every task that needs it ("lost scattered
    data"); and scattered data is keyed by content unless told otherwise, so two renders of
    one scene would share a key, one's release dropping it under the other's tasks. The
    data travels inside the task, hence the large-graph warning is silenced here."""
    import warnings
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sending large graph")
        return client.submit(_held, data, key=f"{name}-{uuid.uuid4().hex}", pure=False)


def _held(data):
    return data


def connect(workers=None, scheduler=None, file="command line", key="--scheduler"):
    """``make_client``, with the one-line SceneError (``file``, ``key``) when Dask is not
    installed or the scheduler cannot be reached."""
    from .scene.errors import SceneError
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise SceneError(file, key, "needs Dask: pip install 'volmc[dask]'") from None
    why = address_problem(scheduler) if scheduler else None
    if why:   # now, not after Dask's connect timeout (30 s)
        raise SceneError(file, key, f"{scheduler!r}: {why}")
    try:
        return make_client(workers, scheduler)
    except KeyboardInterrupt:
        raise
    except Exception as e:   # whatever a listener that is not a scheduler made Dask raise
        if not scheduler:
            raise SceneError(file, key, f"the local Dask cluster did not start: "
                                        f"{describe(e)}") from None
        if isinstance(e, TimeoutError):
            why = (f"no Dask scheduler answered within {worker_timeout():g} s "
                   "(distributed.comm.timeouts.connect)")
        elif isinstance(e, OSError):
            why = describe(e)
        else:   # bytes that were not Dask's: lengths of exabytes, a bad header...
            why = f"what answered is not a Dask scheduler ({describe(e)[:200]})"
        raise SceneError(file, key, f"cannot reach the Dask scheduler {scheduler!r}: "
                                    f"{why}") from None


def address_problem(address):
    """Why ``address`` cannot name a scheduler, or None if it may: a port outside 1-65535,
    or a dotted-quad host with a number above 255. Dask would find out only when its
    connect timeout ends."""
    import re
    host, sep, port = address.split("://", 1)[-1].rpartition(":")
    if not sep:
        return None   # no port: Dask's default one
    if not (port.isascii() and port.isdigit()) or not 0 < int(port) < 65536:
        return f"the port {port!r} is not a number from 1 to 65535"
    if re.fullmatch(r"\d+(\.\d+){3}", host) and any(int(x) > 255 for x in host.split(".")):
        return f"{host} is not an IPv4 address"
    return None


def make_client(workers=None, scheduler=None):
    """(client, cluster): a Dask client of a new local cluster of ``workers`` worker
    processes (one thread each, no dashboard), or of the running scheduler at ``scheduler``
    (e.g. "tcp://10.0.0.1:8786"; cluster None). Raises ImportError without dask."""
    from distributed import Client, LocalCluster
    if scheduler:
        return bounded_client(scheduler, worker_timeout()), None
    # The workers start with SIGINT blocked, which their processes keep (a signal mask is
    # inherited through fork and exec): a Ctrl-C at the terminal reaches the whole process
    # group, and workers that died of it mid-task left the client waiting for them, under
    # screens of tracebacks. The client alone stops the render (render._StopFlag), and
    # closing the cluster ends the workers. A Ctrl-C during the start-up is kept and acted on
    # once the cluster is up: it is closed again and KeyboardInterrupt raised.
    with _sigint_deferred() as interrupted:
        with warnings.catch_warnings():
            # Its HTTP server's "Port 8787 is already in use" beside another volmc: it takes
            # another port, and a render has no dashboard to find.
            warnings.filterwarnings("ignore", "Port .* is already in use", UserWarning)
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                   processes=True, dashboard_address=None)
        try:
            client = Client(cluster)
            # On every worker, also those the nannies start again after one died.
            client.register_plugin(_quiet_worker_plugin(), name="volmc-quiet")
        except BaseException:
            cluster.close()
            raise
    if interrupted:
        close(client, cluster)
        raise KeyboardInterrupt
    return client, cluster


@contextlib.contextmanager
def _sigint_deferred():
    """Within: SIGINT is blocked in this thread, hence in every thread and process started
    from it (Dask's event loop, the processes of a LocalCluster's workers, which therefore
    never see a Ctrl-C: a signal mask is kept through fork and exec), and one that arrives
    is recorded, not lost: the list yielded is non-empty on leaving if it came. (SIG_IGN,
    used before, was inherited by the workers too, but threw the user's Ctrl-C away.)
    Outside the main thread: nothing is changed."""
    got = []
    try:
        old = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    except ValueError:   # not the main thread: signals are not ours to set
        yield got
        return
    # multiprocessing starts its resource tracker on the first spawn, unblocking SIGINT in
    # the thread that spawns (Dask's event loop, whose later threads start the workers):
    # started now, it is not started again.
    from multiprocessing import resource_tracker
    resource_tracker.ensure_running()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield got
    finally:
        # A Ctrl-C left pending by the mask is delivered here, to the recorder.
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        signal.signal(signal.SIGINT, old)


def bounded_client(address, timeout):
    """A Client of the scheduler at ``address`` whose whole start (TCP connect, Dask's
    handshake, the scheduler's first reply) must end within ``timeout`` seconds plus a
    margin: Dask bounds the connect alone, and a listener that accepts but never speaks (an
    HTTP server) held it for ever. TimeoutError when it does not."""
    import distributed

    class Client(distributed.Client):   # its name is the scheduler's name for the client
        def start(self, **kwargs):
            kwargs.setdefault("callback_timeout", timeout + 5.0)
            try:
                return super().start(**kwargs)
            except BaseException:
                with contextlib.suppress(Exception):
                    self.close(timeout=5)
                raise

    return Client(address, timeout=timeout)


def close(client, cluster=None):
    """Close ``client`` and the local ``cluster`` it runs on (None: a scheduler's), quietly:
    tasks a stopped render left behind may still report to the scheduler as it closes, which
    Dask logs as CRITICAL tracebacks of a closed comm, none of them the user's business."""
    if cluster is not None:
        # Our workers share the terminal: one whose heartbeat meets the scheduler closed
        # before it logs an ERROR traceback there (seen once in a CI run after Ctrl-C).
        try:
            client.run(_quiet_for_close)
        except Exception:   # a worker already gone: nothing of its to silence
            pass
    with quiet_logs():
        # A client that lost its scheduler fails to say goodbye to it: nothing to report.
        with contextlib.suppress(Exception):
            client.close(timeout=10)
        if cluster is not None:
            cluster.close()


@contextlib.contextmanager
def quiet_logs():
    """Within: nothing of Dask's is logged in this process (every ``distributed`` logger
    above CRITICAL; Dask's configuration gives some of them levels of their own)."""
    import logging
    names = ["distributed"] + [n for n in logging.root.manager.loggerDict
                               if n.startswith("distributed.")]
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)


def _quiet_for_close():
    """In a worker of our local cluster that is about to be closed: nothing of Dask's to log
    any more (close)."""
    import logging
    for name in ["distributed"] + [n for n in logging.root.manager.loggerDict
                                   if n.startswith("distributed.")]:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _quiet_worker_plugin():
    """A Dask WorkerPlugin that runs _quiet_cancellations on each worker as it starts (a
    local class, which cloudpickle sends by value: distributed is imported only here)."""
    from distributed import WorkerPlugin

    class QuietCancellations(WorkerPlugin):
        def setup(self, worker):
            _quiet_cancellations()

    return QuietCancellations()


def _quiet_cancellations():
    """In a worker of our local cluster: the tasks a stopped render cancels are no news (each
    one logged a WARNING of CancelledError on the user's terminal)."""
    import logging
    logging.getLogger("distributed.worker.state_machine").setLevel(logging.ERROR)

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
"""

import signal
import threading
import uuid
import warnings

import numpy as np

from .params import COUNTER_NAMES

#: Backends built in this (worker) process: {token: backend} of the render in progress.
_WORKER_BACKENDS = {}
#: One chunk at a time per worker process: a worker with several threads (dask-worker's
#: default) would otherwise run chunks at once on the one backend, whose buffers, kernel
#: arguments and counters are not shared safely. One volmc backend already uses every core.
_WORKER_LOCK = threading.Lock()


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

    def warm_up(self):
        """Sends the scene to every worker and submits every task (workers build their
        backends as their first task starts)."""
        # Held until close(), so it outlives every task.
        self.scene_future = hold(self.client, self.scene, "volmc-scene")
        self.futures = [
            self.client.submit(render_task, self.scene_future, self.token, self.backend,
                               self.device, r, self.lanes, self.albedo,
                               key=f"volmc-{self.token}-{i}",
                               retries=3, pure=False)
            for i, r in enumerate(self.tasks)]

    def __iter__(self):
        for fut, chunk in zip(self.futures, self.tasks):
            s, sq, counts = fut.result()
            fut.release()   # the merged chunk's arrays can go
            self.film.sum += s
            self.film.sum_sq += sq
            self.counts += counts
            yield sum(n for _, n in chunk)

    def counter_totals(self):
        return self.counts

    def close(self):
        """Cancels the tasks not merged yet (after Ctrl-C, or at the end: a no-op)."""
        pending = [f for f in self.futures if not f.done()]
        if pending:
            self.client.cancel(pending)
        self.scene_future = None


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
    except (OSError, TimeoutError, ValueError) as e:
        raise SceneError(file, key, f"cannot reach the Dask scheduler {scheduler!r}: "
                                    f"{e}") from None


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
        # The connect timeout is Dask's distributed.comm.timeouts.connect (30 s unless
        # configured, e.g. DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=5s).
        return Client(scheduler), None
    # The workers start with SIGINT ignored, which their interpreters keep: a Ctrl-C at the
    # terminal reaches the whole process group, and workers that died of it mid-task left
    # the client waiting for them, under screens of tracebacks. The client alone stops the
    # render (render._StopFlag), and closing the cluster ends the workers.
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:   # not the main thread: signals are not ours to set
        old = None
    try:
        with warnings.catch_warnings():
            # Its HTTP server's "Port 8787 is already in use" beside another volmc: it takes
            # another port, and a render has no dashboard to find.
            warnings.filterwarnings("ignore", "Port .* is already in use", UserWarning)
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                   processes=True, dashboard_address=None)
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)
    client = Client(cluster)
    client.run(_quiet_cancellations)
    return client, cluster


def close(client, cluster=None):
    """Close ``client`` and the local ``cluster`` it runs on (None: a scheduler's), quietly:
    tasks a stopped render left behind may still report to the scheduler as it closes, which
    Dask logs as CRITICAL tracebacks of a closed comm, none of them the user's business."""
    import logging
    if cluster is not None:
        # Our workers share the terminal: one whose heartbeat meets the scheduler closed
        # before it logs an ERROR traceback there (seen once in a CI run after Ctrl-C).
        try:
            client.run(_quiet_for_close)
        except Exception:   # a worker already gone: nothing of its to silence
            pass
    log = logging.getLogger("distributed")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        client.close()
        if cluster is not None:
            cluster.close()
    finally:
        log.setLevel(level)


def _quiet_for_close():
    """In a worker of our local cluster that is about to be closed: nothing of Dask's to log
    any more (close)."""
    import logging
    for name in ["distributed"] + [n for n in logging.root.manager.loggerDict
                                   if n.startswith("distributed.")]:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _quiet_cancellations():
    """In a worker of our local cluster: the tasks a stopped render cancels are no news (each
    one logged a WARNING of CancelledError on the user's terminal)."""
    import logging
    logging.getLogger("distributed.worker.state_machine").setLevel(logging.ERROR)

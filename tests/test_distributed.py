"""Rendering on a Dask cluster (volmc/distributed.py, ``render(client=...)``, ``volmc render
--workers`` and ``--scheduler``): a local cluster on loopback renders the single-process
image bit for bit, also when a worker is killed mid-render, and the CLI does too."""

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from volmc.film import read_exr   # noqa: E402
from volmc.params import sample_counts   # noqa: E402
from volmc.render import batch_schedule, chunk_schedule, render   # noqa: E402
from volmc.resources import default_scene   # noqa: E402
from volmc.scene import load_scene   # noqa: E402

SMALL = ["medium.density.resolution=32", "camera.resolution=[64, 48]", "render.max_depth=8"]


@pytest.fixture(scope="module")
def cluster():
    """A scheduler and 2 single-threaded worker processes on loopback."""
    c = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                 dashboard_address=":0", host="127.0.0.1")
    client = distributed.Client(c)
    yield c, client
    client.close()
    c.close()


def test_chunks_tile_the_schedule():
    """Chunks cover the batches of [start, spp) in order and contiguously, each (but the
    last) holding at least the chunk size, and a chunk boundary of the full schedule starts
    the same chunks."""
    for n_pix, spp, start in [(3072, 1000, 0), (3072, 1000, 7), (65536, 40, 0), (1, 5, 2)]:
        full = chunk_schedule(n_pix, spp, 0, 200_000)
        chunks = chunk_schedule(n_pix, spp, start, 200_000)
        flat = [r for c in chunks for r in c]
        assert [n for _, n in flat] == batch_schedule(n_pix, spp, start)
        s = start
        for a, n in flat:
            assert a == s
            s += n
        assert s == spp
        assert all(sum(n for _, n in c) * n_pix >= 200_000 for c in full[:-1])
        ends = np.cumsum([sum(n for _, n in c) for c in full])
        for k, e in enumerate(ends[:-1]):
            assert chunk_schedule(n_pix, spp, int(e), 200_000) == full[k + 1:]


def test_cluster_render_equals_single_process(cluster):
    """The same seed and spp on 2 workers: the film's sums, the counters and the image are
    the single-process render's, bit for bit."""
    _, client = cluster
    scene = load_scene(default_scene(), SMALL)
    a = render(scene, backend="opencl", spp=300, progress=False)
    b = render(scene, backend="opencl", spp=300, progress=False, client=client)
    np.testing.assert_array_equal(a.film.sum, b.film.sum)
    np.testing.assert_array_equal(a.film.sum_sq, b.film.sum_sq)
    assert a.counters == b.counters and b.film.spp == 300


def test_cluster_renders_at_the_clients_lane_width(cluster):
    """The workers build at the lane width the client chose, whatever their own default (a
    worker's $VOLMC_LANES here): the image is the local one at that width bit for bit, and
    another width on the client gives its own."""
    _, client = cluster
    scene = load_scene(default_scene(), SMALL)
    client.run(lambda: os.environ.__setitem__("VOLMC_LANES", "16"))
    try:
        for lanes in (4, 1):
            a = render(scene, backend="opencl", spp=40, progress=False, lanes=lanes)
            b = render(scene, backend="opencl", spp=40, progress=False, client=client,
                       lanes=lanes)
            np.testing.assert_array_equal(a.film.sum, b.film.sum)
            assert a.counters == b.counters and b.techniques["lanes"] == str(lanes)
    finally:
        client.run(lambda: os.environ.pop("VOLMC_LANES", None))


def test_api_render_on_the_cluster(cluster):
    """volmc.render(client=Client) and volmc.render(client="tcp://...") (a client opened
    and closed for the call) give the single-process image bit for bit."""
    import volmc
    c, client = cluster
    scene = load_scene(default_scene(), SMALL)
    one = volmc.render(scene, spp=40, progress=False)
    for where in (client, c.scheduler_address):
        there = volmc.render(scene, spp=40, progress=False, client=where)
        np.testing.assert_array_equal(there.image, one.image)
        assert there.counters == one.counters and there.backend == "opencl on dask"
    import dask
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        with pytest.raises(volmc.VolmcError,
                           match=r"^volmc\.render\(\): client: cannot reach"):
            volmc.render(scene, spp=1, progress=False, client="tcp://127.0.0.1:9")


def test_multithreaded_worker_renders_the_same_image():
    """A worker with 2 threads (dask-worker's default is one per core) runs one chunk at a
    time on its one backend: the image and counters are the single-process ones."""
    scene = load_scene(default_scene(), SMALL)
    a = render(scene, backend="opencl", spp=300, progress=False, chunk_samples=20_000)
    # Dashboard on a free port: the module's cluster may hold the default one.
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True,
                                  dashboard_address=":0", host="127.0.0.1") as c, \
            distributed.Client(c) as client:
        b = render(scene, backend="opencl", spp=300, progress=False, client=client,
                   chunk_samples=20_000)
    np.testing.assert_array_equal(a.film.sum, b.film.sum)
    assert a.counters == b.counters


def test_held_data_survives_losing_every_worker_holding_it(cluster):
    """distributed.hold: kill (SIGKILL) every worker holding the data, and a task that
    needs it still gets it, since the scheduler runs the holding task again. (Scattered
    data is lost with its workers.)"""
    from volmc.distributed import hold
    _, client = cluster
    data = np.arange(1000.0)
    fut = hold(client, data, "test-held")
    fut.result()
    holders = client.who_has([fut])[fut.key]
    pids = client.run(os.getpid, workers=list(holders))
    for pid in pids.values():
        os.kill(pid, signal.SIGKILL)
    assert client.submit(np.sum, fut, pure=False).result(timeout=120) == data.sum()
    client.wait_for_workers(2, timeout=120)


def test_killed_worker_leaves_the_image_exact(cluster):
    """A worker process killed by SIGKILL while the render runs: its tasks are run again on
    a worker (the nanny restarts the process), and the image is still the single-process
    one, with every sample counted once."""
    _, client = cluster
    scene = load_scene(default_scene(), SMALL)
    spp = 1200
    a = render(scene, backend="opencl", spp=spp, progress=False)
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    killed = threading.Event()

    def kill_soon():
        time.sleep(1.0)
        os.kill(victim, signal.SIGKILL)
        killed.set()

    b = render(scene, backend="opencl", spp=spp, progress=False, client=client,
               on_start=threading.Thread(target=kill_soon).start)
    assert killed.is_set()
    np.testing.assert_array_equal(a.film.sum, b.film.sum)
    np.testing.assert_array_equal(a.film.sum_sq, b.film.sum_sq)
    assert a.counters == b.counters and b.film.spp == spp
    client.wait_for_workers(2, timeout=120)
    assert victim not in client.run(os.getpid).values()   # it was killed and replaced


def _cli(args, cwd):
    env = dict(os.environ)
    env["DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT"] = "2s"   # the unreachable scheduler
    env["PYTHONPATH"] = os.pathsep.join([os.path.dirname(os.path.dirname(__file__)),
                                         env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-m", "volmc.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=900)


def test_cli_workers_and_scheduler(cluster, tmp_path):
    """volmc render --workers 2 (a new local cluster) and --scheduler ADDRESS (the running
    one) write the EXR of a single-process render, bit for bit; an unreachable scheduler is
    a one-line error with exit status 2."""
    c, _ = cluster
    common = ["render", str(default_scene()), "--quiet", "--spp", "40"]
    for d in SMALL:
        common += ["-D", d]
    runs = {"one.exr": [], "workers.exr": ["--workers", "2"],
            "scheduler.exr": ["--scheduler", c.scheduler_address]}
    for out, extra in runs.items():
        r = _cli(common + ["-o", out] + extra, tmp_path)
        assert r.returncode == 0, r.stderr
    one, meta = read_exr(tmp_path / "one.exr")
    for out in ("workers.exr", "scheduler.exr"):
        img, m = read_exr(tmp_path / out)
        np.testing.assert_array_equal(img, one)
        assert m["backend"] == "opencl on dask" and m["spp"] == 40
    r = _cli(common + ["-o", "x.exr", "--scheduler", "tcp://127.0.0.1:9"], tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0].startswith("volmc: error: command line: --scheduler: ")


def test_bench_render_configurations_on_the_cluster(cluster):
    """volmc bench render --workers: a configuration rendered on the cluster draws the same
    samples as in this process: the same counters, and the same mean image up to float32
    rounding (the cluster cuts samples [start, start + spp) along the render's global
    batch schedule, the local runner from the start of its own, and the kernel averages
    each batch in float32)."""
    from volmc.bench import convergence as cv
    _, client = cluster
    scene = load_scene(default_scene(), SMALL)
    cfg = cv.make_configs(["opencl"], ["grid"], ["delta"], ["track_length"], None)[0]
    here = cv._VolmcRunner(scene, cfg, None)
    there = cv._ClusterRunner(scene, cfg, None, client)
    for spp in (8, 24):
        a, _, ca = here.render(spp)
        b, sec, cb = there.render(spp)
        np.testing.assert_allclose(b, a, rtol=2e-6, atol=1e-9)
        # The cluster cuts the samples into other batches: the lanes' counts may differ.
        assert sample_counts(ca) == sample_counts(cb) and sec > 0


def _without_times(x):
    """A bench transmittance report without its wall-clock figures."""
    timed = {"seconds_per_estimate", "eff_mse_time", "winner_mse_time", "seconds"}
    if isinstance(x, dict):
        return {k: _without_times(v) for k, v in x.items() if k not in timed}
    if isinstance(x, list):
        return [_without_times(v) for v in x]
    return x


def test_bench_transmittance_on_the_cluster(cluster, tmp_path):
    """volmc bench transmittance with a Dask client: every case (profile points, replayed
    segment sets, map bins) runs as a task, and every figure of the report but the times
    equals the local run's; every case is measured once (no bin or row lost or repeated).
    The CLI's --scheduler runs the sweep there too."""
    import json
    from volmc.bench import transmittance as bt
    from volmc.resources import scenes_dir
    c, client = cluster
    path = scenes_dir() / "tests" / "white_furnace.toml"
    small = ["camera.resolution=[16, 16]", "render.majorant_resolution=[4, 4, 4]"]
    scene = load_scene(path, small)
    names = ["ratio", "track_length", "residual_ratio", "auto"]
    quiet = lambda *a: None   # noqa: E731
    here = bt.run(names, [scene], n_rays=64, quick=True, log=quiet)
    there = bt.run(names, [scene], n_rays=64, quick=True, log=quiet, client=client)
    assert _without_times(json.loads(json.dumps(there, default=float))) == \
        _without_times(json.loads(json.dumps(here, default=float)))
    assert sum(1 for b in there["maps"]["bins"] if b["results"]) > 0
    assert all(len(r["results"]) == len(names) for r in there["grids"])
    out = tmp_path / "t.json"
    args = ["bench", "transmittance", str(path), "--quick", "--rays", "16", "--estimators",
            "ratio,auto", "--json", str(out), "--scheduler", c.scheduler_address]
    for d in small:
        args += ["-D", d]
    r = _cli(args, tmp_path)
    assert r.returncode == 0, r.stderr
    assert "running as tasks on the cluster" in r.stdout
    assert len(json.loads(out.read_text())["grids"]) == 2


def test_ctrl_c_at_the_terminal_stops_a_local_cluster_render(tmp_path):
    """A Ctrl-C typed at the terminal reaches the whole process group, the local cluster's
    workers too. Found by an outside workflow test: the workers died of it mid-task, under
    screens of tracebacks, and the client could wait for them for ever. They now ignore
    SIGINT: the render stops after its current chunk, writes the partial image and exits
    with 130, with nothing else on the terminal."""
    import pty
    import select
    from cli_subprocess import volmc_cli, volmc_env
    from volmc.scene.serialize import to_toml
    scene = load_scene(default_scene(), SMALL + ["render.spp=1000000"])
    (tmp_path / "s.toml").write_text(to_toml(scene.spec))
    pid, fd = pty.fork()
    if pid == 0:   # the child: the render, in the pty's process group
        os.chdir(tmp_path)
        os.execve(sys.executable, volmc_cli("render", "s.toml", "--workers", "2", "-o",
                                            "x.exr"), volmc_env())
    out, sent, t0 = b"", None, time.monotonic()
    try:
        while time.monotonic() - t0 < 240:
            if sent is None and b"volmc: started" in out:
                time.sleep(2.0)
                os.write(fd, b"\x03")            # the terminal's Ctrl-C: SIGINT to the group
                sent = time.monotonic()
            if select.select([fd], [], [], 0.2)[0]:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    break
                if not data:
                    break
                out += data
    finally:
        # The terminal closes before the process has closed its cluster and exited.
        deadline = time.monotonic() + 120
        done, status = os.waitpid(pid, os.WNOHANG)
        while not done and time.monotonic() < deadline:
            time.sleep(0.2)
            done, status = os.waitpid(pid, os.WNOHANG)
        if not done:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
    text = out.decode(errors="replace")
    assert done and sent is not None, text
    assert os.waitstatus_to_exitcode(status) == 130, text
    assert "volmc: interrupted, partial image: x.exr" in text
    assert "Traceback" not in text and "WARNING" not in text, text
    assert read_exr(tmp_path / "x.exr")[1]["partial"] == 1


# --- Robustness of cluster renders (an outside tester's reproductions): a cluster that fails
# mid-render keeps the merged samples, Ctrl-C during --workers start-up is not lost, an
# address that is not a scheduler and a scheduler without workers fail in bounded time.

def _small_scene_file(tmp_path, spp):
    from volmc.scene.serialize import to_toml
    scene = load_scene(default_scene(), SMALL + [f"render.spp={spp}"])
    (tmp_path / "s.toml").write_text(to_toml(scene.spec))
    return scene


def _thread_cluster(n_workers=1):
    """A scheduler and ``n_workers`` thread workers in this process, on loopback TCP, Dask's
    connect timeout 2 s for the client (its reconnection after losing the scheduler, the
    wait for workers)."""
    import dask
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        c = distributed.LocalCluster(n_workers=n_workers, threads_per_worker=1,
                                     processes=False, dashboard_address=":0",
                                     protocol="tcp", host="127.0.0.1")
        return c, distributed.Client(c, set_as_default=False)


@pytest.mark.parametrize("refusal", [False, True])
def test_failed_task_keeps_the_merged_chunks(tmp_path, monkeypatch, refusal):
    """A chunk whose task fails for good (here: every run of it raises; Dask's KilledWorker
    is the same to the host) ends the render with volmc's ClusterError, a VolmcError: the
    chunks merged before it are its .result (partial) and in the checkpoint, from which a
    resume gives the uninterrupted image bit for bit. Found by an outside tester: Dask's
    exception escaped the driver before the final save, losing the merged work. So does a
    worker's one-line SceneError (its memory check: a worker that joined later refused),
    which went out bare, losing the work too (a review of that change)."""
    import dask
    import volmc
    import volmc.distributed as vd
    from volmc.scene.errors import SceneError
    scene = load_scene(default_scene(), SMALL)
    spp = 1000
    chunks = chunk_schedule(64 * 48, spp)
    bad = chunks[2][0][0]   # chunks 0 and 1 merge, chunk 2 fails
    real = vd._render_task

    def failing(scene, token, backend, device, chunk, lanes, albedo):
        if chunk[0][0] == bad:
            if refusal:
                raise SceneError("s.toml", "medium.density", "on the Dask worker at x: too big")
            raise RuntimeError("simulated worker failure")
        return real(scene, token, backend, device, chunk, lanes, albedo)

    monkeypatch.setattr(vd, "_render_task", failing)
    ckpt = tmp_path / "c.npz"
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                      dashboard_address=":0") as c, \
                distributed.Client(c, set_as_default=False) as client:
            with pytest.raises(volmc.VolmcError) as info:
                volmc.render(scene, spp=spp, progress=False, client=client,
                             checkpoint=str(ckpt))
    e = info.value
    assert type(e).__name__ == "ClusterError"
    why = "a worker refused a chunk (s.toml: medium.density:" if refusal else \
        "a task of the render failed (RuntimeError: simulated worker failure)"
    assert str(e).startswith(f"volmc.render(): client: the Dask cluster failed: {why}"), str(e)
    assert f"resume='{ckpt}'" in str(e)
    done = sum(n for c in chunks[:2] for _, n in c)
    assert e.result.partial and e.result.spp == done
    monkeypatch.setattr(vd, "_render_task", real)
    whole = render(scene, backend="opencl", spp=spp, progress=False)
    resumed = render(scene, backend="opencl", spp=spp, progress=False, resume=str(ckpt))
    np.testing.assert_array_equal(resumed.film.sum, whole.film.sum)
    assert resumed.counters == whole.counters


def test_lost_scheduler_keeps_the_merged_chunks(tmp_path):
    """The scheduler goes away mid-render (closed here; the tester killed a `dask scheduler`
    with SIGKILL): the client's futures are cancelled, and the render ends with ClusterError
    carrying the chunks merged so far, checkpointed, instead of Dask's FutureCancelledError
    and nothing saved."""
    from volmc.checkpoint import load
    from volmc.scene.errors import VolmcError
    scene = load_scene(default_scene(), SMALL)
    ckpt = tmp_path / "c.npz"
    c, client = _thread_cluster()

    def close_scheduler_after_a_chunk():
        t0 = time.monotonic()
        while not ckpt.exists() and time.monotonic() - t0 < 60:
            time.sleep(0.05)
        c.sync(c.scheduler.close)

    t0 = time.monotonic()
    try:
        with pytest.raises(VolmcError, match="lost its connection to the Dask scheduler") \
                as info:
            render(scene, backend="opencl", spp=10**6, progress=False, client=client,
                   checkpoint=str(ckpt), checkpoint_every=0,
                   on_start=threading.Thread(target=close_scheduler_after_a_chunk).start)
    finally:
        client.close(timeout=5)
        try:   # its scheduler is gone: closing it times out
            c.close(timeout=2)
        except TimeoutError:
            pass
    assert time.monotonic() - t0 < 30
    res = info.value.result
    assert res.partial and 0 < res.film.spp < 10**6
    film = load(str(ckpt), scene, "opencl", res.techniques.get("lanes") and
                int(res.techniques["lanes"]), False)[0]
    assert film.spp == res.film.spp
    np.testing.assert_array_equal(film.sum, res.film.sum)


def _children(pid, pattern="spawn_main"):
    r = subprocess.run(["pgrep", "-P", str(pid), "-f", pattern], capture_output=True,
                       text=True)
    return [int(p) for p in r.stdout.split()]


def _popen_cli(args, cwd, **env_extra):
    from cli_subprocess import volmc_cli, volmc_env
    env = volmc_env()
    env.update(env_extra)
    return subprocess.Popen(volmc_cli(*args), cwd=cwd, env=env, stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, start_new_session=True)


def test_cli_killed_worker_writes_the_partial_image_and_checkpoint(tmp_path):
    """volmc render --workers 1 --checkpoint, and its worker killed with SIGKILL while it
    renders (Dask allowed no failure here, so the first death is Dask's KilledWorker, as
    repeated kills were for the tester): the partial EXR and the checkpoint are written and
    the one-line error (exit status 2) says how to resume, with no traceback."""
    _small_scene_file(tmp_path, 10**6)
    p = _popen_cli(["render", "s.toml", "--quiet", "--workers", "1", "-o", "x.exr",
                    "--checkpoint", "c.npz", "--checkpoint-every", "0"], tmp_path,
                   DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="0")
    try:
        t0 = time.monotonic()
        while not (tmp_path / "c.npz").exists() and time.monotonic() - t0 < 60:
            time.sleep(0.05)
        for pid in _children(p.pid):
            os.kill(pid, signal.SIGKILL)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    lines = err.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, err
    assert lines[0].startswith("volmc: error: command line: --workers: the Dask cluster "
                               "failed: the workers running a chunk of the render kept dying "
                               "(Dask's KilledWorker"), err
    assert lines[0].endswith("(marked partial) and c.npz: continue with --resume c.npz"), err
    img, meta = read_exr(tmp_path / "x.exr")
    assert meta["partial"] == 1 and 0 < meta["spp"] < 10**6
    assert f"the {meta['spp']} spp rendered are in x.exr" in lines[0]


def test_cli_ctrl_c_during_cluster_start_up_is_not_lost(tmp_path):
    """A Ctrl-C (SIGINT to the process group) while --workers starts its cluster: volmc used
    to ignore SIGINT then and rendered the whole image. It stops now, with exit status 130
    and nothing rendered, and the workers, which still never see a Ctrl-C, print nothing."""
    _small_scene_file(tmp_path, 64)
    p = _popen_cli(["render", "s.toml", "--workers", "2", "-o", "x.exr"], tmp_path)
    try:
        t0 = time.monotonic()
        while not _children(p.pid) and time.monotonic() - t0 < 60:
            time.sleep(0.02)
        assert _children(p.pid), "no worker process started"
        os.killpg(p.pid, signal.SIGINT)   # the workers are starting: the cluster is not up
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert "volmc: started" not in err and not (tmp_path / "x.exr").exists(), err


class _FakeScheduler:
    """A TCP listener on loopback that is not a Dask scheduler: it sends ``greeting`` to
    whoever connects (or, None, stays silent) and keeps the connection open."""

    def __init__(self, greeting):
        import socket
        self.greeting, self.conns = greeting, []
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.address = f"tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.greeting:
                try:
                    conn.sendall(self.greeting)
                except OSError:
                    pass

    def close(self):
        self.sock.close()
        for conn in self.conns:
            conn.close()


@pytest.mark.parametrize("greeting", [
    b"HTTP/1.0 200 OK\r\n\r\n" + b"x" * 100,   # frame count of exabytes: numpy MemoryError
    b"\xff" * 64,                               # ValueError of the frame header
    None,                                       # an accepting, silent listener
], ids=["http", "garbage", "silent"])
def test_address_that_is_not_a_scheduler(greeting):
    """A --scheduler / client= address where something else listens: the one-line error
    (SceneError) within Dask's connect timeout plus a margin, never a numpy traceback or
    a hang (found by an outside tester: 'Unable to allocate 2.82 EiB', and for ever)."""
    import dask
    from volmc.distributed import connect
    from volmc.scene.errors import SceneError
    fake = _FakeScheduler(greeting)
    t0 = time.monotonic()
    try:
        with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
            with pytest.raises(SceneError) as info:
                connect(scheduler=fake.address)
    finally:
        fake.close()
    assert time.monotonic() - t0 < 15
    text = str(info.value)
    assert text.startswith(f"command line: --scheduler: cannot reach the Dask scheduler "
                           f"'{fake.address}': ") and "\n" not in text, text


def test_scheduler_without_workers():
    """A scheduler with no worker: the render waits Dask's connect timeout for one, then
    fails with ClusterError (nothing rendered), where it waited for ever."""
    import volmc
    c, client = _thread_cluster(n_workers=0)
    scene = load_scene(default_scene(), SMALL)
    t0 = time.monotonic()
    try:
        import dask
        with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
            with pytest.raises(volmc.VolmcError, match="no worker joined the Dask "
                                                       "scheduler within 2 s") as info:
                volmc.render(scene, spp=8, progress=False, client=client)
    finally:
        client.close()
        c.close()
    assert time.monotonic() - t0 < 15 and info.value.result is None


def test_cli_ctrl_c_while_waiting_for_workers(tmp_path):
    """--scheduler of a scheduler without workers: a first Ctrl-C stops the wait (exit
    status 130, nothing rendered); with a short connect timeout, the wait ends in the
    one-line error with exit status 2."""
    _small_scene_file(tmp_path, 8)
    c, client = _thread_cluster(n_workers=0)
    try:
        known = len(c.scheduler.clients)
        p = _popen_cli(["render", "s.toml", "--scheduler", c.scheduler_address, "-o",
                        "x.exr"], tmp_path, DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT="60s")
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and len(c.scheduler.clients) <= known:
                time.sleep(0.05)
            time.sleep(1.0)   # connected: waiting for a worker
            os.kill(p.pid, signal.SIGINT)
            _, err = p.communicate(timeout=20)
        finally:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        assert p.returncode == 130 and "Traceback" not in err, err
        assert "volmc: started" not in err and not (tmp_path / "x.exr").exists()
        r = _cli(["render", "s.toml", "--quiet", "--scheduler", c.scheduler_address, "-o",
                  "x.exr"], tmp_path)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1, r.stderr
        assert lines[0] == ("volmc: error: command line: --scheduler: the Dask cluster "
                            "failed: no worker joined the Dask scheduler within 2 s "
                            "(distributed.comm.timeouts.connect); start one with 'dask "
                            "worker ADDRESS'"), r.stderr
    finally:
        client.close()
        c.close()


def test_a_worker_checks_its_own_memory(monkeypatch):
    """A worker holds the scene and its backend, so it checks its own memory before it
    builds them (the client checks only the film): a render that does not fit a worker is
    the one-line SceneError naming the key, not a worker swapped or killed. Found by an
    outside tester: a cluster render was never checked. The error crosses from the worker
    pickled (VolmcError.__reduce__)."""
    import volmc
    from volmc.scene.errors import SceneError
    scene = load_scene(default_scene(), ["medium.density.resolution=128",
                                         "camera.resolution=[64, 48]"])
    monkeypatch.setenv("VOLMC_MEMORY_LIMIT", "4M")   # the film fits; the 8 MiB grid does not
    c, client = _thread_cluster()
    try:
        with pytest.raises(SceneError) as info:
            volmc.render(scene, spp=4, progress=False, client=client)
    finally:
        client.close()
        c.close()
    e = info.value
    assert e.key == "medium.density" and "on the Dask worker at " in e.message, str(e)
    assert "VOLMC_MEMORY_LIMIT" in str(e)


@pytest.mark.parametrize("via", ["api", "cli"])
def test_frame_sequence_cluster_failure_writes_the_partial_frame(tmp_path, monkeypatch,
                                                                 capsys, via):
    """A frame sequence whose cluster fails in its second frame: the first frame's EXR is
    complete, the second's is written marked partial with the chunks merged before the
    failure, and the error (``volmc.render_frames``: ClusterError; ``volmc render --frames``:
    the one-line error, exit status 2) names it. Run again, the first frame is skipped and
    the second renders to the image of its single render."""
    import volmc
    import volmc.distributed as vd
    from volmc import cli
    from volmc.scene.serialize import dict_to_toml
    spp = 600
    for f in (1, 2):   # frame f's density: a block of f / 2
        g = np.zeros((8, 8, 8), np.float32)
        g[1:7, 2:6, 1:7] = 0.5 * f
        np.save(tmp_path / f"d_{f:04d}.npy", g)
    (tmp_path / "s.toml").write_text(dict_to_toml({
        "camera": {"eye": [0.0, 0.0, 4.0], "resolution": [64, 48]},
        "medium": {"bounds": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]],
                   "density": {"file": "d_{frame:04d}.npy"}, "scale": 3.0, "albedo": 0.8},
        "lights": [{"type": "environment", "radiance": 1.0}],
        "render": {"spp": spp, "seed": 3, "max_depth": 4}}))
    chunks = chunk_schedule(64 * 48, spp)
    assert len(chunks) >= 3
    bad, seen = chunks[2][0][0], []
    real = vd._render_task

    def failing(scene, token, backend, device, chunk, lanes, albedo):
        if chunk[0][0] == bad:
            seen.append(bad)
            if len(seen) > 1:   # the second frame's third chunk
                raise RuntimeError("simulated worker failure")
        return real(scene, token, backend, device, chunk, lanes, albedo)

    monkeypatch.setattr(vd, "_render_task", failing)
    monkeypatch.chdir(tmp_path)
    c, client = _thread_cluster()
    try:
        why = "the Dask cluster failed: a task of the render failed (RuntimeError: " \
              "simulated worker failure)"
        if via == "api":
            with pytest.raises(vd.ClusterError) as info:
                volmc.render_frames("s.toml", "1-2", output="s.exr", progress=False,
                                    client=client)
            msg = str(info.value)
            assert msg.startswith(f"volmc.render_frames(): client: {why}"), msg
        else:
            status = cli.main(["render", "s.toml", "--frames", "1-2", "-o", "s.exr",
                               "--quiet", "--scheduler", c.scheduler_address])
            lines = capsys.readouterr().err.strip().splitlines()
            assert status == 2 and len(lines) == 1, lines
            msg = lines[0]
            assert msg.startswith(f"volmc: error: command line: --scheduler: {why}"), msg
            assert msg.endswith("run the command again to render it"), msg
        partial, meta2 = read_exr(tmp_path / "s.0002.exr", alpha=True)
        assert "frame 2 is written, marked partial, to " in msg and "s.0002.exr" in msg
        done = sum(n for chunk in chunks[:2] for _, n in chunk)
        assert meta2["partial"] == 1 and meta2["frame"] == 2 and meta2["spp"] == done
        first, meta1 = read_exr(tmp_path / "s.0001.exr", alpha=True)
        assert meta1["partial"] == 0 and meta1["spp"] == spp
        monkeypatch.setattr(vd, "_render_task", real)
        mtime = (tmp_path / "s.0001.exr").stat().st_mtime_ns
        volmc.render_frames("s.toml", "1-2", output="s.exr", progress=False, client=client)
        assert (tmp_path / "s.0001.exr").stat().st_mtime_ns == mtime   # complete: skipped
    finally:
        client.close(timeout=5)
        c.close(timeout=5)
    for f in (1, 2):
        one = volmc.render(volmc.load_scene("s.toml", frame=f), progress=False)
        img, meta = read_exr(tmp_path / f"s.{f:04d}.exr", alpha=True)
        np.testing.assert_array_equal(img[..., :3], one.image)
        assert meta["partial"] == 0

"""One fit across processes: multi-controller JAX, frames sharded over every process.

Every process runs the same program (``jax.distributed``: one coordinator, K
processes; on CPU the collectives go through gloo). Each reads only its own
block of frames (:func:`row_block`) and hands it to
``jax.make_array_from_process_local_data``: the result is ONE global
``jax.Array`` of all frames, sharded by rows over a mesh of every process's
devices. The unchanged jitted solver (:func:`rhythmic_jax.solvers.newton.newton_fit`)
then runs on it: each product with the frames (gradient, Hessian-vector
products in CG, the line search's sums, the preconditioner's ``Xa^T Xa``, the
training errors) is computed on local frames, and XLA inserts the all-reduces.
Blocks are padded to equal sizes with zero rows whose bias is 0 too (they
add nothing to any product; the solver takes their constant off the objective).

The streamed solver (:mod:`rhythmic_jax.solvers.streamed`) takes the same Newton
steps (:func:`rhythmic_jax.solvers.newton_cg.newton_solver`) and reduces every
pass's sums with :func:`allreduce`.

Launch: ``rhythmic-jax fit ref.npy --out m --processes 2`` on one machine, or
on each of K hosts ``rhythmic-jax fit ref.npy --out m --coordinator HOST:PORT
--num-processes K --process-id i`` (the coordinator is process 0's host).

Names: n frames, d features, p templates, K processes.
"""

from __future__ import annotations

import functools
import logging
import os
import re
import socket
import subprocess
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.periods import period_offsets
from rhythmic_jax.solvers.newton import NewtonConfig, NewtonInfo, newton_fit
from rhythmic_jax.solvers.objective import Templates, targets

__all__ = [
    "Cluster",
    "allreduce",
    "fit_newton",
    "frame_mesh",
    "global_rows",
    "initialize",
    "launch_local",
    "row_block",
]

log = logging.getLogger(__name__)
FRAMES = "frames"
# names the launcher's process id in its workers' environment (read there by
# rhythmic_jax.app.signals, which this layer cannot import)
LAUNCHER_ENV = "RHYTHMIC_JAX_LAUNCHER"
_DEFAULT = NewtonConfig()


@dataclass(frozen=True)
class Cluster:
    """Where this process sits: the coordinator ``HOST:PORT``, K, and its index."""

    coordinator: str
    num_processes: int
    process_id: int

    def __post_init__(self):
        host, _, port = self.coordinator.rpartition(":")
        if not host or not port.isdigit():
            raise InputError(
                f"{{opt:coordinator}} must be HOST:PORT, got {self.coordinator!r}"
            )
        if self.num_processes < 1 or not 0 <= self.process_id < self.num_processes:
            raise InputError(
                f"{{opt:process_id}} must be in 0 .. {self.num_processes - 1}, "
                f"got {self.process_id}"
            )


def initialize(cluster: Cluster) -> None:
    """Join the cluster (call before any other JAX work in the process)."""
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        cluster.coordinator, cluster.num_processes, cluster.process_id
    )
    log.info("process %d of %d: devices %s", jax.process_index(),
             jax.process_count(), jax.devices())  # fmt: skip


def row_block(n: int, k: int, i: int) -> tuple[int, int]:
    """Process i's rows ``start, stop`` of n split into k contiguous blocks."""
    per = -(-n // k)
    return min(n, i * per), min(n, (i + 1) * per)


def frame_mesh() -> Mesh:
    """A one-axis mesh (``frames``) over every process's devices."""
    return Mesh(np.asarray(jax.devices()), (FRAMES,))


def global_rows(local: np.ndarray, rows: int, mesh: Mesh) -> jax.Array:
    """One global array from every process's block (m, ...), each padded with
    zeros to ``rows`` (a multiple of its local device count): shape (K rows, ...)."""
    pad = np.zeros((rows - len(local), *local.shape[1:]), local.dtype)
    block = np.concatenate([local, pad])
    spec = P(FRAMES, *([None] * (block.ndim - 1)))
    shape = (rows * jax.process_count(), *block.shape[1:])
    return jax.make_array_from_process_local_data(
        NamedSharding(mesh, spec), block, shape
    )


def padded_rows(n: int) -> int:
    """Rows per process for n frames: the largest block, rounded up to a multiple
    of the local device count."""
    per = -(-n // jax.process_count())
    local = jax.local_device_count()
    return -(-per // local) * local


def allreduce(tree):
    """Sum a tree of host arrays over the processes (identity for one process)."""
    if jax.process_count() == 1:
        return tree
    leaves, treedef = jax.tree.flatten(tree)
    flat = np.concatenate([np.ravel(np.asarray(v, np.float64)) for v in leaves])
    mesh = Mesh(np.asarray(jax.devices()), ("p",))
    per = jax.local_device_count()
    block = np.zeros((per, flat.size))
    block[0] = flat  # the process's sum on its first device, zeros on the others
    with jax.enable_x64(True):
        arr = jax.make_array_from_process_local_data(
            NamedSharding(mesh, P("p", None)), block, (len(jax.devices()), flat.size)
        )
        total = np.asarray(_sum0(arr))
    out, at = [], 0
    for v in leaves:
        size = int(np.size(v))
        out.append(total[at : at + size].reshape(np.shape(v)))
        at += size
    return jax.tree.unflatten(treedef, out)


@jit
def _sum0(a: jax.Array) -> jax.Array:
    return jnp.sum(a, axis=0)


@functools.partial(jit, static_argnames=("periods",))
def _targets(labels: jax.Array, periods: tuple[int, ...]) -> jax.Array:
    return targets(labels, periods)


@functools.partial(jit, static_argnames=("periods",))
def _wrong(w, b, x, labels, valid, periods: tuple[int, ...]) -> jax.Array:
    """(k,) frames whose argmax phase is wrong, per period (padding not counted)."""
    s = jnp.matmul(x, w, precision="highest") + b[None, :]
    out = []
    for off, t in zip(period_offsets(periods), periods, strict=True):
        pred = jnp.argmax(s[:, off : off + t], axis=1)
        out.append(jnp.sum((pred != labels % t) * valid))
    return jnp.stack(out)


def fit_newton(
    x_local: np.ndarray,
    labels_local: np.ndarray,
    n: int,
    periods: Sequence[int],
    c: float,
    config: NewtonConfig = _DEFAULT,
    progress: bool = True,
) -> tuple[Templates, np.ndarray, NewtonInfo]:
    """Newton's solve of every template over the frames of all processes.

    Args:
      x_local: (m, d) this process's frames; labels_local: (m,) their places.
      n: frames over all processes; periods: the candidate periods; c: C.

    Returns:
      Templates (numpy, the same on every process), the (k,) training error of
      every period over all frames, and the solver's info.
    """
    mesh = frame_mesh()
    rows = padded_rows(n)
    x = global_rows(np.asarray(x_local, np.float32), rows, mesh)
    labels = global_rows(np.asarray(labels_local, np.int32), rows, mesh)
    valid = global_rows(np.ones(len(x_local), np.float32), rows, mesh)
    periods = tuple(int(t) for t in periods)
    y = _targets(labels, periods)
    params, info = newton_fit(
        x, y, c, config, progress=progress and jax.process_index() == 0, bias=valid
    )
    wrong = np.asarray(_wrong(params.w, params.b, x, labels, valid, periods))
    w, b = np.asarray(params.w), np.asarray(params.b)
    return Templates(w, b), wrong / n, info


# --------------------------------------------------------------------- launch


def free_port() -> int:
    """A TCP port free on this machine now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch_local(argv: Sequence[str], k: int) -> int:
    """Run ``rhythmic-jax *argv`` as k processes of one cluster on this machine.

    Process 0's progress reaches the terminal as it runs; every process's error
    output is kept apart (:class:`_Relay`), so a failure is said once, as one
    line, whichever process saw it and however many did: raises InputError with
    the line of a process that refused its input (exit status 2), else of the
    one that failed first. A process that crashed (a traceback) has its output
    written out whole and its status returned. When one fails the others are
    stopped. Returns 0 when all succeeded.

    The workers run in a process group of their own, so a terminal's Ctrl-C
    reaches the launcher alone, and each learns the launcher's id
    (:data:`LAUNCHER_ENV`) to die with it however it ends, killed included
    (:mod:`rhythmic_jax.app.signals`): no worker goes on to write the map.
    """
    if k < 1:
        raise InputError(f"{{opt:processes}} must be >= 1, got {k}")
    port = free_port()
    cluster = ["--coordinator", f"127.0.0.1:{port}", "--num-processes", str(k)]
    env = dict(os.environ)
    env.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    env[LAUNCHER_ENV] = str(os.getpid())
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "rhythmic_jax.app.cli",
                *argv,
                *cluster,
                "--process-id",
                str(i),
            ],
            stdout=subprocess.PIPE if i == 0 else subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env,
            process_group=0,
        )  # fmt: skip
        for i in range(k)
    ]
    relays = [
        _Relay(p.stderr, sys.stderr if i == 0 else None) for i, p in enumerate(procs)
    ]
    output = _Relay(procs[0].stdout, sys.stdout, hold=False)
    first = None  # the rank that failed first
    try:
        pending = list(procs)
        while pending:
            for proc in list(pending):
                try:
                    rc = proc.wait(timeout=0.2)
                except subprocess.TimeoutExpired:
                    continue
                pending.remove(proc)
                if rc != 0 and first is None:
                    first = procs.index(proc)
                    for other in pending:
                        other.terminate()
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        for relay in (output, *relays):
            relay.join()
    if first is None:
        return 0
    codes = [p.returncode for p in procs]
    cause = next((i for i, rc in enumerate(codes) if rc == 2), first)
    line = relays[cause].error_line()
    if line is not None:
        raise InputError(line)
    rc = codes[cause]
    if rc < 0:
        raise InputError(f"fit process {cause} was killed (signal {-rc})")
    sys.stderr.write(relays[cause].held())
    return rc


class _Relay:
    """A worker's output, read by a thread and passed on to ``out`` as it comes
    (process 0's results and progress; None: nothing passed on), gloo's
    connection notes left out. With ``hold``, from its first error line or
    traceback on it is held back instead, for the launcher to say once."""

    def __init__(self, pipe, out, hold: bool = True):
        self._pipe, self._out, self._hold = pipe, out, hold
        self._held: list[str] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        holding, rest = self._out is None, ""
        for raw in iter(lambda: self._pipe.read1(65536), b""):
            rest += raw.decode(errors="replace")
            *pieces, rest = re.split(r"(?<=[\r\n])", rest)
            for piece in pieces:
                if piece.startswith("[Gloo] "):
                    continue
                if self._hold and (
                    piece.startswith("Traceback (") or _ERROR.match(piece)
                ):
                    holding = True
                if holding:
                    self._held.append(piece)
                else:
                    self._out.write(piece)
                    self._out.flush()
        if holding or not rest:
            self._held.append(rest)
        else:
            self._out.write(rest)
            self._out.flush()
        self._pipe.close()

    def join(self) -> None:
        self._thread.join()

    def held(self) -> str:
        """What was held back, whole."""
        return "".join(self._held)

    def error_line(self) -> str | None:
        """The last ``rhythmic-jax ...: error: ...`` line held back, without
        the command's name; None where there is none."""
        for line in reversed(self.held().splitlines()):
            found = _ERROR.match(line)
            if found:
                return found.group(1)
        return None


_ERROR = re.compile(r"rhythmic-jax [\w-]+: error: (.*?)\s*$")

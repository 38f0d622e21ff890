"""The mapper in its own process (``mapper_process: true`` with ``parallel: true``; ESLAM's design).

In parallel mode the tracker and the mapper are two threads of one Python process, and every torch op and numba
kernel call takes the interpreter's lock. At ``tum/fr1_rpy-cpu-fast`` (small, many ops) a warm mapping call beside a
tracking thread took 65 % longer than alone and a tracking call beside a mapping thread 59 %, against 0 % and 12 %
beside a separate process (``benchmarks/thread_contention.py`` at f5975fa, since retired).
Here the mapping calls run in a child process instead, on a replica of the map and the keyframes that the parent
keeps in step:

* the child starts at the first call from the parent's map, keyframes, mapping random stream and carried Adam
  moments (``mapping.optimizer_state: persistent``) as they are then (a fresh run's initial map, or a resumed
  run's);
* every call sends the job (frame, pose, flags) and gets back what :class:`slam.engine.map_worker.MapWorker` needs:
  the result, the map the call left (the snapshot the thread mode takes too), the random stream's state and the
  keyframes' poses (BA refines them); the parent then makes the same keyframe store change the child made, so both
  stores hold the same keyframes with the same poses, and its own map becomes the child's. The carried moments
  (twice the map's size) stay in the child until a checkpoint asks for them (:meth:`MapProcess.moments`);
* a growth of the map's box is sent between calls and applied to the replica by the same samples (the carried
  moments reset on both sides).

The results are the thread mode's, bit for bit (same code, same inputs, same order; tested), so everything the
schedule promises holds. Messages are pickled by value over a pipe (no shared-memory handles to leak on long runs;
a map is a few MB), its tensors as numpy arrays (:mod:`slam.engine.wire`). The child is spawned when the worker is
made, and it imports its modules and rehearses its calls (:mod:`slam.engine.rehearsal`) before the first frame.
The child ignores SIGINT and SIGTERM: a Ctrl-C reaches the whole foreground process group, and so does a stop by
Slurm's ``scancel``, systemd or ``kill -TERM -PGID``, and each is the parent's to handle (it finishes the frame and
waits for the call in flight before saving). A child that dies (killed, out of memory) or raises makes every later
call of this object raise :class:`slam.errors.SlamRunError` naming the mapping process (the child's traceback in
its ``detail``): the replica is lost, so the run stops and resumes from its last checkpoint.
"""

from __future__ import annotations

import multiprocessing
import pickle
import queue
import signal
import threading

import torch

from slam.engine.map_child import serve
from slam.engine.mapper import MapMoments
from slam.errors import SlamRunError
from slam.engine.wire import pack_state, unpack_state

__all__ = ["MapProcess"]


def _exit_reason(code: int | None) -> str:
    """Words for a child's exit code: a signal (``-N``) is named, with the usual cause of a SIGKILL."""
    if code is None:
        return "still running, its pipe closed"
    if code < 0:
        name = signal.Signals(-code).name if -code in signal.valid_signals() else f"signal {-code}"
        why = ": killed, perhaps by the system when memory ran out" if -code == signal.SIGKILL else ""
        return f"{name}{why}"
    return f"exit code {code}"


class _Call:
    """A submitted call: ``result()`` waits for it (and, in order, for every earlier one) like a future."""

    def __init__(self, owner: "MapProcess", job):
        self.owner, self.job, self._done = owner, job, None

    def done(self) -> bool:
        """Whether the call's reply has arrived (replies come in order: one for each call sent before it too)."""
        if self._done is not None:
            return True
        waiting = self.owner._waiting
        return self in waiting and self.owner._replies.qsize() > waiting.index(self)

    def result(self):
        while self._done is None:
            self.owner._receive()  # raises once the child has failed, for this call and every later one
        return self._done


class MapProcess:
    """The child process and the pipe to it, for :class:`slam.engine.map_worker.MapWorker`.

    Args:
        cfg, intrinsics, device: the run's config, working-image intrinsics and device (the child's map lives there).
        arrived: called in the parent with each finished call's ``(job, reply)`` in submission order, before its
            ``result()`` returns: the worker mirrors the child's map, keyframes and random stream there.
    """

    def __init__(self, cfg, intrinsics, device, arrived):
        self.cfg, self.intr, self.device, self.arrived = cfg, intrinsics, str(device), arrived
        self._proc = self._conn = self._reader = self._writer = None
        self._replica = self._hello = False
        self._replies: queue.Queue = queue.Queue()
        self._outbox: queue.Queue = queue.Queue()
        self._waiting: list[_Call] = []
        self._failed: SlamRunError | None = None  # the child died or raised: every later request raises this

    @property
    def started(self) -> bool:
        """Whether the child holds a replica (:meth:`start`)."""
        return self._proc is not None and self._replica

    def spawn(self, rehearsal: tuple | None = None) -> None:
        """Start the child process (no-op when it runs already); it imports what it runs (about 2 s) and rehearses
        its calls on ``rehearsal`` ``(aabb, color, depth, pose)`` (CPU tensors; None: no rehearsal) while the
        parent goes on, until :meth:`ready`. The worker does this when it is made, so the loop's first frames do
        not wait for it, as they do not wait for the imports of the thread mode."""
        if self._proc is not None:
            return
        ctx = multiprocessing.get_context("spawn")  # a fork would copy the parent's threads' locks mid-use
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=serve, args=(child, self.cfg, self.intr, self.device, rehearsal),
                                 name="lrslam-map", daemon=True)
        self._proc.start()
        child.close()
        # the pipe is read and written on threads of their own: a map or a frame is larger than the pipe's buffer,
        # so a write waits until the other side reads, which the child does only between calls (the tracker would
        # wait for the call in flight at every submit), and two writers facing each other would wait forever
        self._replies, self._outbox = queue.Queue(), queue.Queue()
        self._reader = threading.Thread(target=self._read, args=(self._conn, self._replies), name="lrslam-map-in",
                                        daemon=True)
        self._writer = threading.Thread(target=self._write, args=(self._conn, self._outbox), name="lrslam-map-out",
                                        daemon=True)
        self._reader.start()
        self._writer.start()
        self._replica, self._hello = False, False

    def ready(self) -> None:
        """Wait until the spawned child has imported its modules and rehearsed its calls."""
        if self._proc is not None and not self._hello:
            kind, _ = self._recv()
            if kind != "hello":
                raise RuntimeError(f"the mapping process answered {kind!r} where 'hello' was due")
            self._hello = True

    def start(self, scene, keyframes, generator: torch.Generator, moments: MapMoments | None = None) -> None:
        """Give the child (spawned first if needed) a replica of ``scene``, ``keyframes``, ``generator`` and the
        carried Adam ``moments`` as they are now."""
        self.spawn()
        self.ready()
        kfs = [(kf.index, *kf.images(), kf.pose.clone()) for kf in keyframes.frames]
        state = {name: t.detach().cpu() for name, t in scene.state_dict().items()}
        self._send("init", {"aabb": scene.aabb.detach().cpu(), "scene": state, "keyframes": kfs,
                            "gen": generator.get_state(), "moments": (moments or MapMoments()).cpu_state()})
        self._expect("ready")
        self._replica = True

    def submit(self, job) -> _Call:
        """Queue a mapping call (a :class:`slam.engine.map_call.MapJob`; its images travel on the CPU)."""
        call = _Call(self, job)
        images = pack_state({"color": job.color, "depth": job.depth})
        self._send("map", (job.k, images["color"], images["depth"], job.pose.cpu(), job.first, job.keyframe,
                           job.iters))
        self._waiting.append(call)
        return call

    def moments(self) -> dict | None:
        """The carried Adam moments the child holds after every call sent so far (its ``MapMoments.state``, CPU
        tensors; None: none carried). Asked for by checkpoints only: they are as large as the map twice over, and
        sending them with every call's map cost the loop more than the map itself."""
        self._send("moments", None)
        body = self._expect("moments")
        return None if body is None else {name: unpack_state(st) for name, st in body.items()}

    def grow(self, pads) -> None:
        """Grow the replica (every call submitted before has finished: the worker waited)."""
        self._send("grow", pads)
        self._expect("grown")

    def close(self, abort: bool = False) -> None:
        """End the child: after its queued calls, or at once (``abort``: their work is lost)."""
        if self._proc is None:
            return
        if abort or self._failed is not None:
            self._proc.kill()  # it ignores SIGTERM (the process group's stop is the parent's to handle)
        else:
            self._send("close", None)  # after the calls queued, as the thread's pool finishes them
        self._proc.join(timeout=None if not abort else 5)
        self._conn.close()
        self._outbox.put(None)
        self._writer.join(timeout=5)
        self._reader.join(timeout=5)
        self._proc = self._conn = self._reader = self._writer = None
        self._waiting = []
        self._replica = self._hello = False
        self._failed = None

    # ------------------------------------------------------------------------------------------------- pipe
    def _send(self, kind: str, body) -> None:
        self._outbox.put(pickle.dumps((kind, body), protocol=pickle.HIGHEST_PROTOCOL))

    @staticmethod
    def _write(conn, outbox: queue.Queue) -> None:
        while (data := outbox.get()) is not None:
            try:
                conn.send_bytes(data)
            except OSError:  # the child is gone: the reader reports it
                return

    @staticmethod
    def _read(conn, replies: queue.Queue) -> None:
        while True:
            try:
                replies.put(conn.recv_bytes())
            except (EOFError, OSError):
                replies.put(None)
                return

    def _recv(self):
        if self._failed is not None:
            raise self._failed
        data = self._replies.get()
        if data is None:  # the reader saw the pipe close (a reply cut off mid-message too)
            self._proc.join(timeout=5)
            self._fail(f"the mapping process (pid {self._proc.pid}) ended unexpectedly "
                       f"({_exit_reason(self._proc.exitcode)})")
        kind, body = pickle.loads(data)
        if kind == "error":
            last = body.strip().splitlines()[-1] if body.strip() else "no message"
            self._fail(f"the mapping process (pid {self._proc.pid}) failed: {last}", body)
        return kind, body

    def _fail(self, message: str, detail: str = ""):
        """Stop using the child: its replica is lost or half-updated, so no later reply can be paired with a call."""
        self._failed = SlamRunError(message, detail)
        self._waiting = []
        raise self._failed

    def _expect(self, what: str):
        """Wait for the reply ``what`` (to the message just sent) and return its body."""
        while self._waiting:  # replies come in order: calls sent before this message answer first
            self._receive()
        kind, body = self._recv()
        if kind != what:
            raise RuntimeError(f"the mapping process answered {kind!r} where {what!r} was due")
        return body

    def _receive(self) -> None:
        if self._failed is not None:
            raise self._failed
        call = self._waiting[0]
        kind, body = self._recv()
        if kind != "done":
            raise RuntimeError(f"the mapping process answered {kind!r} where a mapping call was due")
        self._waiting.pop(0)
        call._done = self.arrived(call.job, body)

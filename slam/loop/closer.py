"""Loop closure beside the tracker: :class:`LoopCloser` takes every frame's pose, keeps a loop keyframe where the
camera has moved, and a worker thread extracts its features, finds candidates by appearance and by geometry,
and verifies them; at the end :meth:`LoopCloser.close` optimises the pose graph and corrects every frame.

The worker handles keyframes in their order and each result depends on the keyframes before it only, so the loops
found are the same however the thread is scheduled, and a checkpoint (:meth:`state_dict`, after :meth:`wait`)
resumes to the same result. Nothing here changes the tracker's poses or the map while the run goes on."""

from __future__ import annotations

import logging
import queue
import threading
from collections import Counter

import numpy as np

from slam.core.pose import pose_gap
from slam.loop.correct import correct_frames
from slam.loop.features import KeyframeFeatures, extract
from slam.loop.graph import Edge, odometry_sigmas, optimize
from slam.loop.verify import VerifyLimits, match, verify
from slam.loop.vocabulary import Vocabulary

log = logging.getLogger("slam")

#: sigmas of a verified loop edge (rotation radians x3, translation metres x3): ICP on depth, about 1 cm and 0.5 deg
LOOP_SIGMAS = np.array([0.01] * 3 + [0.01] * 3)


class LoopCloser:
    """Loop detection over a run's frames (``cfg``: a :class:`slam.config.LoopsConfig`; ``intrinsics`` of the
    working image; ``seed``: RANSAC's and k-means' draws)."""

    def __init__(self, cfg, intrinsics, seed: int = 0):
        self.cfg, self.intr, self.seed = cfg, intrinsics, seed
        self.limits = VerifyLimits(min_inliers=cfg.min_inliers, min_inlier_share=cfg.min_inlier_share,
                                   reprojection_px=cfg.reprojection_px, max_icp_rms=cfg.max_icp_rms,
                                   min_overlap=cfg.min_overlap, max_disagreement_m=cfg.max_disagreement_m,
                                   max_disagreement_deg=cfg.max_disagreement_deg)
        self.keyframes: list[KeyframeFeatures] = []
        self._path: list[float] = []  # the keyframes' path length from the first, metres (the drift bound grows with it)
        self.hists: list[np.ndarray | None] = []
        self.vocab: Vocabulary | None = None
        self.loops: list[dict] = []
        self.rejected: Counter = Counter()
        self.last_pose: np.ndarray | None = None
        self.error = ""
        self._queue: queue.Queue = queue.Queue()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------------------------------------ the run
    def offer(self, k: int, color, depth, pose: np.ndarray, trusted: bool) -> bool:
        """Frame ``k`` (``color [H, W, 3]`` in [0, 1], ``depth [H, W]`` metres, torch or numpy; ``pose [4, 4]``
        camera-to-world) after tracking: a loop keyframe when trusted, with depth, and moved or turned enough
        since the last one; queued for the worker (returns at once). Returns whether it became a keyframe."""
        if not trusted or depth is None or self.error:
            return False
        pose = np.asarray(pose, np.float64)
        if self.last_pose is not None:
            dt, dr = pose_gap(self.last_pose, pose)
            if dt < self.cfg.keyframe_distance and dr < self.cfg.keyframe_angle:
                return False
        self.last_pose = pose
        to_np = (lambda x: x.detach().cpu().float().numpy()) if hasattr(x := depth, "detach") else np.asarray
        self._queue.put((k, to_np(color), to_np(depth), pose))
        if self._thread is None:
            self._thread = threading.Thread(target=self._work, name="lrslam-loops", daemon=True)
            self._thread.start()
        return True

    def wait(self) -> None:
        """Until every keyframe offered so far is handled."""
        if self._thread is not None:
            self._queue.join()

    def close(self) -> None:
        """Stop the worker (what it has not handled is dropped). Safe to call twice."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
            self._thread = None

    def _work(self) -> None:
        import cv2

        cv2.setNumThreads(1)  # the tracker and the mapper own the cores; this thread is a guest
        while True:
            item = self._queue.get()
            try:
                if item is None:
                    return
                if not self.error:
                    self.add_keyframe(*item)
            except Exception as exc:  # loop closure must never take the run down: it stops, the run goes on
                self.error = f"{type(exc).__name__}: {exc}"
                log.warning("loop closure stopped at frame position %d: %s", item[0], self.error)
            finally:
                self._queue.task_done()

    # ---------------------------------------------------------------------------------------- one keyframe
    def add_keyframe(self, k: int, color: np.ndarray, depth: np.ndarray, pose: np.ndarray) -> dict | None:
        """Extract keyframe ``k``'s features, look for its loop; returns the accepted loop or None."""
        cfg = self.cfg
        q = extract(k, pose, color, depth, self.intr, cfg.features)
        self._add(q)
        self.hists.append(self.vocab.histogram(q.descriptors) if self.vocab is not None else None)
        if self.vocab is None and self.keyframes[0].k <= k - cfg.min_gap_frames:
            self.vocab = self._learn_vocabulary()
            if self.vocab is not None:
                self.hists = [self.vocab.histogram(f.descriptors) for f in self.keyframes]
        for j in self.candidates(len(self.keyframes) - 1):
            c = self.keyframes[j]
            v = verify(q, c, self.intr, self.limits, seed=self.seed * 1_000_003 + k * 1009 + c.k)
            if not v.ok:
                self.rejected[v.reason] += 1
                continue
            odo_t, odo_r = pose_gap(np.linalg.inv(c.pose) @ q.pose, v.rel)
            loop = {"query": k, "match": c.k, "query_kf": len(self.keyframes) - 1, "match_kf": j,
                    "rel": v.rel, **v.evidence(), "odometry_gap_m": round(odo_t, 4), "odometry_gap_deg": round(odo_r, 3)}
            self.loops.append(loop)
            return loop
        return None

    def _learn_vocabulary(self) -> Vocabulary | None:
        """The vocabulary over the first ``vocabulary_after`` keyframes, or the first more that hold ``words``
        descriptors (None while none do).

        Learned only once a keyframe is ``min_gap_frames`` older than the newest, the first moment a candidate can
        exist: before it the words rank nothing, and the k-means (0.4 s of the tracker's core on a 125-frame fr1_rpy
        window that never reaches a candidate) would be spent for nothing. The prefix is the one an eager vocabulary
        would have been learned from, so the loops are the same whenever it is learned."""
        cfg = self.cfg
        counts = np.cumsum([len(f.descriptors) for f in self.keyframes])
        ready = np.flatnonzero((np.arange(1, len(counts) + 1) >= cfg.vocabulary_after) & (counts >= cfg.words))
        if not len(ready):
            return None
        return Vocabulary.learn([f.descriptors for f in self.keyframes[: ready[0] + 1]], cfg.words, self.seed)

    def _add(self, f: KeyframeFeatures) -> None:
        """Append keyframe ``f`` and its path length from the first (metres; the drift bound grows with it)."""
        step = float(np.linalg.norm(f.pose[:3, 3] - self.keyframes[-1].pose[:3, 3])) if self.keyframes else 0.0
        self._path.append(self._path[-1] + step if self._path else 0.0)
        self.keyframes.append(f)

    def candidates(self, i: int) -> list[int]:
        """Keyframe positions to verify for keyframe ``i``: the best word histograms, then the nearest poses within
        the drift bound, each at least ``min_gap_frames`` older; no repeats."""
        cfg, q = self.cfg, self.keyframes[i]
        old = [j for j in range(i) if self.keyframes[j].k <= q.k - cfg.min_gap_frames]
        if not old:
            return []
        out: list[int] = []
        if self.hists[i] is not None:
            s = np.array([float(self.hists[j] @ self.hists[i]) for j in old])
            short = [old[o] for o in np.argsort(-s, kind="stable")[: cfg.shortlist] if s[o] > 0]
            # the words shortlist places; feature matches (about a millisecond each) rank them
            hits = [len(match(q, self.keyframes[j], self.limits.ratio)) for j in short]
            out += [short[o] for o in np.argsort(-np.array(hits), kind="stable")[: cfg.candidates]]
        olds = np.array(old)
        poses = np.stack([self.keyframes[j].pose for j in old])
        gap = np.linalg.norm(poses[:, :3, 3] - q.pose[:3, 3], axis=1)
        # trace(R_j^T R_q) = 1 + 2 cos(turn): the turn is under 60 degrees where it exceeds 2
        facing = np.einsum("nab,ab->n", poses[:, :3, :3], q.pose[:3, :3]) > 2.0
        path = np.asarray(self._path)
        reach = cfg.search_radius + cfg.drift_per_metre * (path[i] - path[olds])
        near = np.flatnonzero(facing & (gap <= reach))
        out += [int(olds[o]) for o in near[np.argsort(gap[near], kind="stable")][: cfg.candidates]
                if olds[o] not in out]
        return out

    # ------------------------------------------------------------------------------------------------ the end
    def close_loops(self, poses: np.ndarray, trusted: list[bool]) -> tuple[np.ndarray, dict]:
        """The pose graph over the loop keyframes with the run's final poses ``[N, 4, 4]`` (camera-to-world of
        every processed frame) and the guard's ``trusted`` flags; returns the corrected ``[N, 4, 4]`` and a summary
        (JSON-ready). Without an accepted loop the poses come back unchanged."""
        self.wait()
        summary = {"keyframes": len(self.keyframes), "loops": len(self.loops), "rejected": dict(self.rejected),
                   "candidates_tried": len(self.loops) + sum(self.rejected.values()),
                   "accepted": [{**{k: v for k, v in lp.items() if k != "rel"},
                                 "relative_pose": np.round(lp["rel"], 6).tolist()} for lp in self.loops]}
        if self.error:
            summary["error"] = self.error
        poses = np.asarray(poses, np.float64)
        keys = [f.k for f in self.keyframes if f.k < len(poses)]
        if not self.loops or len(keys) < 2:
            return poses.copy(), summary
        before = poses[keys]
        edges = []
        for a in range(len(keys) - 1):
            rel = np.linalg.inv(before[a]) @ before[a + 1]
            ok = all(trusted[keys[a] + 1: keys[a + 1] + 1])
            edges.append(Edge(a, a + 1, rel, odometry_sigmas(rel, ok, untrusted_scale=self.cfg.untrusted_scale)))
        edges += [Edge(lp["match_kf"], lp["query_kf"], lp["rel"], LOOP_SIGMAS)
                  for lp in self.loops if lp["query_kf"] < len(keys)]
        after = optimize(before, edges)
        out = correct_frames(poses, keys, before, after)
        moved = np.linalg.norm(out[:, :3, 3] - poses[:, :3, 3], axis=1)
        summary.update(max_correction_m=float(moved.max()), mean_correction_m=float(moved.mean()))
        return out, summary

    # ------------------------------------------------------------------------------------------- checkpoints
    def state_dict(self) -> dict:
        """Everything found so far (after :meth:`wait`): keyframes' features, the vocabulary, the loops, counts."""
        import torch

        self.wait()
        return {"keyframes": [f.state_dict() for f in self.keyframes],
                "vocab": self.vocab.state_dict() if self.vocab is not None else None,
                "loops": [{**lp, "rel": torch.from_numpy(np.asarray(lp["rel"]).copy())} for lp in self.loops],
                "rejected": dict(self.rejected), "error": self.error,
                "last_pose": None if self.last_pose is None else torch.from_numpy(self.last_pose.copy())}

    def load_state_dict(self, d: dict) -> None:
        self.keyframes, self._path = [], []
        for f in d["keyframes"]:
            self._add(KeyframeFeatures.from_state_dict(f))
        self.vocab = Vocabulary.from_state_dict(d["vocab"]) if d["vocab"] is not None else None
        self.hists = [self.vocab.histogram(f.descriptors) if self.vocab is not None else None for f in self.keyframes]
        self.loops = [{**lp, "rel": lp["rel"].numpy()} for lp in d["loops"]]
        self.rejected = Counter(d["rejected"])
        self.error = d["error"]
        self.last_pose = None if d["last_pose"] is None else d["last_pose"].numpy()


def loop_closer(cfg, intrinsics):
    """A :class:`LoopCloser` for a run's config (``cfg``: :class:`slam.config.Config`) when ``loops.enabled``, else
    None.

    Raises:
        SlamInputError: loop closure is enabled but OpenCV or gtsam is not installed (with the install command)."""
    if not cfg.loops.enabled:
        return None
    from slam._deps import install_command
    from slam.errors import SlamInputError

    for module, dist in (("cv2", "opencv-python-headless"), ("gtsam", "gtsam")):
        try:
            __import__(module)
        except ImportError:
            raise SlamInputError(f"loops.enabled needs {dist}, which is not installed; install the loops extra: "
                                 f"{install_command('loops')} (or set loops.enabled=false)") from None
    return LoopCloser(cfg.loops, intrinsics, cfg.seed)


def close_run_loops(closer: LoopCloser, state, indices, poses: np.ndarray) -> None:
    """At a run's end: the pose graph over the run's final ``poses [N, 4, 4]``; sets ``state.corrected`` and
    ``state.loop_summary`` and adds a "loop closed" event per loop (``state``: a :class:`slam.engine.state.RunState`;
    ``indices``: the dataset index of each frame position)."""
    state.corrected, state.loop_summary = closer.close_loops(poses, list(state.trusted))
    # a finished run resumed again closes its loops again: its events once, not twice
    state.events[:] = [e for e in state.events if e.get("event") != "loop closed"]
    for lp in state.loop_summary["accepted"]:
        state.events.append({"frame": int(indices[lp["query"]]), "event": "loop closed",
                             "with_frame": int(indices[lp["match"]]),
                             **{k: v for k, v in lp.items() if k not in ("query", "match")}})
    log.info("loop closure: %d loop(s) from %d candidates", state.loop_summary["loops"],
             state.loop_summary["candidates_tried"])

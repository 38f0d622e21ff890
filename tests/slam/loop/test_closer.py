"""The loop closer over real frames: loops found where the camera comes back and each within the ground truth's
accuracy, the same loops after a checkpoint and a resume, the worker's order not mattering, and a missing
dependency named."""

import numpy as np
import pytest

pytest.importorskip("cv2")
pytest.importorskip("gtsam")

from slam.config import LoopsConfig  # noqa: E402
from slam.loop.closer import LoopCloser  # noqa: E402
from slam.core.pose import pose_gap  # noqa: E402

# fr1_rpy turns in place: keyframes by angle, candidates 20 frames back (the default 150 exceeds the excerpt)
CFG = LoopsConfig(enabled=True, keyframe_angle=6.0, min_gap_frames=20, vocabulary_after=3, words=32)


def _feed(closer, rpy, ks, wait_each=False):
    frames, gt, _ = rpy
    for k in ks:
        if closer.offer(k, *frames[k], gt[k], True) and wait_each:
            closer.wait()


def test_loops_where_the_camera_returns_each_within_the_ground_truth(rpy):
    _, gt, intr = rpy
    closer = LoopCloser(CFG, intr, seed=0)
    _feed(closer, rpy, range(60))
    closer.wait()
    closer.close()
    assert len(closer.loops) >= 3, closer.rejected
    for lp in closer.loops:
        dt, dr = pose_gap(np.linalg.inv(gt[lp["match"]]) @ gt[lp["query"]], lp["rel"])
        assert dt < 0.05 and dr < 4.0, lp
        assert lp["query"] - lp["match"] >= CFG.min_gap_frames


def test_the_same_loops_after_a_resume_and_whatever_the_thread_timing(rpy):
    _, _, intr = rpy
    whole = LoopCloser(CFG, intr, seed=0)
    _feed(whole, rpy, range(60), wait_each=True)
    state = LoopCloser(CFG, intr, seed=0)
    _feed(state, rpy, range(35))
    saved = state.state_dict()
    state.close()
    resumed = LoopCloser(CFG, intr, seed=0)
    resumed.load_state_dict(saved)
    _feed(resumed, rpy, range(35, 60))
    a, b = whole.state_dict(), resumed.state_dict()
    whole.close(), resumed.close()
    assert [(lp["query"], lp["match"]) for lp in a["loops"]] == [(lp["query"], lp["match"]) for lp in b["loops"]]
    for x, y in zip(a["loops"], b["loops"]):
        assert np.array_equal(x["rel"].numpy(), y["rel"].numpy())
    assert a["rejected"] == b["rejected"]


def test_the_vocabulary_waits_for_the_first_candidate_and_learns_from_the_first_keyframes(rpy):
    """Its k-means runs once a keyframe is min_gap_frames old (before, the words rank nothing), over the prefix an
    eager vocabulary had: the first vocabulary_after keyframes."""
    from slam.loop.vocabulary import Vocabulary

    _, _, intr = rpy
    closer = LoopCloser(CFG, intr, seed=0)
    _feed(closer, rpy, range(CFG.min_gap_frames))
    closer.wait()
    assert len(closer.keyframes) >= CFG.vocabulary_after and closer.vocab is None  # the eager one had learned
    _feed(closer, rpy, range(CFG.min_gap_frames, 60))
    closer.wait()
    closer.close()
    eager = Vocabulary.learn([f.descriptors for f in closer.keyframes[:CFG.vocabulary_after]], CFG.words, 0)
    assert np.array_equal(closer.vocab.words, eager.words) and np.array_equal(closer.vocab.idf, eager.idf)
    assert all(h is not None for h in closer.hists) and len(closer.hists) == len(closer.keyframes)


def test_close_loops_corrects_a_drifted_trajectory(rpy):
    frames, gt, intr = rpy
    drift = np.array([np.eye(4)] * 60)
    drift[:, 0, 3] = np.linspace(0, 0.08, 60)  # 8 cm of drift along x over the excerpt
    est = drift @ gt
    closer = LoopCloser(CFG, intr, seed=0)
    for k in range(60):
        closer.offer(k, *frames[k], est[k], True)
    out, summary = closer.close_loops(est, [True] * 60)
    closer.close()
    assert summary["loops"] >= 3 and summary["candidates_tried"] >= summary["loops"]
    # each loop ties two frames 20+ frames apart: their relative pose, off by the drift between them before, now
    # agrees with the ground truth (the end stays off by the drift of the frames it is tied to, as it should)
    def gap(P):
        return np.mean([pose_gap(np.linalg.inv(P[lp["match"]]) @ P[lp["query"]],
                                 np.linalg.inv(gt[lp["match"]]) @ gt[lp["query"]])[0] for lp in closer.loops])

    assert gap(est) > 0.02 and gap(out) < 0.7 * gap(est), (gap(est), gap(out))
    assert np.abs(out[:, :3, 3] - gt[:, :3, 3]).mean() < np.abs(est[:, :3, 3] - gt[:, :3, 3]).mean()


def test_a_missing_dependency_is_named(monkeypatch):
    import builtins

    from slam.config import load_config
    from slam.errors import SlamInputError
    from slam.loop.closer import loop_closer

    real = builtins.__import__

    def no_gtsam(name, *a, **kw):
        if name == "gtsam":
            raise ImportError("No module named 'gtsam'")
        return real(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_gtsam)
    cfg = load_config("synthetic", ["loops.enabled=true"])
    with pytest.raises(SlamInputError, match="loops.enabled needs gtsam.*loops"):
        loop_closer(cfg, None)
    assert loop_closer(load_config("synthetic"), None) is None


def test_a_failing_worker_stops_loop_closure_and_the_run_keeps_its_poses(rpy, monkeypatch, caplog):
    frames, gt, intr = rpy
    closer = LoopCloser(CFG, intr, seed=0)
    for k in range(10):
        closer.offer(k, *frames[k], gt[k], True)
    closer.wait()
    made = len(closer.keyframes)

    def broken(*a, **kw):
        raise ValueError("corrupt descriptors")

    monkeypatch.setattr("slam.loop.closer.extract", broken)
    with caplog.at_level("WARNING", logger="slam"):
        offered = [k for k in range(10, 60) if closer.offer(k, *frames[k], gt[k], True)]
        closer.wait()
    assert offered and closer.error == "ValueError: corrupt descriptors" and "loop closure stopped" in caplog.text
    assert not closer.offer(59, *frames[59], gt[59], True)  # no more keyframes once stopped, and no hang
    out, summary = closer.close_loops(gt[:60], [True] * 60)
    closer.close()
    assert summary["error"] == closer.error and summary["keyframes"] == made
    assert np.array_equal(out, gt[:60])

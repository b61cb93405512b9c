"""What the streaming calibrator keeps of the joint stream (:mod:`skincal.calib.online.history`) against the
whole-stream computation it replaces: ``np.gradient`` over the concatenated grid, the stable merge of every
joint chunk received."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.calib.online.history import KINEMATIC, GridHistory, JointBuffer
from skincal.calib.online.unit import Grid


def _blocks(seed: int, count: int):
    """Blocks of 40-160 grid rows at 125 Hz (a gap of 3 rows now and then), 3 links x 18 signals of smooth
    curves, ``dy`` their exact ``dw``."""
    rng = np.random.default_rng(seed)
    k0, out = 17, []
    for _ in range(count):
        G = int(rng.integers(40, 161))
        k = k0 + np.arange(G)
        t = k / 125.0
        y = np.sin(np.outer(t, np.linspace(0.3, 3.0, 54))).reshape(G, 3, 18) + 0.01 * rng.normal(size=(G, 3, 18))
        out.append(Grid(t, y, rng.normal(size=(G, 3, 3)), rng.random(G) > 0.1, rng.random((G, 3)),
                        float(rng.uniform(1, 10))))  # fmt: skip
        k0 = k[-1] + 1 + (3 if rng.random() < 0.2 else 0)
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_the_grid_kept_block_by_block_is_the_whole_grids_gradient(seed):
    history, kept = GridHistory(), []
    for i, block in enumerate(_blocks(seed, 60)):
        history.append(block)
        kept.append(block)
        if i % 7 == 6:  # the oldest blocks go now and then (the buffers move when full)
            horizon = kept[2].t[-1] + 1e-3
            history.forget_before(horizon)
            kept = [b for b in kept if b.t[-1] >= horizon]
        whole = history.whole()
        assert whole is not None
        t = np.concatenate([b.t for b in kept])
        y = np.concatenate([b.y for b in kept])
        dy = np.gradient(y, t, axis=0)
        dy[..., KINEMATIC] = np.concatenate([b.dy for b in kept])
        np.testing.assert_array_equal(whole.t, t)
        np.testing.assert_array_equal(whole.y, y)
        np.testing.assert_array_equal(whole.dy, dy)  # the same arithmetic, row by row
        np.testing.assert_array_equal(whole.ok, np.concatenate([b.ok for b in kept]))
        np.testing.assert_array_equal(whole.speed, np.concatenate([b.speed for b in kept]))
        assert whole.resolved_rps == min(b.resolved_rps for b in kept)
    history.forget_before(np.inf)
    assert not history and history.whole() is None


def test_joint_chunks_in_any_order_merge_by_stamp_keeping_the_first_of_a_repeat():
    rng = np.random.default_rng(3)
    t = np.arange(400) / 100.0
    q = np.column_stack([np.sin(t), np.cos(2 * t)])
    buffer, cuts = JointBuffer(), [0, 90, 200, 260, 400]
    pieces = [(t[a:b], q[a:b]) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    order = rng.permutation(len(pieces))
    for i in order:
        buffer.add(pieces[i][0], pieces[i][1], None)
    buffer.add(t[100:101], q[100:101] + 1.0, np.zeros((1, 2)))  # a repeat of a stamp received before
    merged = buffer.arrays()
    assert merged is not None and buffer.newest == t[-1]
    np.testing.assert_array_equal(merged[0], t)
    np.testing.assert_array_equal(merged[1], q)
    # qd from each chunk's own positions where none was sent
    expected = np.concatenate([np.gradient(p[1], p[0], axis=0) for p in pieces])
    np.testing.assert_array_equal(merged[2], expected)
    buffer.forget_before(2.0)
    kept = buffer.arrays()
    assert kept is not None and kept[0][0] == 2.0 and kept[0].size == 200


def test_a_stream_whose_stamps_stop_advancing_is_merged_and_stays_bounded(monkeypatch):
    """A driver repeating its last state with its last stamp reaches no block; the buffer merges every
    ``MERGE_EVERY`` chunks (the repeats go), and merging then or only at the end gives the same states."""
    from skincal.calib.online import history

    t = np.arange(50) / 100.0
    q = np.column_stack([np.sin(t), t])
    chunks = [(t, q)] + [(t[-1:], q[-1:] + 1.0)] * (3 * history.MERGE_EVERY)
    eager = JointBuffer()
    for tc, qc in chunks:
        eager.add(tc, qc, None)
        assert len(eager._t) < history.MERGE_EVERY
    monkeypatch.setattr(history, "MERGE_EVERY", 10**9)
    late = JointBuffer()
    for tc, qc in chunks:
        late.add(tc, qc, None)
    assert len(late._t) == len(chunks)
    merged = eager.arrays()
    assert merged is not None and merged[0].size == t.size
    np.testing.assert_array_equal(merged[1], q)  # the first received of a repeated stamp is kept
    for a, b in zip(merged, late.arrays(), strict=True):
        np.testing.assert_array_equal(a, b)

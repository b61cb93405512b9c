"""A bag's samples made streams: stamps sorted, repeated stamps and NaN samples dropped, interleaved
sources refused (:data:`INTERLEAVED_FRACTION`), the robot's joints found by name in the joint-state
messages (:func:`match_joints`)."""

from __future__ import annotations

import numpy as np

from skincal.data.ros.messages import BagPass
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.chain import SerialChain
from skincal.names import printable

INTERLEAVED_FRACTION = 0.01
"""Above this fraction of stamps going back or repeating (in bag order), or of samples jumping away
from both neighbours, one frame_id's samples come from several sources: refused."""
JUMP_RELATIVE = 0.05
"""A sample "jumps" when it is farther than this times the median ``|a|`` (and 3 times the gap
between its neighbours) from both neighbours."""


def stamps_ns(rows: list[tuple[int, int]], topic: str, notes: list[str]) -> np.ndarray:
    """``(M,)`` int64 ns from (header stamp ns, bag time ns) rows; bag time if a stamp is zero."""
    arr = np.array(rows, dtype=np.int64).reshape(-1, 2)
    if np.any(arr[:, 0] == 0):
        notes.append(f"{topic}: header.stamp is zero in {int(np.sum(arr[:, 0] == 0))} message(s); using bag time")
        return arr[:, 1]
    return arr[:, 0]


def clean_samples(
    topic: str, t_ns: np.ndarray, values: np.ndarray, notes: list[str], source: str, nan_ok: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Sort by time, drop repeated stamps and (unless ``nan_ok``) samples with NaN; error if none left."""
    order = np.argsort(t_ns, kind="stable")
    t_ns, values = t_ns[order], values[order]
    keep = np.concatenate([[True], np.diff(t_ns) > 0])
    if not np.all(keep):
        notes.append(f"{topic}: dropped {int(np.sum(~keep))} message(s) with a repeated time stamp")
    flat = values.reshape(len(values), -1)
    bad = np.zeros(len(values), dtype=bool) if nan_ok else np.any(np.isnan(flat), axis=1)
    if np.all(bad):
        raise DatasetError(f"{source}: topic {topic}: all {len(values)} samples contain NaN")
    if np.any(bad & keep):
        notes.append(f"{topic}: dropped {int(np.sum(bad & keep))} sample(s) containing NaN")
    keep &= ~bad
    return t_ns[keep], values[keep]


def refuse_interleaved(label: str, t_ns: np.ndarray, accel: np.ndarray | None, source: str) -> None:
    """One-line :class:`DatasetError` when one source's samples (``t_ns`` in bag order; ``accel`` in
    time order, raw units) look like several sources interleaved (module docstring)."""
    hint = "give each sensor its own frame_id or topic"
    steps = np.diff(t_ns)
    back = int(np.sum(steps < 0))  # repeated stamps alone are coarse clocks (dropped later, with a note)
    if back > max(1, INTERLEAVED_FRACTION * len(steps)):
        raise DatasetError(
            printable(
                f"{source}: {label}: {back} of {len(steps)} time stamps go back: "
                f"samples of several sources interleaved (not merged); {hint}"
            )
        )
    if accel is None or len(accel) < 3:
        return
    a = accel[np.all(np.isfinite(accel), axis=1)]
    if len(a) < 3:
        return
    d_prev = np.linalg.norm(a[1:-1] - a[:-2], axis=1)
    d_next = np.linalg.norm(a[1:-1] - a[2:], axis=1)
    d_skip = np.linalg.norm(a[2:] - a[:-2], axis=1)
    eps = JUMP_RELATIVE * float(np.median(np.linalg.norm(a, axis=1)))
    jumps = int(np.sum(np.minimum(d_prev, d_next) > 3.0 * d_skip + eps))
    if jumps > max(1, INTERLEAVED_FRACTION * len(d_skip)):
        raise DatasetError(
            printable(
                f"{source}: {label}: {jumps} of {len(d_skip)} samples jump away from both "
                f"neighbours: samples of several sources interleaved (not merged); {hint}"
            )
        )


def match_joints(
    names: tuple[str, ...], wanted: tuple[str, ...], source: str, topic: str
) -> tuple[np.ndarray | None, list[str]]:
    """Index into the message's arrays of each wanted joint (None if some are missing) and the
    missing ones. A name matches exactly, else as a ``_``/``/`` suffix; two matches are an error."""
    cols, missing = [], []
    for w in wanted:
        hits = [i for i, name in enumerate(names) if name == w]
        if not hits:
            hits = [i for i, name in enumerate(names) if name.endswith("_" + w) or name.endswith("/" + w)]
        if len(hits) > 1:
            raise DatasetError(
                printable(
                    f"{source}: topic {topic}: joint '{w}' matches several names of a message "
                    f"({', '.join(names[i] for i in hits)}); give joint_names in the topic map"
                )
            )
        if hits:
            cols.append(hits[0])
        else:
            missing.append(w)
    return (None if missing else np.array(cols, dtype=int)), missing


def joint_states_from(scan: BagPass, chain: SerialChain, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t_ns, q, qd)`` of the robot's joints, found by name (module docstring)."""
    topic, notes = scan.used.joints, scan.notes
    jrows = scan.rows[topic]
    if not jrows:
        raise DatasetError(f"{source}: joint state topic {topic} has no messages")
    n = chain.n_joints
    wanted = scan.used.joint_names or chain.joint_names
    if wanted is not None and len(wanted) != n:
        raise ConfigError(f"joint_names has {len(wanted)} names but robot '{chain.name}' has {n} joints")
    matched: dict[tuple[str, ...], tuple[np.ndarray | None, list[str]]] = {}
    keep, q_rows, qd_rows = [], [], []
    uneven: tuple[int, int] | None = None
    for i, (_, _, (names, pos, vel)) in enumerate(jrows):  # per message: name order may differ between messages
        if names not in matched:
            if wanted is not None:
                matched[names] = match_joints(names, wanted, source, topic)
            elif len(names) == n:
                matched[names] = (np.arange(n), [])
                notes.append(
                    printable(
                        f"{topic}: robot '{chain.name}' has no joint names; taking the message's "
                        f"order {', '.join(names)} as joints 1..{n}"
                    )
                )
            else:
                matched[names] = (None, [f"joint{j}" for j in range(1, n + 1)])
        cols = matched[names][0]
        if cols is not None and pos.shape[0] != len(names):
            uneven = (int(pos.shape[0]), len(names))  # a malformed message: positions and names differ in count
        if cols is None or pos.shape[0] != len(names):
            continue
        keep.append(i)
        q_rows.append(pos[cols])
        qd_rows.append(vel[cols] if vel.shape[0] == len(names) else np.full(len(cols), np.nan))
    if not keep:
        seen = "; ".join(", ".join(k) for k in list(matched)[:2])
        if wanted is None:
            raise DatasetError(
                printable(
                    f"{source}: topic {topic}: robot '{chain.name}' has no joint names and no "
                    f"message has exactly its {n} joints (names seen: {seen}); give "
                    "joint_names in the topic map"
                )
            )
        missing = min((m for _, m in matched.values()), key=len)
        if not missing and uneven is not None:  # the names matched, the positions did not
            raise DatasetError(
                printable(
                    f"{source}: topic {topic}: the messages carry {uneven[0]} position(s) for {uneven[1]} joint "
                    "name(s); a JointState's position list must be as long as its name list"
                )
            )
        raise DatasetError(
            printable(
                f"{source}: topic {topic}: joint{'s' if len(missing) > 1 else ''} {', '.join(missing)} of robot "
                f"'{chain.name}' missing from the messages (names seen: {seen}); give joint_names in the topic map"
            )
        )
    if len(keep) < len(jrows):
        partial = sorted({m for c, ms in matched.values() if c is None and len(ms) < n for m in ms})
        notes.append(
            f"{topic}: skipped {len(jrows) - len(keep)} message(s) without the robot's joints"
            + (f" (some lack {', '.join(partial)})" if partial else "")
        )
    t_j = stamps_ns([jrows[i][:2] for i in keep], topic, notes)
    q, qd = np.array(q_rows), np.array(qd_rows)
    no_velocity = np.all(np.isnan(qd), axis=1)
    t_j, qq = clean_samples(topic, t_j, np.stack([q, np.where(no_velocity[:, None], 0.0, qd)], axis=1), notes, source)
    q, qd = qq[:, 0], qq[:, 1]
    if np.any(no_velocity):
        if len(t_j) < 3:
            raise DatasetError(f"{source}: topic {topic}: {len(t_j)} samples, too few to differentiate")
        qd = np.gradient(q, (t_j - t_j[0]) * 1e-9, axis=0)  # relative: epoch seconds lose precision
        notes.append(
            f"{topic}: no velocities in {int(np.sum(no_velocity))} message(s); joint velocities "
            "from central differences of the positions"
        )
    return t_j, q, qd


def first_stamp(scan: BagPass, source: str) -> int:
    """The earliest header stamp (the bag time where a topic's stamps are zero) of the IMU and range
    topics read: time 0 of an IMU-only dataset."""
    firsts = []
    for topic in (*scan.used.imu, *scan.used.range):
        rows = scan.rows.get(topic) or []
        if rows:
            firsts.append(int(stamps_ns([r[:2] for r in rows], topic, []).min()))
    if not firsts:
        raise DatasetError(f"{source}: the IMU topics have no messages")
    return min(firsts)

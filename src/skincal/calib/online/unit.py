"""What the streaming calibrator keeps: the link signals on its grid (:class:`Grid`, read back at the
samples' instants by :func:`signals_at`) and per unit its statistics, pending samples and clock
(:class:`UnitState`); the samples' screening is :mod:`~skincal.calib.online.screen`'s."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skincal.calib.hermite import hermite
from skincal.calib.online import stats
from skincal.calib.online.options import UnitStatus
from skincal.calib.online.split import Ledger
from skincal.calib.online.stuck import StuckScreen
from skincal.calib.timing import ClockSteps
from skincal.kinematics.transforms import FloatArray

REST, MOVING = 0, 1
"""Rest and moving samples are two classes with their own noise level (a resting unit's residual is its sensor
noise; a moving one's adds the errors of the joint-derived accelerations), so the Grams are kept per class
(:func:`~skincal.calib.rest.link_moving`)."""
MIN_POSITION_MOVING = 10
"""A unit whose link has fewer moving samples than this holds no position (rests only)."""


@dataclass(frozen=True)
class Grid:
    """The link signals of every link on the streaming calibrator's uniform grid.

    Attributes:
        t: ``(G,)`` grid instants on the joint clock, s.
        y: ``(G, n, 18)`` per link ``[u (3), K (9, row-major), w (3), u_g (3)]``
            (:func:`~skincal.calib.signals.frame_signals`, link frame).
        dy: ``(G, n, 18)`` their time derivatives (per block: only ``dw`` ``(G, n, 3)``, exact).
        ok: ``(G,)`` the joint accelerations are reliable there.
        speed: ``(G, n)`` ``sum_{j <= k} |qd_j|``, rad/s (the clock search without a gyroscope).
        resolved_rps: the angular speed the joint stream resolves
            (:func:`~skincal.calib.timing.resolved_speed` of the stamps the grid was made from), rad/s.
    """

    t: FloatArray
    y: FloatArray
    dy: FloatArray
    ok: np.ndarray
    speed: FloatArray
    resolved_rps: float = float("inf")


@dataclass
class Windows:
    """A link's normalised residuals in windows of consecutive samples (the correlation inflation,
    :func:`~skincal.calib.online.fit.inflation`): the open window's sum and count, and over closed
    windows the sum of ``n |mean|^2`` (3 per window for white residuals of unit variance) and their count."""

    sum: FloatArray = field(default_factory=lambda: np.zeros(3))
    n: int = 0
    stat: float = 0.0
    count: int = 0


@dataclass
class UnitState:
    """One unit's state in the streaming calibrator: per candidate link its Grams (rest and moving
    classes) and fits, its pending samples, its clock mapping and its residual statistics."""

    links: list[int]  # the candidate links (one once decided)
    Za: FloatArray  # (L, 2, NA, NA): per candidate link, rest and moving samples
    Zg: FloatArray  # (L, 2, NG, NG)
    moving: FloatArray  # (L,) moving samples per candidate link
    pending_t: list[FloatArray] = field(default_factory=list)
    pending_a: list[FloatArray] = field(default_factory=list)
    pending_g: list[FloatArray | None] = field(default_factory=list)
    offset: float | None = None
    offset_sharpness: float = float("nan")
    searched_span: float = 0.0  # span of the stream the coarse offset was last searched on, s (clock.recheck)
    clock_widened: bool = False  # that search found the offset beyond the usual range (timing.WIDE_OFFSET_S)
    clock_provisional: bool = False  # stamps taken as they are (no motion seen yet): aligned again on motion
    has_gyro: bool | None = None
    chunks: deque = field(default_factory=deque)  # (t_min, t_max, Za, Zg, moving, pieces) per absorb call
    ledger: Ledger = field(default_factory=Ledger)  # the statistics per window of the stream (split check)
    split_cache: tuple | None = None  # (link, absorbed samples, Solution, unchecked std, Consistency | None)
    t_last: float = float("-inf")
    t_first: float = float("inf")
    dirty: bool = True
    solutions: dict[int, stats.Solution] = field(default_factory=dict)
    # link (0: the common weights of undecided candidates) -> [accel rest, accel moving, gyro rest, gyro moving]
    sigmas: dict[int, FloatArray] = field(default_factory=dict)
    decided: bool = False
    windows: dict[int, Windows] = field(default_factory=dict)  # link -> its residual windows (correlation)
    outliers: int = 0
    residual_norms: deque = field(default_factory=lambda: deque(maxlen=4096))  # a settled unit's recent |rn|
    status: UnitStatus | None = None
    best_joint_t: float = float("-inf")
    best_joint: int | None = None
    # per channel (accel, gyro) each axis' largest reading and largest negated one (x, y, z, -x, -y, -z) seen...
    peak: FloatArray = field(default_factory=lambda: np.zeros((2, 6)))
    peak_count: FloatArray = field(default_factory=lambda: np.zeros((2, 6)))  # ...and how often exactly it came
    screened: FloatArray = field(default_factory=lambda: np.zeros(2))  # readings screened: accel, gyro
    saturated: int = 0  # samples not absorbed: the accelerometer at its rail
    gyro_saturated: int = 0  # samples absorbed without their gyroscope reading (at its rail)
    t_solved: float = float("-inf")
    align_tried: float = float("-inf")
    raw: deque = field(default_factory=deque)  # absorbed (stamps, accel, gyro) within the history, to realign
    realigned: int = 0
    rechecked: int = 0  # coarse mappings replaced by a search on a longer stream (clock.recheck)...
    recheck_shift_s: float = 0.0  # ...and the last replacement's change of the offset, s
    # the clock mapping s = t' - offset - drift (t' - t_ref), t' the stamps less their re-sync steps
    drift: float = 0.0
    t_ref: float = 0.0
    steps: ClockSteps | None = None
    t_seen: float = float("-inf")  # newest stamp searched for re-sync steps
    stuck: StuckScreen = field(default_factory=StuckScreen)  # the stuck-axis test, before the samples are pending
    candidates: tuple[int, ...] = ()  # every candidate link (the calibrator's), for :func:`undecide`


def undecide(st: UnitState) -> None:
    """Back to every candidate link (``st.candidates``) with empty statistics, after
    :func:`~skincal.calib.online.clock.restart` emptied the rest: a new coarse clock mapping
    (:func:`~skincal.calib.online.clock.recheck`) means the link was decided on samples the wrong clock placed
    (a UR5e unit stamped 1.2 s late stayed on link 1 after its clock was found, 2.8e8 m off, SIMULATED)."""
    L = len(st.candidates)
    st.links, st.decided, st.sigmas, st.ledger = list(st.candidates), False, {}, Ledger()
    st.Za, st.Zg, st.moving = np.zeros((L, *st.Za.shape[1:])), np.zeros((L, *st.Zg.shape[1:])), np.zeros(L)


def keep_pending(st: UnitState, t: FloatArray, a: FloatArray, g: FloatArray | None) -> None:
    """Put samples ``t``, ``a``, ``g`` back among the unit's pending ones."""
    if t.size:
        st.pending_t.append(t)
        st.pending_a.append(a)
        st.pending_g.append(g)


def take_pending(st: UnitState) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """The unit's pending samples in stamp order: stamps, accelerometer, gyroscope (None: none)."""
    t = np.concatenate(st.pending_t) if st.pending_t else np.zeros(0)
    a = np.concatenate(st.pending_a) if st.pending_a else np.zeros((0, 3))
    g = np.concatenate(st.pending_g) if st.has_gyro and st.pending_g else None  # type: ignore[arg-type]
    order = np.argsort(t, kind="stable")
    return t[order], a[order], None if g is None else g[order]


def signals_at(grid: Grid, s: FloatArray, links: Sequence[int]):
    """Link signals of ``links`` at instants ``s`` (M,) from the grid, as ``mle``'s signal table does
    (:func:`~skincal.calib.hermite.hermite`: cubic Hermite for the values with their derivatives,
    linear for the derivatives). Returns u, K, w, dw_dt, du_dt, dK_dt, u_g (each ``(L, M, ...)``)
    and ok ``(M,)``."""
    y, dy, i = hermite(grid.t, grid.y, grid.dy, s, np.asarray(links) - 1)  # (M, L, 18)
    y, dy = np.moveaxis(y, 1, 0), np.moveaxis(dy, 1, 0)
    L, M = y.shape[:2]
    sig = (
        y[..., :3], y[..., 3:12].reshape(L, M, 3, 3), y[..., 12:15], dy[..., 12:15],
        dy[..., :3], dy[..., 3:12].reshape(L, M, 3, 3), y[..., 15:18],
    )  # fmt: skip
    return (*sig, grid.ok[i] & grid.ok[i + 1])


def windowed_link(st: UnitState) -> int | None:
    """The link whose residuals the unit's correlation windows hold at the data's end: its decided link, else
    the leader of its candidates once its pose is determined (a unit never decided, as on a short real
    recording, still shows its correlated residuals in its std); None: none."""
    if st.decided:
        return st.links[0] if st.links[0] in st.solutions else None
    status = st.status
    if status is None or status.link not in st.solutions or status.link not in st.sigmas:
        return None
    return status.link if np.all(np.isfinite(status.position_std_m)) else None


def rests_only(st: UnitState, k: int) -> bool:
    """Whether the unit recorded in the robot's rests only (static poses: its clock not aligned on motion)
    or its candidate link ``k`` (index into ``st.links``) has too few moving samples: no position."""
    return bool(st.clock_provisional or (st.moving.size and st.moving[k] < MIN_POSITION_MOVING))

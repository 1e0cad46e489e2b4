"""Reference forecasters of the closed loop: the exact oracle (the others' true future) and "static".

The oracle (`predictor="oracle"`, `BranchOracle`) is exact on every backend and under every background
`reaction`, wherever an exact forecast exists: its forecast at frame k is what the other agents then do
in the same episode. It reads them from a branch of the live simulator (highway: a deep copy, RNG
included; SUMO: a fork of the `SumoProcess` worker) rolled ahead `oracle_window_s` with the ego driven
exactly as the episode drives it: a copy of the planner, the loop's own `LoopClock`, forecasts read
from a guess of the branch's future. Under a reacting background the others' future depends on the
ego's, which depends on the forecasts: the oracle iterates guess -> branch -> guess until the ego,
fed the branch's own future, gives the same commands again (checked by replanning over the branch's
recorded frames, without simulating). Then (the backends being deterministic) the branch's future
is the one it was planned on, a fixed point, and the episode, whose planner is fed that same
future, repeats the branch frame for frame.

One converged branch serves every prediction for the next `window - (horizon + 2 planning
horizons)` frames (a prediction needs its horizon, the ego's planning horizon beyond it, and one
more for the ego's decisions there to rest on a settled future); the oracle then branches again
from the live state, warm-started from the last branch.

Cost. A round after the first does not re-simulate what it shares with the last: the ego's commands
come out the same up to the first frame d where the check found a different one, so the round resumes
the last branch there (from a snapshot taken every `snapshot_every` frames, its commands replayed up to
d) and the check itself restarts from the latest of its own saved ego states that the changed frames
cannot have reached. A spent converged branch is likewise continued from where it was verified, not
re-rolled from the live state. Both are what re-rolling gives, frame for frame. A snapshot of a SUMO branch is a
fork, whose copy-on-write costs about two frames of stepping: taken every 10 frames, and none past the settled
frame, where no round resumes. A SUMO branch rolls each stretch in its worker (`SumoProcess.rollout`, the ego a
picklable `_Drive`): one message per stretch, not a round trip per frame. Where no fixed point exists (a
self-defeating forecast: told that a scooter cuts in, the ego holds back and the scooter does
not cut in; told it does not, the ego closes up and it does) the iteration cycles (a round repeats an
earlier one, or the ego's command at the first differing frame flips back to an earlier round's); the oracle
stops there (`cycles`) or after `max_iterations` (`unconverged`). Its last branch is then what the ego does
when fed the round before it; the oracle serves that branch's own future (exact) up to the first forecast
that would make the ego leave it, serves there the blend of the two rounds' futures nearest the branch's
that keeps the ego on it (`inexact`: one forecast per such branch), and branches again at the next forecast
from the live state. It checks that the episode did follow the branch (`mismatches`: frames where the
live state differed from it; each starts a new branch). Its online error is scored like any
predictor's, so how exact it was is visible in every scorecard.

"static" (`StaticForecast`): the planner with no prediction: everyone stays put.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import numpy as np

from simharness.closedloop.config import LoopClock
from simharness.planners import Planner
from simharness.scene import Forecast, Scene, heading_velocity
from simharness.sim.base import EgoCommand, Frame


class StaticForecast:
    """"static": the planner with no prediction at all: everyone stays where they are now."""

    def predict(self, history: Scene, targets: np.ndarray, horizon: int) -> Forecast:
        targets = np.asarray(targets, int)
        mean = np.repeat(history.xy[targets, -1][:, None], horizon, axis=1)
        return Forecast(agent_id=history.agent_id[targets], mean=mean.astype(np.float32), dt=history.dt)


def near_targets(frame: Frame, radius: float) -> np.ndarray:
    """(M,) rows of the agents within `radius` m of the ego in this frame, the ego excluded (the loop's targets)."""
    near = np.linalg.norm(frame.xy - frame.xy[frame.ego], axis=-1) <= radius
    near[frame.ego] = False
    return np.flatnonzero(near)


@dataclasses.dataclass
class Track:
    """Every agent's position but the ego's over consecutive frames: ids (N,) sorted; xy (N, F, 2) float32,
    nan where absent; column 0 is episode frame `start`."""

    ids: np.ndarray
    xy: np.ndarray
    start: int

    @classmethod
    def of(cls, frames: list[Frame], start: int) -> Track:
        others = [np.arange(f.num_agents) != f.ego for f in frames]
        ids = np.unique(np.concatenate([f.agent_id[o] for f, o in zip(frames, others, strict=True)]))
        xy = np.full((len(ids), len(frames), 2), np.nan, np.float32)
        for c, (f, o) in enumerate(zip(frames, others, strict=True)):  # one vectorised assignment per frame
            xy[np.searchsorted(ids, f.agent_id[o]), c] = f.xy[o]
        return cls(ids, xy, start)

    @property
    def end(self) -> int:
        """Episode frame of the last column."""
        return self.start + self.xy.shape[1] - 1

    def future(self, frame: Frame, targets: np.ndarray, k: int, horizon: int, dt: float) -> np.ndarray:
        """(M, horizon, 2) float32 positions at frames k+1 .. k+horizon of the agents in rows `targets` of frame k.

        Beyond the track's end: extrapolated at the track's last velocity; agents the track lacks:
        constant velocity from `frame` (frame k).
        """
        ids = frame.agent_id[targets]
        rows = np.minimum(np.searchsorted(self.ids, ids), len(self.ids) - 1)
        known = self.ids[rows] == ids
        last = self.xy.shape[1] - 1
        cols = k + 1 + np.arange(horizon) - self.start
        out = self.xy[rows][:, np.clip(cols, 0, last)]  # (M, horizon, 2)
        beyond = cols > last
        if beyond.any() and last >= 1:
            vel = self.xy[rows, last] - self.xy[rows, last - 1]  # m per frame
            out[:, beyond] = self.xy[rows, last][:, None] + (cols[beyond] - last)[None, :, None] * vel[:, None]
        hd = frame.heading[targets]
        v = heading_velocity(frame.speed[targets], hd)
        steps = (np.arange(horizon) + 1)[None, :, None] * dt
        fallback = frame.xy[targets][:, None] + v[:, None] * steps
        bad = ~known[:, None] | np.isnan(out).any(-1)
        return np.where(bad[..., None], fallback, out).astype(np.float32)

    def agrees(self, other: Track, frames: int) -> bool:
        """Whether both tracks hold the same agents at the same positions over their first `frames` columns
        (both starting at the same frame)."""
        a, b = self.xy[:, :frames], other.xy[:, :frames]
        pa, pb = ~np.isnan(a[..., 0]).all(1), ~np.isnan(b[..., 0]).all(1)  # agents present at all in the span
        if self.start != other.start or a.shape[1] != b.shape[1] or pa.sum() != pb.sum():
            return False
        return bool((self.ids[pa] == other.ids[pb]).all() and np.array_equal(a[pa], b[pb], equal_nan=True))

    def matches(self, frame: Frame, k: int) -> bool:
        """Whether the others in frame k of the episode are exactly column k of the track (agents, positions)."""
        c = k - self.start
        if not 0 <= c < self.xy.shape[1]:
            return False
        o = np.arange(frame.num_agents) != frame.ego
        ids = frame.agent_id[o]
        if (~np.isnan(self.xy[:, c, 0])).sum() != len(ids):
            return False
        rows = np.minimum(np.searchsorted(self.ids, ids), len(self.ids) - 1)
        return bool((self.ids[rows] == ids).all() and (self.xy[rows, c] == frame.xy[o]).all())


@dataclasses.dataclass
class Blend:
    """The forecast (1 - w) * `a` + w * `b` of two tracks for the agents `ids` (all when None), `b` for the
    others (read like a `Track`)."""

    a: Track
    b: Track
    w: float
    ids: np.ndarray | None = None

    def future(self, frame: Frame, targets: np.ndarray, k: int, horizon: int, dt: float) -> np.ndarray:
        """(M, horizon, 2) float32: see `Track.future`."""
        fa, fb = self.a.future(frame, targets, k, horizon, dt), self.b.future(frame, targets, k, horizon, dt)
        w = np.where(np.isin(frame.agent_id[targets], self.ids), self.w, 1.0) if self.ids is not None else self.w
        w = np.reshape(w, (-1, 1, 1))
        return ((1 - w) * fa + w * fb).astype(np.float32)


@dataclasses.dataclass
class _Rollout:
    """One branch rolled ahead from episode frame k: frames[i] is frame k + i, commands[i] the ego's there.

    snaps: {i: simulator at frames[i]} every `snapshot_every` frames up to the settled one (resumed from, never
    stepped); checkpoints: {i: ego state before driving frames[i]} every `checkpoint_every` frames, as replanning
    over this branch's own track gives it (the check starts at the latest); verified: the ego state before driving
    frame k + settled, once checked.
    """

    k: int
    frames: list[Frame]
    commands: list[EgoCommand | None]
    snaps: dict[int, Any]
    checkpoints: dict[int, tuple]
    verified: tuple | None = None

    def close(self, keep: int = -1) -> None:
        """Close the snapshots after frame index `keep` (all when -1)."""
        for i in [i for i in self.snaps if i > keep]:
            self.snaps.pop(i).close()


class BranchOracle:
    """The exact oracle (see the module docstring). The episode calls `forecast` instead of `predict`.

    horizon: forecast frames; plan_frames: frames of the forecast the planner uses; radius: m (targets);
    window: frames each branch is rolled ahead; max_iterations: guess -> branch rounds per branch;
    snapshot_every: frames between the branch snapshots that later rounds resume from (up to the settled frame
    only: no round resumes later); checkpoint_every: frames between the ego states that the check restarts from.
    `serve`: where the live planner is served degraded forecasts (`perturbations.Degrader`), the branches'
    egos are served the same (a copy of it, deterministic per frame and agent).
    bisections: halvings of the blend weight served where no fixed point exists.
    `stats`: branches, iterations, cycles (no fixed point), unconverged, inexact (blends served), mismatches (see
    the module docstring).
    """

    def __init__(self, dt: float, horizon: int, plan_frames: int, radius: float, window: int,
                 max_iterations: int = 4, snapshot_every: int = 10, checkpoint_every: int = 5,
                 bisections: int = 6) -> None:
        self.dt, self.horizon, self.plan_frames, self.radius = dt, horizon, plan_frames, radius
        self.window = max(window, horizon + 2 * plan_frames + 1)
        self.max_iterations = max_iterations
        self.snapshot_every = max(1, snapshot_every)
        self.checkpoint_every = max(1, checkpoint_every)
        self.serve: Any = None
        self.track: Track | None = None
        self.last: _Rollout | None = None
        self.until: int | None = None  # where no fixed point exists: the last frame this branch serves ...
        self.blend: Blend | None = None  # ... and what it serves there
        self.bisections = bisections
        self.stats = {"branches": 0, "iterations": 0, "cycles": 0, "unconverged": 0, "inexact": 0, "mismatches": 0}

    def forecast(self, k: int, frame: Frame, sim: Any, planner: Planner, clock: LoopClock) -> Forecast | None:
        """The others' true future at frame k of the live episode (sim, planner, clock: its live state)."""
        fresh = self.track is not None and self.track.end - k >= self.horizon + 2 * self.plan_frames
        fresh = fresh and (self.until is None or k <= self.until)
        if fresh and not self.track.matches(frame, k):
            self.stats["mismatches"] += 1
            fresh = False
            self._drop()
        if not fresh:
            if self.stats["branches"] == 0 and hasattr(sim, "rollout"):  # the worker imports the ego's code
                sim.rollout(self._driver(k, (planner, clock, self.serve), Track.of([frame], k)), frame, 0, 0)  # once
            self._branch_out(k, frame, sim, planner, clock)
        return _forecast_from(self.blend if k == self.until else self.track, frame, k, self.dt, self.horizon,
                              self.radius)

    def close(self) -> None:
        """Close the kept branch's snapshots (end of the episode)."""
        self._drop()

    def _drop(self) -> None:
        if self.last is not None:
            self.last.close()
            self.last = None

    # ------------------------------------------------------------------ the iteration
    def _branch_out(self, k: int, frame: Frame, sim: Any, planner: Planner, clock: LoopClock) -> None:
        """Iterate guess -> branch from the live state until the branch's future is the one its ego was
        planned on (checked by replanning over the branch's frames: no simulation); keep the last branch.

        Each round after the first resumes the last branch where the check found the ego's first different
        command (the frames before it are the same), and a branch whose span is used up is continued from
        where it was verified rather than re-rolled: both exactly what re-rolling from the live state gives.
        """
        guess = self.track if self.track is not None else Track.of([frame], k)
        self.until, self.blend = None, None
        # The forecasts this branch will serve need the others' truth up to window - 2 planning horizons,
        # hence the ego's commands up to there; later ones rest on forecasts extrapolated past the window.
        settled = self.window - 2 * self.plan_frames
        seen: list[list[EgoCommand | None]] = []
        self.stats["branches"] += 1
        ego = self._copy((planner, clock, self.serve))
        roll = self._slide(k, frame, sim, ego, guess) if self.last is not None else None
        if roll is None:
            self._drop()
            first = sim.branch()
            try:
                roll = self._extend(_Rollout(k, [frame], [], {}, {0: ego}), first, self._copy(ego), guess)
            finally:
                first.close()
        fed = guess  # the forecasts this round's ego was driven on
        for it in range(self.max_iterations):
            self.stats["iterations"] += 1
            track = Track.of(roll.frames, k)
            d, command, after = self._check(roll, track, settled)
            if d >= settled:  # a fixed point: planned on its own future, the ego does what it did
                roll.verified = after
                break
            # A cycle: no forecast comes true there (a self-defeating one): this round repeats an earlier one,
            # or the next would start as an earlier one did (the ego's command at d flips back and forth).
            if roll.commands[:settled] in seen or any(c[:d + 1] == roll.commands[:d] + [command] for c in seen):
                self.stats["cycles"] += 1
                break
            seen.append(roll.commands[:settled])
            if it == self.max_iterations - 1:
                self.stats["unconverged"] += 1
                break
            roll, fed = self._resume(roll, d, command, after, track), track
        self.track, self.last = Track.of(roll.frames, k), roll
        if roll.verified is None:  # no fixed point: the truth up to the forecast that would defeat itself
            served = self._serve(roll, self.track, fed, settled, d)
            if served is not None:
                self.until, self.blend = served
                self.stats["inexact"] += 1

    def _serve(self, roll: _Rollout, truth: Track, fed: Track, settled: int, d: int) -> tuple[int, Blend] | None:
        """Where no fixed point was found: the first episode frame whose forecast, read from the branch itself
        (`truth`), would make the ego leave the branch, and what to serve there instead, a `Blend` of `fed`
        (what the branch's ego was driven on, which keeps it there) and `truth`: `fed` for one agent or for all,
        each weight bisected towards the truth while it keeps the ego on the branch; the one whose forecast ends
        nearest the truth. None where even `fed` does not. Every forecast before that frame is exact whatever
        comes after, since the ego's commands up to there are the branch's; the oracle branches again at the
        next forecast, from the live state (the ego's choice there made). d: the first frame index where the check
        (the same drive on `truth`) found the ego leaving the branch; the drive restarts from the check's latest
        ego state before it at which a forecast is due.
        """
        i = max(j for j, (_, clock, _) in roll.checkpoints.items() if j <= d and clock.due(roll.k + j))
        ego = self._copy(roll.checkpoints[i])
        while i < settled:
            saved = self._copy(ego)
            nxt = self._segment(roll, ego, i, settled, truth)
            if nxt is not None:
                i = nxt
                continue
            frame = roll.frames[i]
            rows = near_targets(frame, self.radius)
            gap = np.linalg.norm(fed.future(frame, rows, roll.k + i, self.horizon, self.dt)[:, -1]
                                 - truth.future(frame, rows, roll.k + i, self.horizon, self.dt)[:, -1], axis=-1)
            # Most self-defeating forecasts turn on one agent: try `fed` for each that differs, then for all.
            options = [(frame.agent_id[rows[[m]]], gap[m]) for m in np.flatnonzero(gap > 0)] + [(None, gap.sum())]
            best: tuple[float, Blend] | None = None
            for ids, cost in options:
                if best is not None and cost >= best[0]:
                    continue
                if self._segment(roll, self._copy(saved), i, settled, Blend(fed, truth, 0.0, ids)) is None:
                    continue
                lo, hi = 0.0, 1.0  # weights of the truth that keep the branch / leave it
                for _ in range(self.bisections):
                    mid = (lo + hi) / 2
                    ok = self._segment(roll, self._copy(saved), i, settled, Blend(fed, truth, mid, ids))
                    lo, hi = (mid, hi) if ok is not None else (lo, mid)
                if best is None or (1 - lo) * cost < best[0]:
                    best = ((1 - lo) * cost, Blend(fed, truth, lo, ids))
            return None if best is None else (roll.k + i, best[1])
        return None

    def _segment(self, roll: _Rollout, ego: tuple, i: int, settled: int, track: Track | Blend) -> int | None:
        """Drive the ego (advanced in place) over the branch from frame index i, forecasts read from `track`,
        up to the next frame a forecast is due: that frame index (settled at most), None where a command differs
        from the branch's."""
        while True:
            command = _drive(roll.k + i, roll.k, roll.frames[i], ego, track, self.dt, self.horizon, self.radius)
            if command != roll.commands[i]:
                return None
            i += 1
            if i >= settled or ego[1].due(roll.k + i):
                return i

    def _slide(self, k: int, frame: Frame, sim: Any, ego: tuple, guess: Track) -> _Rollout | None:
        """The last branch continued from where it was verified, as the branch from live frame k (None where
        it cannot be: unverified, or the live frame is not its frame k, the ego included)."""
        last, self.last = self.last, None
        i = k - last.k
        settled = self.window - 2 * self.plan_frames
        ok = last.verified is not None and 0 <= i < settled
        if ok:
            f = last.frames[i]
            ok = np.array_equal(f.agent_id, frame.agent_id) and np.array_equal(f.xy, frame.xy) and f.ego == frame.ego
        if not ok:
            last.close()
            return None
        for j in [j for j in last.snaps if j <= i]:
            last.snaps.pop(j).close()
        snaps = {0: sim.branch(), **{j - i: s for j, s in last.snaps.items()}}  # the live simulator is at frame k
        # The last check's ego states hold for the new branch where the forecasts before them read only frames
        # that both branches share (up to the old settled one); frame k's is the live one (the episode ticked it).
        checkpoints = {0: ego, **{j - i: s for j, s in last.checkpoints.items() if i < j < settled - self.horizon}}
        roll = _Rollout(k, last.frames[i:settled + 1], last.commands[i:settled], snaps, checkpoints)
        return self._resume_at(roll, settled - i, last.verified, guess)

    def _resume(self, roll: _Rollout, d: int, command: EgoCommand | None, after: tuple, track: Track) -> _Rollout:
        """The next round: the branch's frames up to d kept, the ego's new command at d, then on from there
        with `after` (the checked ego state after frame d), forecasts read from `track`."""
        roll.close(keep=d)
        # Checked states hold where the forecasts before them read only frames up to d (the same in both rounds);
        # the first is the live one.
        checkpoints = {i: s for i, s in roll.checkpoints.items() if i == 0 or i < d - self.horizon}
        new = _Rollout(roll.k, roll.frames[:d + 1], roll.commands[:d] + [command], roll.snaps, checkpoints)
        return self._resume_at(new, d + 1, after, track, step_last=True)

    def _resume_at(self, roll: _Rollout, n: int, ego: tuple, guess: Track, step_last: bool = False) -> _Rollout:
        """Bring a simulator to frame index n of `roll` (from its latest snapshot, replaying its commands;
        `step_last`: frame n is not recorded yet, its command is the last one), then roll on from there."""
        base = max(j for j in roll.snaps if j <= n - (1 if step_last else 0))
        sim = roll.snaps[base].branch()
        try:
            return self._extend(roll, sim, ego, guess, start=base, replay_to=n)
        finally:
            sim.close()

    def _extend(self, roll: _Rollout, sim: Any, ego: tuple, guess: Track, start: int | None = None,
                replay_to: int = 0) -> _Rollout:
        """Roll `sim` (at frame index `start` of the roll, its last frame by default) on to `window` frames: the
        roll's own commands up to frame index `replay_to`, then the ego driven by `ego` on forecasts read from
        `guess`; snapshots every `snapshot_every` frames. A SUMO branch rolls the whole stretch in its worker."""
        start = len(roll.frames) - 1 if start is None else start
        drive = self._driver(roll.k, ego, guess, roll.commands[:replay_to])
        # A round resumes at a frame before the settled one (a slide at it): later snapshots would go unused.
        settled = self.window - 2 * self.plan_frames
        at = [i for i in range(start, min(self.window, settled + 1)) if i % self.snapshot_every == 0
              and i not in roll.snaps]
        if hasattr(sim, "rollout"):  # one message for the stretch, not one round trip per frame
            frames, commands, snaps = sim.rollout(drive, roll.frames[start], start, self.window, at)
            roll.snaps.update(snaps)
        else:
            frames, commands, frame = [], [], roll.frames[start]
            for i in range(start, self.window):  # frames are sequential: the loop itself
                if i in at:
                    roll.snaps[i] = sim.branch()
                commands.append(drive(i, frame))
                frame = sim.step(commands[-1])
                frames.append(frame)
        # Replayed frames are the roll's own (the same to the bit); keep the new ones.
        new = len(roll.frames) - 1 - start
        roll.frames += frames[new:]
        roll.commands += commands[len(roll.commands) - start:]
        return roll

    def _driver(self, k: int, ego: tuple, guess: Track, replay: list[EgoCommand | None] | None = None) -> _Drive:
        return _Drive(self.dt, self.horizon, self.radius, k, ego, guess, list(replay or []))

    def _check(self, roll: _Rollout, track: Track, settled: int) -> tuple[int, EgoCommand | None, tuple]:
        """Replan over the branch's frames with forecasts read from its own track, from its latest checkpoint:
        the first frame index d (< settled, else settled) where the ego's command differs, that command and
        the ego state after it; the ego states on the way are kept as checkpoints."""
        i0 = max(roll.checkpoints)
        planner, clock, serve = self._copy(roll.checkpoints[i0])
        for i in range(i0, settled):  # stops at the first command that differs
            if i > i0 and i % self.checkpoint_every == 0:
                roll.checkpoints[i] = self._copy((planner, clock, serve))
            command = _drive(roll.k + i, roll.k, roll.frames[i], (planner, clock, serve), track, self.dt,
                             self.horizon, self.radius)
            if command != roll.commands[i]:
                return i, command, (planner, clock, serve)
        return settled, None, (planner, clock, serve)

    @staticmethod
    def _copy(state: tuple) -> tuple:
        """A copy of the ego's driving state (planner, clock, degrader); the planner's road is shared (never
        changed)."""
        road = getattr(state[0], "road", None)
        return copy.deepcopy(state, {} if road is None else {id(road): road})


def _forecast_from(track: Track | Blend, frame: Frame, k: int, dt: float, horizon: int,
                   radius: float) -> Forecast | None:
    """The forecast at frame k of the agents within `radius` of the ego, read from `track`."""
    rows = near_targets(frame, radius)
    if rows.size == 0:
        return None
    return Forecast(agent_id=frame.agent_id[rows], mean=track.future(frame, rows, k, horizon, dt), dt=dt)


def _drive(j: int, k: int, f: Frame, ego: tuple, guess: Track | Blend, dt: float, horizon: int,
           radius: float) -> EgoCommand | None:
    """The ego's command at frame j of a branch started at frame k, forecasts read from `guess`; ego: its driving
    state (planner, clock, degrader or None), advanced."""
    planner, clock, serve = ego
    if j > k and not clock.tick(f.ego >= 0):  # the episode ticked frame k already
        return None
    if clock.due(j):
        forecast = _forecast_from(guess, f, j, dt, horizon, radius)
        if serve is not None and forecast is not None:  # served degraded, as the live planner is
            rows = near_targets(f, radius)
            forecast = serve.degrade(forecast, f.xy[rows], f.agent_type[rows], j, horizon)
        clock.issue(j, forecast)
    return planner.plan(scene_of(f, dt), clock.current(j))


@dataclasses.dataclass
class _Drive:
    """The ego of a branch started at episode frame k as one picklable callable, (frame index i, frame i) ->
    command: the recorded `replay` commands before index len(replay), then `_drive` with the driving state `ego`
    on forecasts read from `guess` (a SUMO branch runs it in its worker: `SumoProcess.rollout`)."""

    dt: float
    horizon: int
    radius: float
    k: int
    ego: tuple
    guess: Track
    replay: list

    def __call__(self, i: int, frame: Frame) -> EgoCommand | None:
        if i < len(self.replay):
            return self.replay[i]
        return _drive(self.k + i, self.k, frame, self.ego, self.guess, self.dt, self.horizon, self.radius)


def scene_of(frame: Frame, dt: float) -> Scene:
    """One frame as a one-column Scene (the planner's "now"), built directly: no id matching needed."""
    return Scene(xy=frame.xy[:, None], heading=frame.heading[:, None], speed=frame.speed[:, None],
                 valid=np.ones((frame.num_agents, 1), bool), agent_id=frame.agent_id, agent_type=frame.agent_type,
                 length=frame.length, width=frame.width, dt=dt, ego=frame.ego,
                 extra={k: v[:, None] for k, v in frame.extra.items()})

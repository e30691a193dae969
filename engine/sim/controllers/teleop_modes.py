"""The teleoperator's modes: `Drive`, `Approach`, `Hold`, `Leave` (`TeleopMode`), like the
foraging states. At each decision the `TeleopDriver` asks its mode for a key; the mode
returns the key to press (None: hand over at once, the next mode decides in this same
decision) and an event ("" for none) that `TELEOP_TRANSITIONS` maps to the next mode:

    drive --landmark--> approach --reached--> hold --done--> leave --clear--> drive
                        approach --gave up--> leave

The modes keep their state on the driver (``target_landmark``, ``until``,
``approach_from``, ``contacts_left``), which its tests and the simulation loop read."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from vitaplace.engine.sim.controllers.common import wrap as _wrap

if TYPE_CHECKING:
    from vitaplace.engine.sim.controllers.teleop import TeleopDriver

__all__ = ["TeleopMode", "Drive", "Approach", "Hold", "Leave", "TELEOP_TRANSITIONS", "LEAVE_TIME"]

Press = tuple[str, float]  #: a key and how long it is pressed [s] (inf: until the next decision)
STOP: Press = ("k", math.inf)

LEAVE_TIME = 6.0  #: the longest the driver backs off from a landmark before driving on [s]
_HOLD_PATIENCE = 3  #: a hold waiting for its contacts ends after this many whisk cycles per contact
_LEAVE_GAP = 0.15  #: after a hold, back off until the head is this far from the landmark [m]
_APPROACH_TIMEOUT = 12.0  #: an exploration that has not reached its landmark by then is given up [s]
_MAKE_ROOM = 0.3  #: where the head cannot swing round to face a landmark, back away up to this far first [m]


class TeleopMode:
    """One mode of the teleoperator; `decide` returns (key or None, event)."""

    name = ""

    def __init__(self, driver: TeleopDriver) -> None:
        self.driver = driver

    def enter(self, t: float, pose: np.ndarray) -> None:
        """Called when the driver switches to this mode."""

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        raise NotImplementedError


class Drive(TeleopMode):
    """Along the path (the loop or, in a detour window, the offset loop): translation keys
    towards the path ahead, turning when the heading is off by more than the tolerance; a
    tactile landmark being passed is explored (`TeleopDriver._start_visit`); blocked, the
    driver makes its way round (`TeleopDriver._way_round`)."""

    name = "drive"

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        path = d.detour if d.detour is not None and d.in_detour(t) else d.loop
        if path is not d.path:
            d._switch_path(path)
        d._progress(pose[:2])
        if path is d.loop and d._start_visit(t, pose):
            return None, "landmark"
        ranked = self._ranked(pose)
        stalled = d.headway.stalled(pose, t)
        key, duration = d._pick(pose, ranked)
        if (key == "k" and d._standing()) or stalled:
            return d._way_round(pose), ""
        return (key, duration), ""

    def _ranked(self, pose: np.ndarray) -> list[str]:
        """The keys to try, best first: towards the path ahead, turning first when the heading
        is off (forward and turn at once where the error is small and forward is best)."""
        d = self.driver
        direction = d._path_direction(pose)
        err = _wrap(d._facing(pose[:2]) - float(pose[2]))
        d.turning = abs(err) > (0.5 if d.turning else 1.0) * d.tolerance
        translation = d._translation_keys(direction)
        if not d.turning:
            return translation
        if d.outward is None and abs(err) < 3 * d.tolerance and translation[:1] == ["i"]:
            return ["u" if err > 0 else "o", d._turn_key(err), *translation]  # forward and turn
        return [d._turn_key(err), *translation]


class Approach(TeleopMode):
    """Turn to face the landmark (as far as the head can swing round; backing away first up to
    `_MAKE_ROOM` where it cannot), then drive up until the whiskers touch it with the head
    within ``touch_gap``: reached. Given up after `_APPROACH_TIMEOUT`, or when it can get no
    closer and the whiskers do not reach it."""

    name = "approach"

    def enter(self, t: float, pose: np.ndarray) -> None:
        d = self.driver
        d.until, d.approach_from = t + _APPROACH_TIMEOUT, pose[:2].copy()

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        if t >= d.until:  # could not get there: give up
            return STOP, "gave up"
        i = d.target_landmark
        bearing = d._bearing(pose, i)
        whisking = d.touched and d._landmark_gaps(pose)[i] <= d.spec.touch_gap
        if abs(bearing) > 0.5 * d.tolerance and not whisking:  # face it
            press = self._face(pose, bearing)
            if press is not None:
                return press, ""
        if whisking:
            return STOP, "reached"
        # then drive up to it until the whiskers touch it, and as close as touch_gap
        key, duration = d._pick(pose, d._translation_keys(bearing)[:3])
        if key != "k":
            return (key, duration), ""
        if not d._standing():  # stop first: from standstill, taps may still be safe
            return STOP, ""
        return STOP, "reached" if d.touched else "gave up"  # no closer: hold if the whiskers reach it

    def _face(self, pose: np.ndarray, bearing: float) -> Press | None:
        """A key turning towards ``bearing`` (or backing away to make room first), else None."""
        d = self.driver
        room = d._room_to_turn(pose, bearing)
        cramped = abs(room) < abs(bearing) - 0.5 * d.tolerance
        if cramped and np.linalg.norm(pose[:2] - d.approach_from) < _MAKE_ROOM:  # back away first
            key, duration = d._pick(pose, d._translation_keys(bearing + math.pi)[:3])
            if key != "k":
                return key, duration
        if abs(room) > 0.5 * d.tolerance:  # as far as the head can swing round here
            key, duration = d._pick(pose, [d._turn_key(room)])
            if key != "k":
                return key, duration
        return None


class Hold(TeleopMode):
    """Stand at the landmark until ``hold_cycles`` samples with contact are recorded (tapping
    back onto it when the whiskers lose it), or `_HOLD_PATIENCE` whisk cycles per contact."""

    name = "hold"

    def enter(self, t: float, pose: np.ndarray) -> None:
        d = self.driver
        lo, hi = d.spec.hold_cycles
        d.contacts_left = int(d.rng.integers(lo, hi + 1)) - int(d.touched)
        d.until = t + _HOLD_PATIENCE * d.contacts_left * d.sample_period

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        d.contacts_left -= int(d.touched)
        if d.contacts_left > 0 and t < d.until:
            if d.touched:
                return STOP, ""
            bearing = d._bearing(pose, d.target_landmark)
            return d._pick(pose, d._translation_keys(bearing)[:3], hold=False), ""  # tap back onto it
        return None, "done"


class Leave(TeleopMode):
    """Back away from the landmark until the head is `_LEAVE_GAP` from it, for at most
    `LEAVE_TIME`; then drive on."""

    name = "leave"

    def enter(self, t: float, pose: np.ndarray) -> None:
        self.driver.until = t + LEAVE_TIME

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        if d._landmark_gaps(pose)[d.target_landmark] < _LEAVE_GAP and t < d.until:
            away = d._bearing(pose, d.target_landmark) + math.pi
            return d._pick(pose, d._translation_keys(away)), ""
        return None, "clear"


#: (mode, event) -> next mode of the teleoperator
TELEOP_TRANSITIONS: dict[tuple[str, str], str] = {
    ("drive", "landmark"): "approach",  # a tactile landmark being passed
    ("approach", "reached"): "hold",  # the whiskers on it, the head within touch_gap
    ("approach", "gave up"): "leave",  # timed out, or no closer and the whiskers do not reach it
    ("hold", "done"): "leave",  # its contacts recorded, or out of patience
    ("leave", "clear"): "drive",  # far enough from it, or out of time
}

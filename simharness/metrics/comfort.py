"""Comfort and progress of one agent's track: acceleration, jerk, distance made good, time stuck.

Pure functions of one row of a Scene: speed (T,) m/s, xy (T, 2) m, heading (T,) rad, valid (T,),
frame period dt in seconds. Every derivative comes back with its own valid mask.
"""

from __future__ import annotations

import numpy as np


def _diff(x: np.ndarray, valid: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Backward difference of x (T, ...) over consecutive valid frames -> (T, ...), valid (T,)."""
    out = np.zeros_like(x, dtype=np.float32)
    ok = np.zeros_like(valid)
    ok[1:] = valid[1:] & valid[:-1]
    out[1:] = np.where(ok[1:].reshape(-1, *[1] * (x.ndim - 1)), (x[1:] - x[:-1]) / dt, 0.0)
    return out, ok


def longitudinal_acceleration(speed: np.ndarray, valid: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """speed (T,) m/s, valid (T,) -> acceleration (T,) m/s^2 and its valid mask (T,)."""
    return _diff(np.asarray(speed, np.float32), np.asarray(valid, bool), dt)


def lateral_acceleration(speed: np.ndarray, heading: np.ndarray, valid: np.ndarray, dt: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Centripetal acceleration speed * yaw rate: speed/heading/valid (T,) -> (T,) m/s^2, valid (T,)."""
    yaw = np.unwrap(np.asarray(heading, np.float64))
    rate, ok = _diff(yaw, np.asarray(valid, bool), dt)
    return (np.asarray(speed, np.float32) * rate).astype(np.float32), ok


def jerk(speed: np.ndarray, valid: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """speed (T,) m/s, valid (T,) -> longitudinal jerk (T,) m/s^3 and its valid mask (T,)."""
    acc, ok = longitudinal_acceleration(speed, valid, dt)
    return _diff(acc, ok, dt)


def progress(xy: np.ndarray, heading: np.ndarray, valid: np.ndarray) -> float:
    """Distance made good (m): each valid step's displacement projected on the heading at its start.

    xy (T, 2) m, heading (T,) rad, valid (T,) -> float; backing up counts negative.
    """
    ok = valid[1:] & valid[:-1]
    step = xy[1:] - xy[:-1]
    along = step[:, 0] * np.cos(heading[:-1]) + step[:, 1] * np.sin(heading[:-1])
    return float(np.sum(along[ok]))


def time_stuck(speed: np.ndarray, valid: np.ndarray, dt: float, threshold: float = 0.5) -> float:
    """Seconds spent below `threshold` m/s: speed (T,), valid (T,) -> float."""
    return float(np.count_nonzero(valid & (speed < threshold)) * dt)


def comfort_summary(speed: np.ndarray, heading: np.ndarray, valid: np.ndarray, dt: float) -> dict[str, float]:
    """Episode figures of one track: RMS and max |acceleration| (m/s^2), RMS and max |jerk| (m/s^3),
    max |lateral acceleration| (m/s^2). Zero where undefined (fewer than 3 valid frames)."""
    acc, a_ok = longitudinal_acceleration(speed, valid, dt)
    jk, j_ok = jerk(speed, valid, dt)
    lat, l_ok = lateral_acceleration(speed, heading, valid, dt)

    def rms(x: np.ndarray, ok: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x[ok] ** 2))) if ok.any() else 0.0

    def peak(x: np.ndarray, ok: np.ndarray) -> float:
        return float(np.abs(x[ok]).max()) if ok.any() else 0.0

    return {"accel_rms": rms(acc, a_ok), "accel_max": peak(acc, a_ok), "jerk_rms": rms(jk, j_ok),
            "jerk_max": peak(jk, j_ok), "lat_accel_max": peak(lat, l_ok)}

"""The configuration every learned model shares: window lengths, layer sizes, neighbour grids."""

from __future__ import annotations

import dataclasses
from typing import Any


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Fields common to all models; the window fields (history ... horizon_grid) are filled in by training.

    history, future: frames; embed, encoder, decoder: layer widths; pos_scale: metres per unit of the
    position inputs; max_neighbours, max_horizon: agents kept in the ellipse and the semi-ellipse;
    neighbour_grid, horizon_grid: (along, lateral) cells of the two maps.
    residual: the means are constant-velocity extrapolation plus a learned correction (zero at initialisation,
        `residual_scale` metres per unit at the last step, ramped from zero along the horizon: models.gaussian),
        not the paper's direct form; False in configs written before the option existed.
    cv_lags: residual form only: the constant velocity it starts from is the last displacement (1) or, above 1,
        that plus a learned blend of the mean displacements over the last 2 .. cv_lags steps (zero at
        initialisation, so still exactly constant velocity; models.gaussian.LagBlend): noisy real tracks
        extrapolate better from a velocity smoothed over several steps.
    cv_gate: with cv_lags > 1, the blend's weights depend on each track's own jitter (models.gaussian.track_jitter),
        learned likewise from zero: a data set that mixes noisy and clean annotations smooths only the noisy
        tracks. False in configs written before the option existed.
    cv_gate_pool: with cv_gate, the gate reads the jitter pooled over the target and the agents in its
        neighbour and horizon slots (models.gaussian.pooled_jitter) instead of its own track's: annotation noise
        belongs to the recording. False in configs written before the option existed.
    """

    history: int = 15
    future: int = 25
    embed: int = 32
    encoder: int = 64
    decoder: int = 128
    pos_scale: float = 10.0
    max_neighbours: int = 12
    max_horizon: int = 6
    neighbour_grid: tuple[int, int] = (13, 5)
    horizon_grid: tuple[int, int] = (7, 5)
    residual: bool = False
    residual_scale: float = 5.0
    cv_lags: int = 1
    cv_gate: bool = False
    cv_gate_pool: bool = False

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

"""The closed loop: Simulator + Predictor + Planner -> recorded Scene + scores, over seeds.

One module per concern:
- `config`: what an episode is given (`LoopConfig`, `EpisodeJob`) and records (`Issued`);
- `episode`: the loop itself (`simulate`, `run_episode`, `run_closed_loop`);
- `oracles`: the reference forecasters (the exact oracle, "static");
- `scoring`: per-episode scores, the online forecast error and the composite score;
- `aggregation`: scores over episodes with bootstrap CIs, the scorecard table;
- `page`: the report page of a run (imports matplotlib; not imported here);
- `command`: the `closedloop` CLI command and the demo's closed-loop step.
"""

from simharness.closedloop.aggregation import SCORECARD_ROWS, aggregate, bootstrap_ci, scorecard_table
from simharness.closedloop.command import closedloop_command, demo_closed_loop, write_run
from simharness.closedloop.config import EpisodeJob, Issued, LoopConfig
from simharness.closedloop.episode import (
           REFERENCE_EGOS,
           make_planner,
           prepare_spec,
           run_closed_loop,
           run_episode,
           simulate,
)
from simharness.closedloop.oracles import CLONABLE_BACKENDS, LookaheadOracle, ReplayOracle, StaticForecast
from simharness.closedloop.scoring import SCALARS, online_errors, score_episode

__all__ = ["CLONABLE_BACKENDS", "REFERENCE_EGOS", "SCALARS", "SCORECARD_ROWS", "EpisodeJob", "Issued",
           "LookaheadOracle", "LoopConfig", "ReplayOracle", "StaticForecast", "aggregate", "bootstrap_ci",
           "closedloop_command", "demo_closed_loop", "make_planner", "online_errors", "prepare_spec",
           "run_closed_loop", "run_episode", "score_episode", "scorecard_table", "simulate", "write_run"]

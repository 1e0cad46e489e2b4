"""The closed loop: Simulator + Predictor + Planner -> recorded Scene + scores, over seeds.

One module per concern:
- `config`: what an episode is given (`LoopConfig`, `EpisodeJob`) and records (`Issued`);
- `episode`: the loop itself (`simulate`, `run_episode`, `run_closed_loop`);
- `oracles`: the reference forecasters (the exact oracle, "static");
- `scoring`: per-episode scores, the online forecast error and the composite score;
- `aggregation`: scores over episodes with bootstrap CIs, the scorecard table;
- `validation`: every forecast checked (finite, shaped, for the targets asked) and its coverage counted;
- `paired`: two egos on the same seeds: the paired difference, its CI (stratified over scenarios), a verdict;
- `suite`: `simharness stress`, every stress scenario with every ego: the leaderboard;
- `page`: the report page of a run (imports matplotlib; not imported here);
- `command`: the `closedloop` CLI command.
"""

from simharness.closedloop.aggregation import SCORECARD_ROWS, aggregate, bootstrap_ci, scorecard_table
from simharness.closedloop.command import closedloop_command, write_run
from simharness.closedloop.config import EpisodeJob, Issued, LoopClock, LoopConfig
from simharness.closedloop.episode import (
    REFERENCE_EGOS,
    make_oracle,
    make_planner,
    prepare_spec,
    run_closed_loop,
    run_episode,
    simulate,
)
from simharness.closedloop.oracles import BranchOracle, StaticForecast, Track
from simharness.closedloop.paired import paired_difference, stratified_ci, verdict
from simharness.closedloop.scoring import SCALARS, online_errors, score_episode
from simharness.closedloop.suite import run_suite, stress_scenarios

__all__ = ["REFERENCE_EGOS", "SCALARS", "SCORECARD_ROWS", "EpisodeJob", "Issued",
           "BranchOracle", "LoopClock", "LoopConfig", "StaticForecast", "aggregate", "bootstrap_ci",
           "closedloop_command", "make_oracle", "make_planner", "online_errors", "paired_difference",
           "prepare_spec", "run_closed_loop", "run_episode", "run_suite", "score_episode", "scorecard_table",
           "simulate", "stratified_ci", "stress_scenarios", "Track", "verdict", "write_run"]

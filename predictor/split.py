"""Train / validation / test split by scene, shared by training and evaluation.

Whole scenes go to one split (never agents of one scene to two), so no test
agent or its neighbours were seen in training. The order is a hash of the
scene id, so a scene's split does not depend on which other scenes exist.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

from simharness.errors import UserError

SPLITS = ("train", "val", "test")


def _key(scene_id: str) -> str:
    return hashlib.sha256(scene_id.encode()).hexdigest()


def split_scenes(scene_ids: Sequence[str], val: float = 0.15, test: float = 0.15) -> dict[str, list[str]]:
    """Scene ids -> {"train", "val", "test": sorted ids}; each held-out split gets at least one scene.

    Scenes are ordered by sha256(scene_id); the first ceil-ish share goes to test, the next to val.
    Needs at least 3 scenes (one per split).
    """
    ids = sorted(set(scene_ids), key=_key)
    if len(ids) < 3:
        raise UserError(f"a split by scene needs at least 3 scenes, the data set has {len(ids)}; "
                        "generate more seeds (e.g. --seeds 0-9)")
    n_test = max(1, int(round(test * len(ids))))
    n_val = max(1, int(round(val * len(ids))))
    if n_test + n_val >= len(ids):
        n_test, n_val = 1, 1
    return {"test": sorted(ids[:n_test]), "val": sorted(ids[n_test:n_test + n_val]),
            "train": sorted(ids[n_test + n_val:])}

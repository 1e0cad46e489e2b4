"""Train / validation / test split by scene, shared by training and evaluation.

Whole scenes go to one split (never agents of one scene to two), so no test
agent or its neighbours were seen in training. The order is a hash of the
scene id, so a scene's split does not depend on which other scenes exist.
A data set whose scene ids end in `_train` / `_val` (ETH/UCY as Social-GAN and
Trajectron++ lay it out: `<scene>/train/*_train.txt`, `val/*_val.txt`, `test/*.txt`)
is split by those names instead (`SUFFIXES`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

from simharness.errors import UserError

SPLITS = ("train", "val", "test")
SUFFIXES = {"_train": "train", "_val": "val"}  # a scene id's own split, as the ETH/UCY benchmark files name it


def _own_split(scene_id: str) -> tuple[str, str | None]:
    """(recording name, "train" | "val" | None): "biwi_hotel_val" -> ("biwi_hotel", "val")."""
    for suffix, split in SUFFIXES.items():
        if scene_id.endswith(suffix):
            return scene_id[: -len(suffix)], split
    return scene_id, None


def _key(scene_id: str) -> str:
    return hashlib.sha256(scene_id.encode()).hexdigest()


def resolve_scenes(names: Sequence[str], scene_ids: Sequence[str]) -> list[str]:
    """Scene names as a user types them -> scene ids: an exact id, else the one id containing the name
    (case-insensitive), so `hotel` finds `biwi_hotel`. UserError for a name matching none or several."""
    ids = sorted(set(scene_ids))
    out = []
    for name in names:
        hits = [name] if name in ids else [i for i in ids if name.lower() in i.lower()]
        whole = [i for i in hits if _own_split(i)[1] is None]
        hits = whole if len(whole) == 1 else hits  # "hotel": biwi_hotel, not its _train / _val parts
        if len(hits) != 1:
            why = "matches no scene" if not hits else f"matches {len(hits)} scenes ({', '.join(hits[:5])})"
            raise UserError(f"test scene {name!r} {why}; the data set's scenes are {', '.join(ids[:20])}"
                            + (" ..." if len(ids) > 20 else ""))
        out.append(hits[0])
    return sorted(set(out))


def split_scenes(scene_ids: Sequence[str], val: float = 0.15, test: float = 0.15,
                 test_scenes: Sequence[str] | None = None) -> dict[str, list[str]]:
    """Scene ids -> {"train", "val", "test": sorted ids}; each held-out split gets at least one scene.

    Scenes are ordered by sha256(scene_id); the first ceil-ish share goes to test, the next to val.
    Needs at least 3 scenes (one per split).
    test_scenes: held-out scenes by name (leave-one-scene-out, `resolve_scenes`); val is then taken from
    the others as above, except that a single remaining scene is both train and val (early stopping then
    selects on training scenes: the only choice when e.g. 2 ETH/UCY scenes are split one against one).
    Scene ids ending in `_val` / `_train` (`SUFFIXES`) are the data set's own split: those of the scenes
    not held out are val / train, the others test (all the un-suffixed ones when no test_scenes are named);
    the parts of a held-out recording ("biwi_hotel_train" for "biwi_hotel") are in no split.
    """
    if any(_own_split(i)[1] == "val" for i in scene_ids):
        return _split_by_suffix(scene_ids, test_scenes)
    if test_scenes:
        held = resolve_scenes(test_scenes, scene_ids)
        rest = sorted((i for i in set(scene_ids) if i not in held), key=_key)
        if not rest:
            raise UserError(f"test scenes {', '.join(held)} leave no scene to train on")
        n_val = 0 if len(rest) == 1 else min(len(rest) - 1, max(1, int(round(val * len(set(scene_ids))))))
        train = sorted(rest[n_val:])
        return {"test": held, "val": sorted(rest[:n_val]) or train, "train": train}
    ids = sorted(set(scene_ids), key=_key)
    if len(ids) < 3:
        raise UserError(f"a split by scene needs at least 3 scenes, the data set has {len(ids)}; "
                        "generate more seeds (e.g. --seeds 0-9), or hold out named scenes (--test-scenes)")
    n_test = max(1, int(round(test * len(ids))))
    n_val = max(1, int(round(val * len(ids))))
    if n_test + n_val >= len(ids):
        n_test, n_val = 1, 1
    return {"test": sorted(ids[:n_test]), "val": sorted(ids[n_test:n_test + n_val]),
            "train": sorted(ids[n_test + n_val:])}


def describe_split(split: dict[str, list[str]], scene_ids: Sequence[str], test_scenes: Sequence[str] | None = None
                   ) -> str:
    """Two lines for a person: which scenes `split` holds out for test and why, then what it validates and
    trains on, e.g. "holding out 3 of 17 scenes for test (hash split; pass --test-scenes to choose): A, B, C"."""
    if test_scenes:
        why = "named by --test-scenes"
    elif any(_own_split(i)[1] == "val" for i in scene_ids):
        why = "the data set's own split: scene ids without _train / _val; pass --test-scenes to choose"
    else:
        why = "hash split; pass --test-scenes to choose"
    head = (f"holding out {len(split['test'])} of {len(set(scene_ids))} scenes for test ({why}): "
            f"{name_list(split['test'])}")
    if set(split["val"]) == set(split["train"]):
        return (f"{head}\none scene left to train on, so validation (checkpoint choice) used the training scene(s) "
                f"{name_list(split['train'])}")
    return (f"{head}\nvalidating (checkpoint choice) on {len(split['val'])} scene(s): {name_list(split['val'])}; "
            f"training on {len(split['train'])}")


def name_list(names: Sequence[str], most: int = 10) -> str:
    """"A, B, C" for a printed line; the first `most` and a count of the rest for long lists."""
    names = list(names)
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def _split_by_suffix(scene_ids: Sequence[str], test_scenes: Sequence[str] | None) -> dict[str, list[str]]:
    """The data set's own split: `*_val` -> val, `*_train` -> train, whole recordings -> test (see split_scenes)."""
    ids = sorted(set(scene_ids))
    held = resolve_scenes(test_scenes, ids) if test_scenes else [i for i in ids if _own_split(i)[1] is None]
    gone = {_own_split(i)[0] for i in held}
    rest = [i for i in ids if i not in held and _own_split(i)[0] not in gone]
    parts = {s: [i for i in rest if _own_split(i)[1] == s] for s in ("train", "val")}
    suffixed = {_own_split(i)[0] for i in ids if _own_split(i)[1]}
    # A whole recording not held out trains too, unless its _train / _val parts are there already.
    parts["train"] += [i for i in rest if _own_split(i)[1] is None and i not in suffixed]
    if not held or not parts["train"] or not parts["val"]:
        what = "test" if not held else "train" if not parts["train"] else "val"
        raise UserError(f"the data set's own split (scene ids ending in _train / _val) leaves no {what} scene; "
                        f"its scenes are {', '.join(ids[:20])}" + (" ..." if len(ids) > 20 else ""))
    return {"test": sorted(held), "val": sorted(parts["val"]), "train": sorted(parts["train"])}

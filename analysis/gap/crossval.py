"""Cross-validation by repeat: one repeat of every sE is held out, rotated.

With three repeats this is 3-fold cross-validation; every trial is predicted exactly once by
a model that never saw it (its level's other repeats trained the model). A level with a
single completed repeat cannot be predicted and is left out of the held-out figures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmsid.analysis.gap.data import GapData


@dataclass(frozen=True)
class Fold:
    """Row indices (into ``GapData.trials``) of one fold."""

    held_out_repeat: int
    train: np.ndarray
    test: np.ndarray


def repeat_folds(data: GapData) -> list[Fold]:
    """The folds: for each repeat number r, train on the trials whose repeat is not r and
    test on those whose repeat is r (only at sE levels that have training trials).

    Examples
    --------
    Each fold's training and test rows never overlap, and each trial is tested at most
    once (see ``tests/analysis/gap/test_crossval.py``).
    """
    rep = data.repeat
    lev = data.level
    folds = []
    for r in sorted(set(rep.tolist())):
        train = np.flatnonzero(rep != r)
        trained_levels = set(lev[train].tolist())
        test = np.array([i for i in np.flatnonzero(rep == r) if lev[i] in trained_levels],
                        dtype=int)
        if len(train) and len(test):
            folds.append(Fold(held_out_repeat=int(r), train=train, test=test))
    return folds

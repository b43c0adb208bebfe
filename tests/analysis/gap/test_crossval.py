"""Cross-validation by repeat never trains on a held-out trial."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from nmsid.analysis.gap.crossval import repeat_folds
from nmsid.analysis.gap.data import GapData, PreprocessSettings, TrialInfo


def _fake(levels, repeats):
    trials = [TrialInfo(name=f"t{i + 1:03d}", order=i + 1, sE=0.3 + 0.1 * lv, repeat=r,
                        level=lv, cum_stim_s=15.0 * i)
              for i, (lv, r) in enumerate(zip(levels, repeats, strict=True))]
    n = len(trials)
    z = np.zeros((n, 4))
    return GapData(path="x", participant="P", settings=PreprocessSettings(), fs_raw_Hz=2000.0,
                   sE_levels=np.arange(max(levels) + 1) * 0.1 + 0.3, trials=trials, y_N=z,
                   drive_raw=z, drive_sim=z, rE_sim=z, d_eval=z, t_eval_s=np.arange(4.0),
                   f_inst_Hz=np.ones(4), phase_eval_rad=np.zeros(4), chirp_f0_Hz=1.0,
                   chirp_f1_Hz=10.0, chirp_s=10.0, steady_s=5.0, n_lead_sim=0, sim_step=5)


def test_three_repeats_give_three_folds_each_trial_tested_once():
    levels = [lv for lv in range(5) for _ in range(3)]
    repeats = [r for _ in range(5) for r in (1, 2, 3)]
    folds = repeat_folds(_fake(levels, repeats))
    assert [f.held_out_repeat for f in folds] == [1, 2, 3]
    tested = np.concatenate([f.test for f in folds])
    assert sorted(tested.tolist()) == list(range(15))
    for f in folds:
        assert len(f.test) == 5 and len(f.train) == 10


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 4), st.integers(1, 3)), min_size=2, max_size=30))
def test_no_fold_trains_on_its_test_trials(pairs):
    levels = [p[0] for p in pairs]
    repeats = [p[1] for p in pairs]
    data = _fake(levels, repeats)
    seen = []
    for f in repeat_folds(data):
        assert not set(f.train.tolist()) & set(f.test.tolist())
        assert all(repeats[i] == f.held_out_repeat for i in f.test)
        assert all(repeats[i] != f.held_out_repeat for i in f.train)
        # every test trial's level has training data in this fold
        assert {levels[i] for i in f.test} <= {levels[i] for i in f.train}
        seen += f.test.tolist()
    assert len(seen) == len(set(seen))

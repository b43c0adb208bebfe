"""The engine runs the protocol's optional reference trials (a fixed sE spread through the
session, docs/identification.md section 3b) like any scheduled trial."""

import json

import h5py

from nmsid.protocols.session_file import read_session, validate_session
from nmsid.rig.engine import Engine


def test_reference_trials_are_scheduled_run_and_stored(tmp_path, fake_rig, small_config):
    path = tmp_path / "ref.h5"
    cfg = small_config(protocol={"reference_sE": 0.4, "reference_every": 2})
    eng = Engine(cfg, fake_rig(), path)
    assert len(eng.schedule) == 4 + 3
    assert [p.reference for p in eng.schedule] == [True, False, False, True, False, False,
                                                   True]
    s = eng.run()
    assert s.complete and validate_session(path) == []
    sess = read_session(path)
    assert [(t.sE, t.repeat) for t in sess.trials] == [(p.sE, p.repeat) for p in eng.schedule]
    assert sorted(t.repeat for t in sess.trials if t.sE == 0.4) == [1, 2, 3, 4, 5]
    with h5py.File(path, "r") as f:
        stored = json.loads(f.attrs["schedule_json"])
    assert [d.get("reference", False) for d in stored] == [p.reference for p in eng.schedule]

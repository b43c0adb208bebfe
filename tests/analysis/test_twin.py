"""The twin file: round trip, clear load errors, parameters and simulation."""

import json

import numpy as np
import pytest
from scipy.signal import lsim

from nmsid.analysis.errors import TwinFileError
from nmsid.analysis.twin import Curve, Twin


def make_twin():
    return Twin("P01", {"Kp": Curve("exponential", [0.9, 1.6]),
                        "wn_rad_s": Curve("quadratic", [10.0, 40.0, -25.0]),
                        "zeta": Curve("linear", [0.4, 0.3])}, (0.3, 1.0),
                offset_N=Curve("constant", [0.25]), effects=[{"name": "dead_time",
                                                               "params": {"L_s": 0.02}}])


def test_round_trip(tmp_path):
    tw = make_twin()
    p = tmp_path / "twin.json"
    tw.save(p)
    data = json.loads(p.read_text())
    assert data["format"] == "nmsid-twin" and data["format_version"] == 1
    back = Twin.load(p)
    assert back.to_dict() == tw.to_dict()
    assert back.effects == [{"name": "dead_time", "params": {"L_s": 0.02}}]


def test_the_documented_example_loads():
    doc = {"format": "nmsid-twin", "format_version": 1, "participant": "P01",
           "source": ["sessions/P01.h5"], "sE_range": [0.30, 1.00],
           "parameters": {"Kp": {"model": "exponential", "coefficients": [0.9, 1.6]},
                          "wn_rad_s": {"model": "quadratic", "coefficients": [10.0, 40.0, -25.0]},
                          "zeta": {"model": "linear", "coefficients": [0.4, 0.3]}},
           "offset_N": {"model": "constant", "coefficients": [0.0]}, "effects": []}
    tw = Twin.from_dict(doc)
    kp, wn, zeta = tw.parameters_at(0.5)
    assert (kp, wn, zeta) == pytest.approx((0.9 * np.exp(0.8), 10 + 20 - 6.25, 0.55))


@pytest.mark.parametrize("mutate,match", [
    (lambda d: d.update(format="x"), "format is 'x'"),
    (lambda d: d.update(format_version=2), "format_version"),
    (lambda d: d["parameters"].pop("zeta"), "parameters.zeta is missing"),
    (lambda d: d["parameters"]["Kp"].update(model="cubic"), "parameters.Kp.model is 'cubic'"),
    (lambda d: d["parameters"]["Kp"].update(coefficients=[1.0]), "2 finite number"),
    (lambda d: d.update(sE_range=[1.0, 0.3]), "sE_range"),
    (lambda d: d.update(effects=[{"params": {}}]), "effects"),
])
def test_load_errors_name_the_item(tmp_path, mutate, match):
    d = make_twin().to_dict()
    mutate(d)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(TwinFileError, match=match) as info:
        Twin.load(p)
    assert str(p) in str(info.value)


def test_load_missing_and_not_json(tmp_path):
    with pytest.raises(TwinFileError, match="no such file"):
        Twin.load(tmp_path / "nope.json")
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(TwinFileError, match="not readable JSON"):
        Twin.load(p)


def test_constant_sE_simulation_matches_lsim():
    tw = make_twin()
    fs = 2000.0
    t = np.arange(6000) / fs
    rE = 0.5 + 0.4 * np.sin(2 * np.pi * 3 * t) * (t > 0.5)
    kp, wn, zeta = (float(v) for v in tw.parameters_at(0.6))
    ref = lsim(([kp * wn * wn], [1, 2 * zeta * wn, wn * wn]), rE - 0.5, t)[1] + 0.25
    assert np.max(np.abs(tw.simulate(rE, 0.6, fs) - ref)) < 1e-9 * kp


def test_time_varying_sE_consistent_and_clipped():
    tw = make_twin()
    fs = 1000.0
    rE = 0.5 + 0.3 * np.sin(2 * np.pi * 2 * np.arange(3000) / fs)
    const = tw.simulate(rE, 0.7, fs)
    nearly = np.full(3000, 0.7)
    nearly[-1] += 1e-12                               # forces the time-varying path
    assert np.max(np.abs(tw.simulate(rE, nearly, fs) - const)) < 1e-9
    # clipping: sE beyond the range behaves as the range end
    assert np.allclose(tw.simulate(rE, 1.5, fs), tw.simulate(rE, 1.0, fs))
    ramp = tw.simulate(rE, np.linspace(0.3, 1.0, 3000), fs)
    assert np.all(np.isfinite(ramp))
    with pytest.raises(ValueError, match="one per sample"):
        tw.simulate(rE, np.ones(10), fs)


def test_time_varying_matches_fine_integration():
    """A fast sE ramp against an RK4 integration of the time-varying ODE."""
    tw = make_twin()
    fs = 1000.0
    n = 1500
    t = np.arange(n) / fs
    rE = 0.5 + 0.3 * np.sin(2 * np.pi * 2 * t)
    sE = 0.35 + 0.6 * t / t[-1]
    got = tw.simulate(rE, sE, fs) - 0.25
    m = 8                                      # RK4 on an 8x finer grid, linear inputs
    tf = np.linspace(0, t[-1], (n - 1) * m + 1)
    kp, wn, ze = (v.tolist() for v in tw.parameters_at(np.interp(tf, t, sE)))
    r_f = np.interp(tf, t, rE).tolist()
    h = float(tf[1] - tf[0])

    def f(i, y, v, frac):
        j = min(i + 1, len(tf) - 1)
        k_ = kp[i] + frac * (kp[j] - kp[i])
        w_ = wn[i] + frac * (wn[j] - wn[i])
        z_ = ze[i] + frac * (ze[j] - ze[i])
        r_ = r_f[i] + frac * (r_f[j] - r_f[i])
        return v, k_ * w_ * w_ * (r_ - 0.5) - 2 * z_ * w_ * v - w_ * w_ * y

    y = v = 0.0
    out = [0.0]
    for i in range(len(tf) - 1):
        a1, b1 = f(i, y, v, 0.0)
        a2, b2 = f(i, y + h / 2 * a1, v + h / 2 * b1, 0.5)
        a3, b3 = f(i, y + h / 2 * a2, v + h / 2 * b2, 0.5)
        a4, b4 = f(i, y + h * a3, v + h * b3, 1.0)
        y += h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
        v += h / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
        if (i + 1) % m == 0:
            out.append(y)
    assert np.max(np.abs(got - np.array(out))) < 1e-4 * np.max(np.abs(out))


def test_source_is_file_name_and_content_hash_never_the_path(tmp_path):
    import hashlib

    from nmsid.analysis.twin import source_entry
    private = tmp_path / "home" / "someone" / "secret-study"
    private.mkdir(parents=True)
    session = private / "P07.h5"
    payload = bytes(range(256)) * 5000 + b"tail"   # > one read block, not a multiple of it
    session.write_bytes(payload)
    entry = source_entry(session)
    assert entry == {"file": "P07.h5", "sha256": hashlib.sha256(payload).hexdigest()}
    tw = make_twin()
    tw.source = [entry, "sim_backends"]
    p = tmp_path / "twin.json"
    tw.save(p)
    text = p.read_text()
    assert "secret-study" not in text and str(tmp_path) not in text
    assert Twin.load(p).source == [entry, "sim_backends"]
    # the same bytes elsewhere give the same entry; changed bytes a different hash
    copy = tmp_path / "P07.h5"
    copy.write_bytes(payload)
    assert source_entry(copy) == entry
    copy.write_bytes(payload[:-1] + b"X")
    assert source_entry(copy)["sha256"] != entry["sha256"]


def test_twin_from_selection_hashes_its_sources(tmp_path):
    from types import SimpleNamespace

    from nmsid.analysis.twin import file_sha256, twin_from_selection

    class Comp:
        def __init__(self, model, coef):
            self.selected, self.problems = model, []
            self.selected_fit = SimpleNamespace(coefficients=coef)

        def used_points(self):
            return np.array([0.3, 0.6, 0.9]), None

    comps = {"Kp": Comp("linear", [1.0, 2.0]), "wn_rad_s": Comp("constant", [30.0]),
             "zeta": Comp("quadratic", [0.5, 0.1, 0.0])}
    selection = SimpleNamespace(comparison=lambda name, label: comps[name])
    session = tmp_path / "deep" / "P02.h5"
    session.parent.mkdir()
    session.write_bytes(b"\x89HDF\r\n" + b"0" * 100)
    tw = twin_from_selection(selection, "P02", source=[str(session)])
    assert tw.source == [{"file": "P02.h5", "sha256": file_sha256(session)}]
    assert str(tmp_path) not in json.dumps(tw.to_dict())


def test_old_twins_with_a_path_source_still_load():
    doc = make_twin().to_dict()
    doc["source"] = ["/home/someone/sessions/P01.h5"]      # written before the hash
    assert Twin.from_dict(doc).source == ["/home/someone/sessions/P01.h5"]
    doc["source"] = "/home/someone/sessions/P01.h5"         # a bare string, too
    assert Twin.from_dict(doc).source == ["/home/someone/sessions/P01.h5"]


@pytest.mark.parametrize("bad", [{"sha256": "0" * 64}, {"file": "a.h5", "sha256": "abc"},
                                 {"file": "a.h5", "sha256": "G" * 64}, 3])
def test_a_malformed_source_entry_is_named(bad):
    doc = make_twin().to_dict()
    doc["source"] = ["ok.h5", bad]
    with pytest.raises(TwinFileError, match=r"source\[1\]"):
        Twin.from_dict(doc)


def test_file_sha256_is_the_sha256_of_the_whole_file_across_block_edges(tmp_path):
    """The hash read block by block (one refilled 1 MB buffer) is that of the bytes."""
    import hashlib

    from nmsid.analysis.twin import file_sha256
    rng = np.random.default_rng(3)
    for n in (0, 1, 1 << 20, (1 << 20) + 5, 3 << 20):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        path = tmp_path / f"f{n}.bin"
        path.write_bytes(data)
        assert file_sha256(path) == hashlib.sha256(data).hexdigest()

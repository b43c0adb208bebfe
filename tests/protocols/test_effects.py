"""The effect registry is the one declaration of each effect: the simulator's dataclasses,
the gap diagnosis's forms and the FMU's reference step are held to it here (the FMU's C
step is held to the reference step by tests/export/test_fmu.py)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np
import pytest
from scipy import signal

from nmsid.analysis.gap.models import FORMS, FinalContext, candidate
from nmsid.analysis.twin import Twin
from nmsid.export.fmu.reference import TwinStepper
from nmsid.protocols.effects import (
    CANDIDATES,
    EFFECT_NAMES,
    EFFECTS,
    Effect,
    EffectParamError,
    check_param,
    spec,
)
from nmsid.protocols.effects import CANDIDATES as GAP_CANDIDATES
from nmsid.protocols.effects import Effect as GapEffect
from nmsid.sim_backends.effects import (
    EFFECT_TYPES,
    FatigueShape,
    RecruitmentShape,
    effect_from_dict,
)
from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.participant import default_participant

RNG = np.random.default_rng(20261124)


def test_every_name_is_declared_once_and_used_everywhere():
    assert list(EFFECT_NAMES) == [e.value for e in Effect if e is not Effect.NONE]
    assert list(EFFECT_TYPES) == list(EFFECT_NAMES)          # the simulator's names
    assert GapEffect is Effect and GAP_CANDIDATES == CANDIDATES   # the diagnosis's names
    assert list(FORMS) == list(CANDIDATES)                   # each has a fitted form


@pytest.mark.parametrize("s", EFFECTS, ids=lambda s: s.name)
def test_the_simulators_dataclass_has_the_registry_parameters(s):
    cls = EFFECT_TYPES[s.name]
    assert cls.name == s.name
    assert {f.name for f in dataclasses.fields(cls)} == {p.name for p in s.params}
    shapes = {"fatigue": FatigueShape, "recruitment_nonlinearity": RecruitmentShape}
    if s.name in shapes:
        assert s.param("shape").choices == tuple(m.value for m in shapes[s.name])


def _valid_params(s) -> dict:
    """Mid-range values of every required numeric parameter (plus a shape)."""
    out: dict = {}
    for p in s.params:
        if p.choices:
            out[p.name] = p.choices[0]
        elif p.required:
            lo = p.lower if p.lower is not None else -1.0
            hi = p.upper if p.upper is not None else lo + 10.0
            out[p.name] = 0.5 * (lo + hi)
    if s.name == "recruitment_nonlinearity":     # power needs its exponent
        out["gamma"] = 2.0
    return out


@pytest.mark.parametrize("s", EFFECTS, ids=lambda s: s.name)
def test_the_simulator_refuses_exactly_outside_the_registry_bounds(s):
    base = _valid_params(s)
    effect_from_dict({"name": s.name, "params": base})
    for p in s.params:
        if p.choices or p.name not in base:
            continue
        if p.upper is not None:
            effect_from_dict({"name": s.name, "params": {**base, p.name: p.upper}})
            with pytest.raises(SimConfigError, match=f"{s.name}.{p.name}"):
                effect_from_dict({"name": s.name, "params": {**base, p.name: p.upper * 1.01}})
        if p.lower is not None:
            below = p.lower - 1e-9
            with pytest.raises(SimConfigError, match=f"{s.name}.{p.name}"):
                effect_from_dict({"name": s.name, "params": {**base, p.name: below}})
            if p.lower_open:
                with pytest.raises(SimConfigError):
                    effect_from_dict({"name": s.name, "params": {**base, p.name: p.lower}})
            else:
                effect_from_dict({"name": s.name, "params": {**base, p.name: p.lower}})


def test_check_param_names_the_value_and_the_range():
    assert check_param("dead_time", "L_s", "0.5") == 0.5
    with pytest.raises(EffectParamError, match=r"dead_time.L_s .*>= 0 and <= 2, got 3"):
        check_param("dead_time", "L_s", 3)
    with pytest.raises(EffectParamError, match="valid: recruitment_nonlinearity"):
        spec("refractory")


@pytest.mark.parametrize("e", CANDIDATES, ids=lambda e: e.value)
def test_each_form_fits_its_declared_parameters_and_writes_the_registry_names(e):
    form = FORMS[e]
    assert len(form.bounds) == form.n
    assert all(len(g) == form.n for g in form.grid())
    cand = candidate(e)
    lo, hi = cand.bounds()
    q = np.array([RNG.uniform(a, b) for a, b in zip(lo[:-1], hi[:-1], strict=True)])
    p = cand.params(np.append(q, 0.0)).to_dict()
    p.update({"input_timing_s": 0.0, "corner_Hz": 0.2, "amplitude_N": 0.05})
    form.final(p, FinalContext(q=q, sE_levels=np.array([0.3, 0.6, 0.9]),
                               drift_amplitude=lambda: (0.04, 0.05)))
    entry = {"name": e.value, "params": form.twin_params(p, np.array([0.3, 0.6, 0.9]))}
    assert set(entry["params"]) <= {p.name for p in spec(e).params}
    effect_from_dict(entry)          # the simulator accepts what the diagnosis writes


# -- the FMU's reference step against the registry's continuous-time definitions ----------

def _twin(effects: list[dict]) -> Twin:
    data = default_participant().to_twin()
    data["effects"] = effects
    return Twin.from_dict(data)


def _random_input(n: int) -> np.ndarray:
    """A smooth random rE: a few sinusoids around 0.5 within [0, 1]."""
    t = np.arange(n) / 1000.0
    f = RNG.uniform(0.5, 8.0, 3)
    ph = RNG.uniform(0, 2 * np.pi, 3)
    return 0.5 + 0.15 * np.sum(np.sin(2 * np.pi * f[:, None] * t + ph[:, None]), axis=0)


@pytest.mark.parametrize("trial", range(3))
def test_fmu_reference_dead_time_is_the_nominal_response_delayed(trial):
    fs, k = 1000.0, int(RNG.integers(5, 60))
    rE, sE = _random_input(1500), float(RNG.uniform(0.4, 0.9))
    nominal = TwinStepper(_twin([])).simulate(rE, sE, fs)
    late = TwinStepper(_twin([{"name": "dead_time", "params": {"L_s": k / fs}}])).simulate(
        rE, sE, fs)
    np.testing.assert_allclose(late[k:], nominal[:-k], atol=1e-9)


@pytest.mark.parametrize("shape", ["exponential", "linear"])
def test_fmu_reference_fatigue_is_the_registry_gain_law(shape):
    fs = 1000.0
    rE, sE = _random_input(1200), float(RNG.uniform(0.4, 0.9))
    loss, cref = float(RNG.uniform(5, 60)), float(RNG.uniform(0.5, 2.0))
    tw = _twin([])
    base = TwinStepper(tw).simulate(rE, sE, fs)
    tired = TwinStepper(_twin([{"name": "fatigue", "params": {
        "shape": shape, "gain_loss_pct": loss, "reference_stim_s": cref}}])).simulate(rE, sE, fs)
    c = np.arange(len(rE)) / fs             # stimulated since the first sample
    p = loss / 100.0
    g = (1 - p) ** (c / cref) if shape == "exponential" else np.maximum(0.05, 1 - p * c / cref)
    off = float(tw.offset_N(sE))
    np.testing.assert_allclose(tired - off, g * (base - off), atol=1e-9)


@pytest.mark.parametrize("trial", range(3))
def test_fmu_reference_activation_lag_is_g_over_tau_s_plus_one(trial):
    fs = 1000.0
    rE, sE = _random_input(2000), float(RNG.uniform(0.4, 0.9))
    tau = float(RNG.uniform(0.005, 0.1))
    tw = _twin([{"name": "activation_dynamics", "params": {"tau_s": tau}}])
    got = TwinStepper(tw).simulate(rE, sE, fs, rest_lead_s=0.0)
    Kp, wn, zeta = TwinStepper(tw).params(sE)
    # the registry's definition, independently: Kp wn^2 / ((s^2 + 2 zeta wn s + wn^2)
    # (tau s + 1)) of rE - 0.5, inputs straight between samples (lsim's interpolation)
    sys = signal.lti([Kp * wn * wn], np.polymul([1, 2 * zeta * wn, wn * wn], [tau, 1]))
    t = np.arange(len(rE)) / fs
    _, want, _ = signal.lsim(sys, rE - 0.5, t, interp=True)
    np.testing.assert_allclose(got - float(tw.offset_N(sE)), want, atol=1e-6 * np.ptp(want))


@pytest.mark.parametrize("e", CANDIDATES, ids=lambda e: e.value)
def test_each_form_says_its_signature_in_one_line(e):
    from nmsid.analysis.gap.evidence import PhaseShape, Signatures
    tf = {"r2_linear_phase": 0.9, "r2_atan_phase": 0.5, "dead_time_equivalent_s": 0.02,
          "lag_equivalent_s": 0.03, "gain_error_at_top_dB": -1.0,
          "gain_rolloff_expected_for_lag_dB": -2.0, "max_abs_phase_error_deg": 12.0}
    sig = Signatures(transfer_function=PhaseShape(**tf), effect_footprint=None,
                     gain_vs_stimulation={"slope_per_100s": -0.01, "correlation": -0.8},
                     harmonics={"median_2f_pct": 1.0, "median_3f_pct": 2.0,
                                "median_1.5f_noise_reference_pct": 0.1},
                     low_frequency={"share_below_chirp": 0.5, "share_if_white": 0.1,
                                    "excess": 5.0})
    line = FORMS[e].signature(sig)
    assert line.startswith("signature: ") and "\n" not in line


# -- adding an effect takes its module and its registry entry, nothing else ----------------

def _code_words(path) -> tuple[set[str], set[str]]:
    """(identifiers, string constants) of a module's code, docstrings left out."""
    import ast
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef))
            and n.body and isinstance(n.body[0], ast.Expr)
            and isinstance(n.body[0].value, ast.Constant)}
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    names |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
               and isinstance(n.value, str) and id(n) not in docs}
    return names, strings


def test_no_consumer_names_an_effect_or_its_parameters():
    """The simulator's step, the gap fit's model and the FMU's reference step are loops over
    the registry: none names an effect, its class or (as a twin-file key) one of its
    parameters (the C step and its FMU variables are the one exception, held to the
    reference step by tests/export)."""
    from pathlib import Path

    import nmsid.analysis.gap.models as models
    import nmsid.export.fmu.reference as reference
    import nmsid.sim_backends.participant as participant
    import nmsid.sim_backends.simulation as simulation
    effects = set(EFFECT_NAMES) | {s.source.params_type.__name__ for s in EFFECTS}
    effects |= {n.upper() for n in EFFECT_NAMES}              # Effect.DEAD_TIME
    params = {p.name for s in EFFECTS for p in s.params}
    for mod in (simulation, participant, models, reference):
        names, strings = _code_words(Path(mod.__file__))
        found = sorted((names | strings) & effects | strings & params)
        assert not found, f"{mod.__name__} names {found}"


def _toy_module():
    """A new effect, written as docs/architecture.md says: one module's worth of code (a
    transport delay given in ms, fitted on a linear scale), acting at the ``delay`` slot."""
    from dataclasses import dataclass

    from nmsid.protocols.effect_defs.base import EffectDefinition, EffectParams, FittedForm, param

    @dataclass(frozen=True)
    class TransportDelay(EffectParams):
        delay_ms: float = param("the transport delay, ms", 0.0, 500.0)
        name: ClassVar[str] = "toy_transport_delay"
        summary: ClassVar[str] = "a toy: the force arrives delay_ms late"
        definition: ClassVar[str] = "F(t) = F_0(t - delay_ms / 1000)"
        slots: ClassVar[frozenset[str]] = frozenset({"delay"})

        def delay_s(self) -> float:
            return self.delay_ms * 1e-3

    class TransportDelayForm(FittedForm):
        bounds = ((0.0, 150.0),)

        def grid(self):
            return [[v] for v in (5.0, 20.0, 60.0)]

        def physical(self, q):
            return {"delay_ms": float(q[0])}

        def fit_delay_s(self, q):
            return float(q[0]) * 1e-3

        def twin_params(self, p, sE_levels):
            return {"delay_ms": p["delay_ms"]}

        def signature(self, sig):
            return f"signature: a phase line of slope {sig.phase.dead_time_equivalent_s:g} s."

    return EffectDefinition(TransportDelay, TransportDelayForm())


@pytest.fixture(scope="module")
def dead_time_session(tmp_path_factory):
    """A synthetic session with a 30 ms dead time, made without ``analysis.gap``."""
    from nmsid.testing.sessions import write_gap_session
    return write_gap_session(tmp_path_factory.mktemp("gap") / "dead.h5", seed=2,
                             levels=(0.5, 0.9), repeats=2, dead_time_s=0.030)


@pytest.fixture
def toy():
    from nmsid.protocols.effects import register, unregister
    defn = _toy_module()
    name = register(defn)
    try:
        yield name, defn.params_type
    finally:
        unregister(name.value)
    assert "toy_transport_delay" not in EFFECT_NAMES


def test_a_registered_effect_is_named_simulated_fitted_and_written_with_no_other_change(
        toy, dead_time_session):
    from nmsid.analysis.gap.data import load_session
    from nmsid.analysis.gap.diagnose import GapSettings
    from nmsid.analysis.gap.fit import fit_model
    from nmsid.analysis.gap.models import NOMINAL
    from nmsid.analysis.gap.twin_out import effect_entries
    from nmsid.export.fmu.build import FmuExportError, check_exportable
    from nmsid.sim_backends.direct_drive import currents_for, run_waveform, waveform
    from nmsid.sim_backends.effects import effects_from_list
    from nmsid.sim_backends.rig import make_sim_rig
    from nmsid.sim_backends.sensor import SensorModel
    from nmsid.sim_backends.twin import participant_from_twin

    name, cls = toy
    # the names: everywhere the registry is read
    assert name is Effect("toy_transport_delay") and name is Effect.TOY_TRANSPORT_DELAY
    assert EFFECT_NAMES[-1] == name and CANDIDATES[-1] is name and name in list(Effect)
    assert name in GapSettings().candidates and FORMS[name] is not None
    assert spec(name).param("delay_ms").bounds_text() == ">= 0 and <= 500"
    with pytest.raises(SimConfigError, match="toy_transport_delay.delay_ms"):
        effect_from_dict({"name": name.value, "params": {"delay_ms": -1}})

    # the simulator runs it: 12 ms late is the registry's own dead time of 12 ms
    p0 = default_participant(sensor=SensorModel.ideal())
    I_e, I_f = currents_for(p0.calibration, 0.6, np.r_[np.full(400, 0.5), np.full(1600, 0.8)])

    def run(p):
        return run_waveform(make_sim_rig(p, connect=True), waveform(I_e, I_f))[0]
    got = run(p0.with_effects(cls(delay_ms=12.0)))
    want = run(p0.with_effects({"name": "dead_time", "params": {"L_s": 0.012}}))
    np.testing.assert_array_equal(got, want)
    assert not np.allclose(got, run(p0))

    # the gap diagnosis fits it: the synthetic session's 30 ms (made without analysis.gap)
    data = load_session(dead_time_session)
    nom = fit_model(data, NOMINAL)
    fit = fit_model(data, candidate(name), start=nom)
    assert fit.params["delay_ms"] + 1e3 * fit.params["timing_correction_s"] == \
        pytest.approx(30.0, rel=0.05)
    assert fit.rss < 0.01 * nom.rss

    # a twin file carries it, the simulator reads it back, the FMU refuses it by name
    entries = effect_entries(fit.params, (name,), data.sE_levels)
    assert entries == [{"name": "toy_transport_delay",
                        "params": {"delay_ms": fit.params["delay_ms"]}}]
    twin = default_participant().to_twin()
    twin["effects"] = entries
    tw = Twin.from_dict(twin)
    assert participant_from_twin(twin).effect_truth() == entries
    assert effects_from_list(tw.effects)[0] == cls(delay_ms=fit.params["delay_ms"])
    with pytest.raises(FmuExportError, match="effect toy_transport_delay is not in the FMU"):
        check_exportable(twin, "twin.json")


def test_registering_refuses_a_taken_name_and_the_chain_one_lag(toy):
    from nmsid.protocols.effects import chain_of, register, unregister
    with pytest.raises(EffectParamError, match="already registered"):
        register(_toy_module())
    with pytest.raises(EffectParamError, match="built in"):
        unregister("dead_time")
    from nmsid.sim_backends.effects import ActivationDynamics, DeadTime
    name, cls = toy
    c = chain_of([cls(delay_ms=5.0), DeadTime(0.01), ActivationDynamics(0.02)])
    assert c.delay_s == pytest.approx(0.015) and c.lag_s == 0.02     # delays add up
    assert [e.name for e in c.effects] == ["activation_dynamics", "dead_time", name.value]


def test_an_effect_name_is_one_object_through_pickle_and_copy():
    import copy
    import json
    import pickle
    e = Effect.DEAD_TIME
    assert e is Effect("dead_time") is Effect(e) and e == "dead_time" and e.value == "dead_time"
    for proto in range(pickle.HIGHEST_PROTOCOL + 1):       # the gap's worker processes
        assert pickle.loads(pickle.dumps(e, proto)) is e
    assert copy.deepcopy(e) is e and json.dumps([e]) == '["dead_time"]' and f"{e}" == "dead_time"
    assert Effect.NONE.value == "none" and Effect.NONE not in CANDIDATES
    with pytest.raises(EffectParamError, match="'refractory' is unknown; valid: recruitment"):
        Effect("refractory")
    with pytest.raises(AttributeError, match="refractory"):
        Effect.REFRACTORY  # noqa: B018


def test_the_fmu_and_twin_simulate_share_one_list_of_what_they_cannot_run():
    from nmsid.export.fmu.build import unsupported_effects
    off = {"name": "baseline_drift", "params": {"amplitude_N": 0.0, "corner_Hz": 0.2}}
    on = {"name": "baseline_drift", "params": {"amplitude_N": 0.1, "corner_Hz": 0.2}}
    dead = {"name": "dead_time", "params": {"L_s": 0.02}}
    assert unsupported_effects([dead, off]) == []          # a wander that is off changes nothing
    assert unsupported_effects([dead, on]) == ["baseline_drift"]


def test_the_reports_words_come_from_each_effect():
    from nmsid.analysis.gap.verdict import effect_words
    assert effect_words("dead_time+fatigue") == (
        spec("dead_time").source.params_type.words + " together with "
        + spec("fatigue").source.params_type.words)
    assert all(s.source.params_type.words for s in EFFECTS)


def test_confusable_pairs_come_from_the_effect_modules_and_name_registered_effects():
    from nmsid.analysis.gap.evidence import confusable
    for s in EFFECTS:
        assert set(s.source.params_type.confusable_with) <= set(EFFECT_NAMES) - {s.name}
    got = {frozenset((a.value, b.value)) for a, b in confusable()}
    assert got == {frozenset(p) for p in (
        ("dead_time", "activation_dynamics"), ("activation_dynamics", "flexor_extensor_asymmetry"),
        ("dead_time", "flexor_extensor_asymmetry"), ("fatigue", "baseline_drift"),
        ("recruitment_nonlinearity", "flexor_extensor_asymmetry"))}
    assert len(confusable()) == len(got)        # each pair once


def test_only_the_dead_time_adds_its_phase_shape_and_only_against_the_activation_lag():
    from nmsid.analysis.gap.evidence import PhaseShape, Signatures, confusable
    tf = PhaseShape(0.02, 0.9, 0.03, 0.5, -1.0, -2.0, 12.0)
    sig = Signatures(transfer_function=tf, effect_footprint=None, gain_vs_stimulation={},
                     harmonics={}, low_frequency={})
    added = {(x.value, y.value): FORMS[x].pair_evidence(y.value, sig)
             for a, b in confusable() for x, y in ((a, b), (b, a))}
    assert {k for k, v in added.items() if v} == {("dead_time", "activation_dynamics")}
    assert added[("dead_time", "activation_dynamics")] == {
        "phase_shape": {"r2_linear": 0.9, "r2_atan": 0.5, "gain_error_at_top_dB": -1.0}}
